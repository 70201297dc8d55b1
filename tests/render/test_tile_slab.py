"""The shared-memory slab tile workers write into (render/tile_slab.py, issue #27 item 2):
slots taken and freed (idempotent, by release or by dropping the tile), a closed slab leaves
/dev/shm at once while tiles still viewing it stay readable, the pool's upload releases a
tile's slot, and a machine without room for the slab builds with tiles sent pickled."""

from __future__ import annotations

import gc
import os

import numpy as np
import pytest

from globeview.render.tile_build import ReadyTile
from globeview.render.tile_slab import TileSlab, write_tiles


def _tile(size: int, fill: int) -> ReadyTile:
    from globeview.render.tile_mesh import FLOATS_PER_VERTEX, vertices_per_tile

    verts = np.full((vertices_per_tile(size), FLOATS_PER_VERTEX), fill, dtype=np.float32)
    texels = np.full((size, size, 4), fill, dtype=np.uint8)
    return ReadyTile(np.array([1.0, 2.0, 3.0]), verts, texels, texels + 1, 40.0)


def _in_shm(slab: TileSlab) -> bool:
    return os.path.exists("/dev/shm/" + slab.spec.name.lstrip("/"))


def test_slots_are_taken_written_and_freed() -> None:
    slab = TileSlab(tile_size=9, slots=4)
    try:
        assert _in_shm(slab) and slab.free_count == 4
        slots = slab.take(3)
        assert slots is not None and len(set(slots)) == 3 and slab.free_count == 1
        assert slab.take(2) is None and slab.free_count == 1  # all or nothing
        write_tiles(slab.spec, slots, [_tile(9, v) for v in (5, 6, 7)])
        tiles = [slab.tile(s, np.array([1.0, 2.0, 3.0]), 40.0) for s in slots]
        for tile, v in zip(tiles, (5, 6, 7), strict=True):
            assert (tile.vertices == v).all() and (tile.albedo == v).all()
            assert (tile.normal == v + 1).all() and tile.coast_scale == 40.0
        assert tiles[0].release is not None
        tiles[0].release()
        tiles[0].release()  # idempotent
        slab.free([slots[0]])  # so is freeing a free slot
        assert slab.free_count == 2
        del tiles[1]
        gc.collect()
        assert slab.free_count == 3  # a dropped tile frees its slot
    finally:
        slab.close()


def test_closing_unlinks_at_once_and_live_tiles_stay_readable() -> None:
    slab = TileSlab(tile_size=9, slots=2)
    slots = slab.take(1)
    assert slots is not None
    write_tiles(slab.spec, slots, [_tile(9, 3)])
    tile = slab.tile(slots[0], np.zeros(3), 1.0)
    slab.close()
    slab.close()  # idempotent
    assert not _in_shm(slab) and slab.closed
    assert slab.take(1) is None
    assert (tile.vertices == 3).all()  # still mapped while viewed
    with pytest.raises(RuntimeError, match="closed"):
        slab.tile(slots[0], np.zeros(3), 1.0)
    assert tile.release is not None
    tile.release()  # after close: nothing to do


def test_the_pool_upload_releases_a_tiles_slot(gl_ctx) -> None:
    from globeview.render.tile_pool import TilePool

    slab = TileSlab(tile_size=9, slots=2)
    pool = TilePool(gl_ctx, 9, capacity=2)
    try:
        slots = slab.take(1)
        assert slots is not None
        write_tiles(slab.spec, slots, [_tile(9, 4)])
        tile = slab.tile(slots[0], np.zeros(3), 1.0)
        assert slab.free_count == 1
        pool._upload(0, tile)
        assert slab.free_count == 2
        got = np.frombuffer(pool.vbo.read(size=tile.vertices.nbytes), dtype=np.float32)
        assert (got == 4).all()
    finally:
        for obj in (pool.vbo, pool.albedo_tex, pool.normal_tex):
            obj.release()
        slab.close()


def test_no_room_for_the_slab_sends_tiles_pickled(terrain, monkeypatch, caplog) -> None:
    from globeview.render import tile_workers
    from globeview.render.tile_build import TileBuilder
    from globeview.render.tile_workers import ProcessBuilder, TerrainRecipe

    def full(*args: object, **kwargs: object) -> TileSlab:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(tile_workers, "TileSlab", full)
    keys = np.array([(12, 1230, 700), (12, 1231, 700)])
    procs = ProcessBuilder(TerrainRecipe.of(terrain), workers=1)
    try:
        with caplog.at_level("WARNING", logger="globeview.render"):
            got = procs.build_many(keys)
        assert procs.slab is None and procs.tiles_pickled == 2 and procs.tiles_shared == 0
        warnings = [r.getMessage() for r in caplog.records]
        assert len(warnings) == 1 and "pickled" in warnings[0] and "No space" in warnings[0]
        here = TileBuilder(terrain).ready(keys)
        for k, tile in got.items():
            assert tile.vertices.tobytes() == here[k].vertices.tobytes()
            assert tile.normal.tobytes() == here[k].normal.tobytes()
    finally:
        procs.shutdown()
