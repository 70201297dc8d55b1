"""The one opener (`globeview.terrain.sources`): every kind of source the window, render,
height, info and bench open goes through `open_source`, with one message per case."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from globeview.errors import DemError, GlobeviewError, StoreError
from globeview.terrain.dem.reader import NoCrsError
from globeview.terrain.sources import (
    check_source,
    check_store_url,
    open_source,
    source_kind,
    store_path_for,
)

DATA = Path(__file__).resolve().parents[2] / "data"
SMALL = DATA / "craterlake-elev-16bit-30m.tif"


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "cache"
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(folder))
    return folder


def _tif(path: Path, crs: str | None) -> Path:
    n = 32
    yy, xx = np.mgrid[0:n, 0:n]
    z = (100.0 + xx + yy).astype(np.float32)
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=n,
        height=n,
        count=1,
        dtype="float32",
        crs=crs,
        transform=Affine(1.0 / n, 0.0, 10.0, 0.0, -1.0 / n, 46.0),
    ) as ds:
        ds.write(z, 1)
    return path


@pytest.mark.slow
def test_a_dem_is_ingested_once_and_its_store_opens_as_a_store(cache: Path) -> None:
    with open_source(SMALL) as st:
        folder = st.path
        assert folder == store_path_for(SMALL) and folder.parent == cache / "stores"
    assert source_kind(str(SMALL)) == "dem" and source_kind(str(folder)) == "store"
    with open_source(folder) as again:  # the store folder itself: opened as it is
        assert again.path == folder and again.max_level >= 0


def test_a_folder_that_is_not_a_store_is_one_line(tmp_path: Path) -> None:
    folder = tmp_path / "photos"
    folder.mkdir()
    for call in (open_source, check_source, source_kind):
        with pytest.raises(StoreError) as err:
            call(str(folder))
        # The words the window, render and info each used (now one line for all three).
        assert str(err.value) == (
            f"{folder} is a directory, not a DEM file, and not a globeview tile store (it has "
            "no manifest.json)"
        )


def test_a_missing_dem_and_a_link_loop_are_dem_lines(tmp_path: Path, cache: Path) -> None:
    with pytest.raises(DemError, match=r"^DEM file not found: "):
        open_source(tmp_path / "nope.tif")
    with pytest.raises(DemError, match=r"^DEM file not found: "):
        check_source(str(tmp_path / "nope.tif"))
    loop = tmp_path / "loop.tif"
    loop.symlink_to(loop)
    with pytest.raises(DemError, match="symbolic link loop"):
        open_source(loop)
    assert not (cache / "stores").exists() or not any((cache / "stores").iterdir())


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("ftp://host/store", "ftp:// URLs are not supported"),
        ("file:///tmp/store", "open a local store by its folder path instead"),
        ("s3://bucket/store", "s3:// URLs are not supported"),
        ("https://user:pw@host/store", "user names and passwords in URLs are not supported"),
        ("http://host/store?x=1", "no ?query or #fragment"),
    ],
)
def test_urls_are_checked_before_any_request(text: str, needle: str) -> None:
    for call in (open_source, check_source, check_store_url):
        with pytest.raises(GlobeviewError) as err:
            call(text)
        assert needle in str(err.value) and "\n" not in str(err.value)


def test_a_store_url_is_given_back_as_it_will_be_requested() -> None:
    assert check_source(" https://Host:8080/my store/ ") == "https://Host:8080/my%20store"
    assert source_kind("https://host/store") == "store"


def test_a_dem_without_crs_needs_one_and_keys_a_store_of_its_own(
    tmp_path: Path, cache: Path
) -> None:
    src = _tif(tmp_path / "nocrs.tif", crs=None)
    with pytest.raises(NoCrsError, match="has no coordinate reference system"):
        open_source(src)
    with pytest.raises(DemError, match=r"unknown CRS 'EPSG:999999'"):
        open_source(src, crs="EPSG:999999")
    with open_source(src, crs="EPSG:4326") as st:
        assert st.path == store_path_for(src, crs="EPSG:4326") != store_path_for(src)
        w, s, e, n = st.bounds
        assert (w, s, e, n) == pytest.approx((10.0, 45.0, 11.0, 46.0), abs=0.05)


def test_progress_is_reported_and_its_exception_cancels(tmp_path: Path, cache: Path) -> None:
    src = _tif(tmp_path / "dem.tif", crs="EPSG:4326")
    seen: list[tuple[int, int]] = []
    with open_source(src, on_progress=lambda d, t: seen.append((d, t))):
        pass
    assert seen and seen[-1][0] == seen[-1][1] > 0

    class Stop(Exception):
        pass

    def stop(done: int, total: int) -> None:
        raise Stop

    other = _tif(tmp_path / "other.tif", crs="EPSG:4326")
    with pytest.raises(Stop):
        open_source(other, on_progress=stop)
    assert not store_path_for(other).exists()


def test_a_cache_that_cannot_be_made_is_one_line(tmp_path: Path, monkeypatch) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(blocker / "cache"))
    with pytest.raises(StoreError) as err:
        open_source(SMALL)
    text = str(err.value)
    assert text.startswith(f"cannot ingest {SMALL.name}: cannot create the store cache ")
    assert str(blocker) in text and text.endswith("set GLOBEVIEW_CACHE_DIR to a writable folder")
