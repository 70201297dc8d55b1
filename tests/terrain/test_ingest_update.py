"""Incremental update: when one source file of a store changes, only the chunks whose windows
(wavelet halo included) read it, and what depends on them up the pyramid, are rebuilt; the
rest is hard-linked from the old store; the result equals a full rebuild bit for bit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from globeview.terrain.ingest.driver import ingest
from globeview.terrain.store.identify import MANIFEST_NAME
from globeview.terrain.store.tile_store import TileStore

RES = 1.0 / 2048  # degrees: finest level 12 (tile_n 6), 1456 nodes a degree
N = 2048  # pixels a side: each 1-degree tile spans 2 chunk columns of level 12


def _tile(path: Path, west: float, bump: float = 0.0) -> Path:
    """A 1-degree DEM tile (45..46 N) with smooth relief; ``bump`` adds a hill near its
    south-east corner."""
    y, x = np.mgrid[0:N, 0:N].astype(np.float32) / N
    z = 800.0 + 300.0 * np.sin(6.0 * x + west) * np.cos(5.0 * y) + 40.0 * np.sin(40.0 * x * y)
    z += bump * np.exp(-(((x - 0.8) ** 2 + (y - 0.7) ** 2) / 0.01))
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=N,
        height=N,
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
    return {p.name: p.read_bytes() for p in sorted(store.iterdir())}


def _inodes(store: Path) -> dict[str, int]:
    return {p.name: p.stat().st_ino for p in store.iterdir()}


@pytest.fixture(scope="module")
def updated(tmp_path_factory: pytest.TempPathFactory):
    """(store updated incrementally, its old inodes, the update's result, a full rebuild)."""
    tmp = tmp_path_factory.mktemp("upd")
    a = _tile(tmp / "a.tif", 10.0)
    b = _tile(tmp / "b.tif", 11.0)
    store = tmp / "s"
    first = ingest([a, b], store, workers=2)
    assert first.chunks_rebuilt == first.chunks_total
    before = _inodes(store)
    _tile(b, 11.0, bump=250.0)  # one source changes: same place, new heights
    result = ingest([a, b], store, workers=2)
    full = tmp / "full"
    ingest([a, b], full, workers=1)
    return store, before, result, full


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
    assert man["levels"][-1]["level"] == 12 and len(man["levels"][-1]["chunks"]) == 6
    # Level 12 is 2 x 3 chunks over a.tif (10..11 E) and b.tif (11..12 E); its chunk column
    # 0 ends before 10.75 E, more than a node away from b.tif: kept, linked from the old store
    # (same inodes). Every other chunk's window (halo included) reaches b.tif: level 11's
    # first column already spans 10..11.4 E, and so on up the pyramid.
    kept = {f"level_12_r{cy:04d}_c0000.tif" for cy in range(2)}
    assert result.chunks_total - result.chunks_rebuilt == len(kept)
    after = _inodes(store)
    assert all(after[k] == before[k] for k in kept)
    assert all(after[n] != before[n] for n in after if n.endswith(".tif") and n not in kept)


@pytest.mark.slow
def test_an_unchanged_store_is_still_up_to_date(updated, tmp_path: Path) -> None:
    store, _, _, _ = updated
    src = json.loads((store / MANIFEST_NAME).read_text())["sources"]
    again = ingest([s["path"] for s in src], store)
    assert again.up_to_date


@pytest.mark.slow
def test_a_damaged_sidecar_means_a_full_rebuild_not_a_wrong_store(tmp_path: Path) -> None:
    a = _tile(tmp_path / "a.tif", 10.0)
    b = _tile(tmp_path / "b.tif", 11.0)
    store = tmp_path / "s"
    ingest([a, b], store, workers=2)
    (store / "level_12_r0000_c0000.npz").write_bytes(b"not a zip")
    _tile(b, 11.0, bump=100.0)
    result = ingest([a, b], store, workers=2)
    assert result.chunks_rebuilt == result.chunks_total
    full = tmp_path / "full"
    ingest([a, b], full, workers=2)
    assert _files(store) == _files(full)
