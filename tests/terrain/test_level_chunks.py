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
from globeview.terrain.quadtree import TileKey, key_for_lonlat
from globeview.terrain.store import level_chunks
from globeview.terrain.store.layout import EXTRA_ROW, chunk_file_name, chunk_window
from globeview.terrain.store.level_chunks import write_chunk
from globeview.terrain.store.tile_store import TileStore

DATA = Path(__file__).resolve().parents[2] / "data"


def test_chunk_is_zstd_hashed_as_written_content_named_and_a_new_inode(tmp_path: Path) -> None:
    """The file is a tiled ZSTD GeoTIFF with the floating-point predictor, named by its
    content (store format 7); its values (NaN included) read back bit for bit; the sha256
    returned is the file's; a chunk written again is a new file, leaving a hard link to the
    old one (an incremental update's) intact; no temporary file is left."""
    level, tile_n = 7, 6
    _, _, h, w = chunk_window(level, tile_n, 0, 1)
    assert (h, w) == (1024, 1024)
    rng = np.random.default_rng(3)
    values = (rng.normal(size=(h, w)) * 400.0 + 1200.0).astype(np.float32)
    values[:7, :9] = np.nan
    sha, size = write_chunk(tmp_path, level, tile_n, 0, 1, values, "1")
    path = tmp_path / chunk_file_name(level, 0, 1, sha)
    assert path.parent == tmp_path / "chunks" / "07" / "0"
    assert sha == hashlib.sha256(path.read_bytes()).hexdigest() and size == path.stat().st_size
    with rasterio.open(path) as ds:
        assert ds.profile["compress"].lower() == "zstd"
        assert ds.tags(ns="IMAGE_STRUCTURE").get("PREDICTOR") == "3"
        assert ds.profile["tiled"] and ds.block_shapes == [(256, 256)]
        back = ds.read(1)
    np.testing.assert_array_equal(back.view(np.int32), values.view(np.int32))
    old = tmp_path / "kept.tif"
    os.link(path, old)
    assert write_chunk(tmp_path, level, tile_n, 0, 1, values, "1") == (sha, size)
    assert hashlib.sha256(old.read_bytes()).hexdigest() == sha
    assert os.stat(old).st_ino != os.stat(path).st_ino
    assert write_chunk(tmp_path, level, tile_n, 0, 2, np.full((h, w), np.nan, np.float32)) is None
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]
    # A chunk whose neighbours below and east have no data stores its closing row and column.
    _, _, h2, w2 = chunk_window(level, tile_n, 0, 1, extra_row=True, extra_col=True)
    assert (h2, w2) == (1025, 1025)
    with pytest.raises(ValueError, match="shape"):
        write_chunk(tmp_path, level, tile_n, 0, 1, values, "1", EXTRA_ROW)


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
    chunk = next((tmp_path / "before").glob("chunks/09/*/*.tif"))
    with rasterio.open(chunk) as ds:
        assert ds.profile["compress"].lower() == "deflate"
    with TileStore.open(tmp_path / "now") as now, TileStore.open(tmp_path / "before") as before:
        before.verify()
        for lv in (5, 7, 9):
            x, y = key_for_lonlat(lv, -71.3, 44.6)
            key = TileKey(lv, int(x), int(y))
            assert np.isfinite(now.heights(key)).any()
            np.testing.assert_array_equal(before.heights(key), now.heights(key))
