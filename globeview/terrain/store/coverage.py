"""A store's coverage: which nodes of one level hold data, over the level's bbox.

A layer's blend mask (`globeview.terrain.compose.blend.BlendMask`) is made from it. The level
is the coarsest with at least `MASK_NODES` nodes across the data footprint's shorter side
(`coverage_level`), so the raster is a few hundred nodes a side for any store. The ingest
stores it in the top metadata shard (`shards.Coverage`, `TileStore.coverage`): a store read
over a network then needs no chunk of that level before its first frame (issue #25 item 4).
A store written without one (an older build) has it read from that level's tiles, as
before; both give the same bits (`read_coverage` is what the ingest stores).

Rows run north to south, columns west to east, as the level's global node grid.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from globeview.terrain.store.shards import Coverage

if TYPE_CHECKING:
    from globeview.terrain.store.tile_store import TileStore

__all__ = ["MASK_NODES", "coverage_level", "read_coverage"]

#: The coverage is read at the coarsest level with at least this many nodes across the
#: footprint's shorter side (its edge is then exact to ~1 % of the footprint).
MASK_NODES = 160


def coverage_level(bounds: tuple[float, float, float, float], tile_n: int, max_level: int) -> int:
    """The level of a store's coverage: the coarsest with `MASK_NODES` nodes across the
    shorter side of ``bounds`` (west, south, east, north degrees), else ``max_level``."""
    west, south, east, north = bounds
    short = min((east - west) % 360.0 or 360.0, north - south)
    for cand in range(max_level + 1):
        if short / ((180.0 / 2**cand) / 2**tile_n) >= MASK_NODES:
            return cand
    return max_level


def read_coverage(st: TileStore, level: int) -> Coverage:
    """Level ``level``'s coverage read from its tiles with data (a few dozen tiles): True at
    the nodes holding a height, over the level's bbox (`TileStore.level_grid`), edge nodes
    shared by neighbouring tiles included."""
    grid = st.level_grid(level)
    cells = st.tile_size - 1
    data = np.zeros((grid.ny * cells + 1, grid.nx * cells + 1), dtype=bool)
    ys, xs = np.mgrid[grid.y0 : grid.y0 + grid.ny, grid.x0 : grid.x0 + grid.nx]
    valid = st.has_data(level, xs % grid.ncols, ys)
    for j, i in zip(*np.nonzero(valid), strict=True):
        key = (level, int(xs[j, i]) % grid.ncols, int(ys[j, i]))
        sl = (slice(j * cells, j * cells + cells + 1), slice(i * cells, i * cells + cells + 1))
        data[sl] |= ~np.isnan(st.heights(key))
    return Coverage(level, grid.y0 * cells, grid.x0 * cells, data)
