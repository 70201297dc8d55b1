"""Incremental update: when one source file of a store changes, only the chunks whose windows
(wavelet halo included) read it, and what depends on them up the pyramid, are rebuilt; the
rest is hard-linked from the old store; the result equals a full rebuild bit for bit."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from globeview.terrain.ingest.driver import ingest
from globeview.terrain.store.generations import referenced_files
from globeview.terrain.store.identify import MANIFEST_NAME
from globeview.terrain.store.layout import facts_root
from globeview.terrain.store.tile_store import TileStore

RES = 1.0 / 2048  # degrees: finest level 12 (tile_n 6), 1456 nodes a degree
N = 2048  # pixels across: each 1-degree-wide tile spans 2 chunk columns of level 12
ROWS = 512  # pixels down (45.75..46 N): one chunk row of level 12 (a quarter of the CPU of a
# 1-degree-tall tile's three rows; what is tested is which columns are rebuilt)


def _tile(path: Path, west: float, bump: float = 0.0) -> Path:
    """A DEM tile 1 degree wide (45.75..46 N) with smooth relief; ``bump`` adds a hill near
    its south-east corner."""
    y, x = np.mgrid[0:ROWS, 0:N].astype(np.float32) / N
    z = 800.0 + 300.0 * np.sin(6.0 * x + west) * np.cos(5.0 * y) + 40.0 * np.sin(40.0 * x * y)
    z += bump * np.exp(-(((x - 0.8) ** 2 + (y - 0.2) ** 2) / 0.01))
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=N,
        height=ROWS,
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=Affine(RES, 0.0, west, 0.0, -RES, 46.0),
        tiled=True,
        compress="deflate",
    ) as ds:
        ds.write(z.astype(np.float32), 1)
    return path


def _files(store: Path) -> dict[str, bytes]:
    """Every file of the store's current generation (chunks, shards and VRTs its manifest
    names, its facts as ``facts/...``) with its bytes; the manifest without its generation
    number. (An updated store also holds its previous generation, for readers that have it
    open: `terrain.store.generations`.)"""
    man = json.loads((store / MANIFEST_NAME).read_text())
    gen = man.pop("generation", 0)
    with TileStore.open(store) as st:
        names = referenced_files(store, st.manifest)
    names |= {f"level_{lv:02d}.vrt" for lv in range(man["max_level"] + 1)}
    out = {n: (store / n).read_bytes() for n in sorted(names)}
    facts = store / facts_root(gen)
    out |= {
        p.relative_to(facts).as_posix(): p.read_bytes()
        for p in sorted((facts / "facts").rglob("*"))
        if p.is_file()
    }
    out[MANIFEST_NAME] = json.dumps(man).encode()
    return out


def _inodes(store: Path) -> dict[str, int]:
    return {
        p.relative_to(store).as_posix(): p.stat().st_ino for p in store.rglob("*") if p.is_file()
    }


@pytest.fixture(scope="module")
def stores(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """Two tiles ingested (``s``), a copy of that store with a level-12 sidecar damaged
    (``damaged``); then one source changes (same place, new heights) and both are ingested
    again, and the changed sources are ingested into ``full`` from nothing: four ingests for
    the update and the damaged-sidecar tests (six when each built its own)."""
    tmp = tmp_path_factory.mktemp("upd")
    a = _tile(tmp / "a.tif", 10.0)
    b = _tile(tmp / "b.tif", 11.0)
    store, damaged = tmp / "s", tmp / "damaged"
    first = ingest([a, b], store, workers=2)
    assert first.chunks_rebuilt == first.chunks_total
    shutil.copytree(store, damaged)
    sorted(damaged.glob("facts/12/*/*.npz"))[0].write_bytes(b"not a zip")
    before = _inodes(store)
    _tile(b, 11.0, bump=250.0)  # one source changes: same place, new heights
    result = ingest([a, b], store, workers=2)
    damaged_result = ingest([a, b], damaged, workers=2)
    full = tmp / "full"
    ingest([a, b], full, workers=1)
    return {
        "store": store,
        "before": before,
        "result": result,
        "full": full,
        "damaged": damaged,
        "damaged_result": damaged_result,
    }


@pytest.fixture(scope="module")
def updated(stores: dict[str, object]):
    """(store updated incrementally, its old inodes, the update's result, a full rebuild)."""
    return stores["store"], stores["before"], stores["result"], stores["full"]


@pytest.mark.slow
def test_the_update_equals_a_full_rebuild_bit_for_bit(updated) -> None:
    store, _, result, full = updated
    assert not result.up_to_date
    assert _files(store) == _files(full)  # chunks, VRTs, sidecars and the manifest
    with TileStore.open(store) as st:
        st.verify()


@pytest.mark.slow
def test_only_the_chunks_that_read_the_changed_source_are_rebuilt(updated) -> None:
    store, before, result, _ = updated
    man = json.loads((store / MANIFEST_NAME).read_text())
    assert man["levels"][-1]["level"] == 12 and man["levels"][-1]["chunks"] == 4
    # Level 12 is 1 x 4 chunks of the global grid over a.tif (10..11 E) and b.tif (11..12 E);
    # its westmost chunk column (9.84..10.55 E) ends more than a node away from b.tif: kept,
    # linked from the old store (same names, same inodes). Every other chunk's window (halo
    # included) reaches b.tif: level 11's first column already spans 9.84..11.25 E, and so on
    # up the pyramid.
    current = set(_files(store))  # (the previous generation's files are there too)
    fine = sorted(n for n in current if n.startswith("chunks/12/"))
    west = min(int(n.split("/")[3].split("-")[0]) for n in fine)
    kept = {n for n in fine if n.split("/")[3].startswith(f"{west}-")}
    assert len(kept) == 1
    assert result.chunks_total - result.chunks_rebuilt == len(kept)
    after = {n: ino for n, ino in _inodes(store).items() if n in current}
    assert all(after[k] == before[k] for k in kept)
    # Rebuilt chunks whose bytes changed have new names; one rebuilt to the same bytes keeps
    # the name, and the file already there (generations are committed beside each other).
    assert any(n not in before for n in fine)


@pytest.mark.slow
def test_an_unchanged_store_is_still_up_to_date(updated, tmp_path: Path) -> None:
    store, _, _, _ = updated
    src = json.loads((store / MANIFEST_NAME).read_text())["sources"]
    again = ingest([s["path"] for s in src], store)
    assert again.up_to_date


@pytest.mark.slow
def test_a_damaged_sidecar_means_a_full_rebuild_not_a_wrong_store(stores) -> None:
    """A store whose level-12 sidecar was damaged before a source changed (`stores`): the
    update rebuilds every chunk and equals the full rebuild (1 worker: the same bits as 2,
    tests/terrain/test_ingest_graph.py)."""
    result = stores["damaged_result"]
    assert result.chunks_rebuilt == result.chunks_total
    assert _files(stores["damaged"]) == _files(stores["full"])
