"""The embedded stores opened as stamped (issue #27, the window's launch): once a full open
stamped them, the next opens them without the ingest and records them as DEM sources; a DEM
or a store that changed since, or other terrain code, takes the full open again."""

from __future__ import annotations

import json

import pytest

import globeview.terrain.ingest.driver as driver
from globeview.terrain.embedded import STAMPS_NAME, embedded_stores
from globeview.terrain.sources import opened_as


@pytest.fixture
def cache(seed_cache, tmp_path, monkeypatch):
    """A cache folder of the test's own holding the embedded stores, not stamped yet."""
    folder = seed_cache(tmp_path / "cache")
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(folder))
    return folder


@pytest.fixture
def ingests(monkeypatch):
    """The DEM paths the ingest is called with (it still runs)."""
    calls: list = []
    real = driver.ingest

    def counted(sources, *args, **kwargs):
        calls.extend(sources)
        return real(sources, *args, **kwargs)

    monkeypatch.setattr(driver, "ingest", counted)
    return calls


def _close(stores) -> list[str]:
    names = [st.path.name for st in stores]
    for st in stores:
        st.close()
    return names


def test_a_stamped_open_needs_no_ingest(cache, ingests):
    first = _close(embedded_stores())
    assert len(ingests) == len(first)  # the full open: a no-op ingest each
    assert (cache / STAMPS_NAME).is_file()
    stores = embedded_stores()
    try:
        assert ingests == ingests[: len(first)], "a stamped open ingested"
        assert [st.path.name for st in stores] == first
        origin = opened_as(stores[0])
        assert origin is not None and origin.kind == "dem"
        assert origin.text.endswith("etopo20.tif")
    finally:
        _close(stores)


@pytest.mark.parametrize("field", ["mtime_ns", "size", "code", "manifest"])
def test_a_changed_stamp_opens_in_full(cache, ingests, field):
    n = len(_close(embedded_stores()))
    path = cache / STAMPS_NAME
    stamps = json.loads(path.read_text())
    dem = next(iter(stamps))
    stamps[dem][field] = "other" if isinstance(stamps[dem][field], str) else 1
    path.write_text(json.dumps(stamps))
    _close(embedded_stores())
    assert len(ingests) == 2 * n
    assert json.loads(path.read_text())[dem][field] != stamps[dem][field]  # stamped again


def test_an_unreadable_stamps_file_opens_in_full(cache, ingests):
    n = len(_close(embedded_stores()))
    (cache / STAMPS_NAME).write_text("not json")
    _close(embedded_stores())
    assert len(ingests) == 2 * n
