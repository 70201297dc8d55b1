"""A store's manifest as lookups: per-tile facts (data or not, error, height range, stride
errors) vectorised over arrays of tile keys, a scalar has-data test for the compose path, and
the chunk grid of each level (which chunk file holds which nodes). No I/O: everything here is
the checked manifest (`globeview.terrain.store.schema.StoreManifest`).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from globeview.terrain.levels import LevelGrid
from globeview.terrain.store.schema import LevelRecord, StoreManifest, chunk_file_name
from globeview.terrain.store.schema import chunk_grid_shape as _chunk_grid_shape

__all__ = ["StoreMetadata"]

# The per-tile arrays of a `LevelRecord` that `StoreMetadata.lookup` serves.
_TileArray = Literal["error", "hmin", "hmax", "stride_error"]


class StoreMetadata:
    """The per-level facts of a manifest, looked up by tile key (thread-safe: read-only but
    for small tables built on first use, where a race only builds one twice).

    Attributes:
        levels: the manifest's level records, finest last.
        grids: each level's extent and raster geometry (`LevelGrid`).
        ncols: tile columns of each level on the globe (2^(L+1)).
    """

    def __init__(self, manifest: StoreManifest) -> None:
        self.max_level = manifest.max_level
        self.strides: tuple[int, ...] = manifest.strides
        self.levels: tuple[LevelRecord, ...] = manifest.levels
        self.grids = [lv.grid(manifest.tile_n) for lv in self.levels]
        self.ncols = [g.ncols for g in self.grids]  # (a property computed on each use)
        # Chunk (cy, cx) of each level -> its index in the level's `chunks` (a missing one
        # reads as NaN), and the chunk grid's shape.
        self._chunk_index = [
            {(int(cy), int(cx)): i for i, (cy, cx) in enumerate(lv.chunks)} for lv in self.levels
        ]
        self._chunk_shape = [
            _chunk_grid_shape(g, lv.chunk_nodes) for g, lv in zip(self.grids, self.levels)
        ]
        #: `_data_table`s by (level, grow); small, built on first use (races only rebuild).
        self._tables: dict[tuple[int, int], np.ndarray] = {}

    # -- levels and chunks -------------------------------------------------------------------

    def level_grid(self, level: int) -> LevelGrid:
        """Extent and raster geometry of a level."""
        return self.grids[level]

    def level_error(self, level: int) -> float | None:
        """Largest tile error of a level (metres)."""
        return self.levels[level].level_error

    def chunk_grid_shape(self, level: int) -> tuple[int, int]:
        """(rows, columns) of a level's chunk grid."""
        return self._chunk_shape[level]

    def chunk_index(self, level: int, cy: int, cx: int) -> int | None:
        """The index in the level's ``chunks`` of chunk (cy, cx); None when it has no file
        (all NaN)."""
        return self._chunk_index[level].get((cy, cx))

    def chunk_position(self, level: int, index: int) -> tuple[int, int]:
        """(cy, cx) of chunk ``index`` of a level."""
        cy, cx = (int(v) for v in self.levels[level].chunks[index])
        return cy, cx

    def chunk_name(self, level: int, index: int) -> str:
        """The file name of chunk ``index`` of a level."""
        return chunk_file_name(level, *self.chunk_position(level, index))

    # -- per-tile facts (vectorised) ---------------------------------------------------------

    def lookup(
        self, level: int, x: np.ndarray | int, y: np.ndarray | int, attr: _TileArray
    ) -> np.ndarray:
        """A `LevelRecord` per-tile array at tiles (x, y), NaN outside the level's extent."""
        x_a, y_a = np.broadcast_arrays(np.asarray(x, dtype=np.int64), np.asarray(y, dtype=np.int64))
        if not (0 <= level <= self.max_level):
            tail = (len(self.strides),) if attr == "stride_error" else ()
            return np.full(x_a.shape + tail, np.nan)
        iy, ix, inside = self.grids[level].tile_slots(y_a, x_a)
        arr: np.ndarray = getattr(self.levels[level], attr)
        vals = arr[iy, ix]
        if vals.ndim > inside.ndim:
            return np.where(inside[..., None], vals, np.nan)
        return np.where(inside, vals, np.nan)

    def has_data(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """Bool array: tile inside the level's extent and not all NaN (False beyond
        max_level)."""
        if not (0 <= level <= self.max_level):
            return np.zeros(np.broadcast(np.asarray(x), np.asarray(y)).shape, dtype=bool)
        return np.isfinite(self.lookup(level, x, y, "hmin"))

    def tile_error(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """Geometric error (metres, float32): max |tile bilinear surface - finest data| over
        the tile. NaN where there is no tile."""
        return self.lookup(level, x, y, "error").astype(np.float32)

    def tile_hrange(
        self, level: int, x: np.ndarray | int, y: np.ndarray | int
    ) -> tuple[np.ndarray, np.ndarray]:
        """(hmin, hmax) of the tiles' samples, metres, float32 (NaN where no tile)."""
        return (
            self.lookup(level, x, y, "hmin").astype(np.float32),
            self.lookup(level, x, y, "hmax").astype(np.float32),
        )

    def tile_stride_error(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """(..., 7) float32 upper bounds (metres) on the max deviation from the finest data of
        the tile drawn every 1, 2, 4, ..., 64 samples (column 0 = the tile error)."""
        err = self.lookup(level, x, y, "error")
        if not (0 <= level <= self.max_level):
            stride = np.full((*err.shape, len(self.strides)), np.nan)
        else:
            stride = self.lookup(level, x, y, "stride_error")
        return np.concatenate([err[..., None], stride], axis=-1).astype(np.float32)

    # -- one tile at a time (the compose path) -----------------------------------------------

    def has_tile(self, level: int, x: int, y: int) -> bool:
        """`has_data` for one tile, without numpy's per-call overhead (the compose path asks
        it for every layer of every tile)."""
        return self._table_lookup(level, x, y, 0)

    def has_data_near(self, level: int, x: int, y: int) -> bool:
        """Whether the tile or any of its 8 same-level neighbours has data (a tile's ring of
        neighbour nodes may hold data when the tile itself has none)."""
        return self._table_lookup(level, x, y, 1)

    def _table_lookup(self, level: int, x: int, y: int, grow: int) -> bool:
        if not (0 <= level <= self.max_level):
            return False
        grid = self.grids[level]
        ncols = self.ncols[level]
        iy = y - grid.y0
        ix = (x - grid.x0) % ncols
        if ix >= grid.nx and grid.nx < ncols:
            # Just east (nx) or just west (ncols - 1) of the extent: the table's border.
            ix = grid.nx if ix == grid.nx else (-1 if ix == ncols - 1 else -2)
        if not (-1 <= iy <= grid.ny and -1 <= ix <= grid.nx) or not (0 <= x < ncols):
            return False
        return bool(self._data_table(level, grow)[iy + 1, ix + 1])

    def _data_table(self, level: int, grow: int) -> np.ndarray:
        """(ny + 2, nx + 2) bool: whether tile (iy, ix) of the level has data (``grow`` = 1:
        it or one of its 8 neighbours), at [iy + 1, ix + 1], iy and ix from -1 (the tiles
        just outside the extent) to ny and nx; columns wrap across the antimeridian on a
        level that goes all the way round. Built once per level (a race only rebuilds it)."""
        hit = self._tables.get((level, grow))
        if hit is not None:
            return hit
        grid = self.grids[level]
        has = np.isfinite(self.levels[level].hmin)
        if grid.global_lon:
            has = np.concatenate([has[:, -1:], has, has[:, :1]], axis=1)
        else:
            has = np.pad(has, ((0, 0), (1, 1)))
        table = np.pad(has, ((1, 1), (0, 0)))
        if grow:
            q = np.pad(table, 1)
            rows, cols = table.shape
            near = np.zeros_like(table)
            for dy in range(3):
                for dx in range(3):
                    near |= q[dy : dy + rows, dx : dx + cols]
            table = near
        self._tables[(level, grow)] = table
        return table
