"""Chunk files (globeview.terrain.store.level_chunks): ZSTD with the floating-point predictor
(issue #25 C5), hashed as written, and stores written with DEFLATE (before) still read."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np
import pytest
import rasterio

from globeview.terrain.ingest.driver import ingest
from globeview.terrain.levels import LevelGrid
from globeview.terrain.quadtree import TileKey, key_for_lonlat
from globeview.terrain.store import level_chunks
from globeview.terrain.store.level_chunks import chunk_window, write_chunk
from globeview.terrain.store.schema import chunk_file_name
from globeview.terrain.store.tile_store import TileStore

DATA = Path(__file__).resolve().parents[2] / "data"


def _grid() -> LevelGrid:
    return LevelGrid(level=3, tile_n=6, x0=2, y0=1, nx=5, ny=3)


def test_chunk_is_zstd_hashed_as_written_and_a_new_inode(tmp_path: Path) -> None:
    """The file is a tiled ZSTD GeoTIFF with the floating-point predictor; its values (NaN
    included) read back bit for bit; the sha256 returned is the file's; a chunk written again
    is a new file, leaving a hard link to the old one (an incremental update's) intact."""
    grid = _grid()
    _, _, h, w = chunk_window(grid, 128, 0, 1)
    rng = np.random.default_rng(3)
    values = (rng.normal(size=(h, w)) * 400.0 + 1200.0).astype(np.float32)
    values[:7, :9] = np.nan
    sha = write_chunk(tmp_path, grid, 128, 0, 1, values, "1")
    path = tmp_path / chunk_file_name(grid.level, 0, 1)
    assert sha == hashlib.sha256(path.read_bytes()).hexdigest()
    with rasterio.open(path) as ds:
        assert ds.profile["compress"].lower() == "zstd"
        assert ds.tags(ns="IMAGE_STRUCTURE").get("PREDICTOR") == "3"
        assert ds.profile["tiled"] and ds.block_shapes == [(256, 256)]
        back = ds.read(1)
    np.testing.assert_array_equal(back.view(np.int32), values.view(np.int32))
    old = tmp_path / "kept.tif"
    os.link(path, old)
    write_chunk(tmp_path, grid, 128, 0, 1, values + np.float32(1.0), "1")
    assert hashlib.sha256(old.read_bytes()).hexdigest() == sha
    assert os.stat(old).st_ino != os.stat(path).st_ino
    _, _, h2, w2 = chunk_window(grid, 128, 0, 2)
    assert write_chunk(tmp_path, grid, 128, 0, 2, np.full((h2, w2), np.nan, np.float32)) is None
    assert not (tmp_path / chunk_file_name(grid.level, 0, 2)).exists()


@pytest.mark.slow
def test_a_store_of_deflate_chunks_reads_the_same_heights(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A store built before (DEFLATE level 1 + predictor 3 chunks, as level_chunks wrote
    them) opens and gives the same heights as one built now."""
    profile = level_chunks._profile

    def deflate(*args):  # type: ignore[no-untyped-def]
        p = {k: v for k, v in profile(*args).items() if k != "zstd_level"}
        return {**p, "compress": "deflate", "zlevel": 1}

    src = DATA / "N44W072.hgt"
    ingest([src], tmp_path / "now", max_level=9)
    with monkeypatch.context() as mp:
        mp.setattr(level_chunks, "_profile", deflate)
        ingest([src], tmp_path / "before", max_level=9)
    chunk = next((tmp_path / "before").glob("level_09_*.tif"))
    with rasterio.open(chunk) as ds:
        assert ds.profile["compress"].lower() == "deflate"
    with TileStore.open(tmp_path / "now") as now, TileStore.open(tmp_path / "before") as before:
        before.verify()
        for lv in (5, 7, 9):
            x, y = key_for_lonlat(lv, -71.3, 44.6)
            key = TileKey(lv, int(x), int(y))
            assert np.isfinite(now.heights(key)).any()
            np.testing.assert_array_equal(before.heights(key), now.heights(key))
