"""Reading a store's heights: a tile's padded window of its level raster, assembled chunk by
chunk from whole GDAL blocks kept decoded in a small LRU (a view's tiles share blocks: each
256 x 256 block is read and inflated once), and which blocks a tile needs (what a remote
store's byte prefetch asks for)."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
from rasterio.windows import Window

from globeview.errors import StoreError
from globeview.interrupts import deferred_sigint
from globeview.terrain.quadtree import TileKey
from globeview.terrain.store.backend import (
    RASTER_ERRORS,
    TileNotReady,
    raise_interrupt,
    take_error,
)
from globeview.terrain.store.handles import ChunkHandles, short_error
from globeview.terrain.store.level_chunks import BLOCK
from globeview.terrain.store.metadata import StoreMetadata

__all__ = ["BLOCK_CACHE", "BlockReader"]

#: Decoded raster blocks a store keeps (256 x 256 float32: 256 KB each, so 16 MB).
BLOCK_CACHE = 64
# Reading a window of a level file damaged after the store was opened.
_READ_ERRORS: tuple[type[BaseException], ...] = (*RASTER_ERRORS, ValueError)

#: A decoded block's key: (level, chunk index, block row, block column).
BlockKey = tuple[int, int, int, int]


class BlockReader:
    """A store's level rasters read through its chunk files' handles (thread-safe).

    Attributes:
        blocks_read: raster blocks read from chunk files so far (each counted once per read,
            not per cache hit): 0 after a render means no byte of terrain arrived.
    """

    def __init__(self, handles: ChunkHandles, meta: StoreMetadata, tile_size: int) -> None:
        self._handles = handles
        self._meta = meta
        self.tile_size = tile_size
        self._lock = threading.Lock()
        self._blocks: OrderedDict[BlockKey, np.ndarray] = OrderedDict()
        self.blocks_read = 0

    def holds(self, key: BlockKey) -> bool:
        """Whether a block is decoded in the cache now."""
        return key in self._blocks

    def clear(self) -> None:
        with self._lock:
            self._blocks.clear()

    # -- a tile --------------------------------------------------------------------------------

    def read_padded(self, key: TileKey) -> np.ndarray:
        """A tile's nodes with one node beyond each edge: (tile_size + 2)^2 float32, NaN = no
        data. The interior is the tile (all NaN outside the level's extent, as `heights`
        serves it); the ring is the raster's next node on each side, which is the
        same-level neighbour's (neighbouring tiles share their edge nodes), wrapping across
        the antimeridian on a level that goes all the way round, NaN beyond the data."""
        meta = self._meta
        size = self.tile_size
        out = np.full((size + 2, size + 2), np.nan, dtype=np.float32)
        if not (0 <= key.level <= meta.max_level) or not 0 <= key.x < meta.ncols[key.level]:
            return out  # no such tile (`heights` serves NaN, as it always did)
        grid = meta.grids[key.level]
        n = grid.tile_nodes
        ncols = meta.ncols[key.level]
        iy = key.y - grid.y0
        ix = (key.x - grid.x0) % ncols
        if not grid.global_lon and ix == ncols - 1 and grid.nx < ncols:
            ix = -1  # the tile just west of the extent: its east ring is the raster's column 1
        r0, c0 = iy * n - 1, ix * n - 1  # raster row/column of the padded window's corner
        r_lo, r_hi = max(r0, 0), min(r0 + size + 2, grid.height)
        c_lo, c_hi = max(c0, 0), min(c0 + size + 2, grid.width)
        if r_lo >= r_hi or c_lo >= c_hi:
            return out
        try:
            self.read_into(key.level, r_lo, c_lo, out[r_lo - r0 : r_hi - r0, c_lo - c0 : c_hi - c0])
            if grid.global_lon:
                # Column -1 is the raster's column turn - 1, column turn + 1 its column 1
                # (column turn repeats column 0: -180 = +180).
                turn = ncols * n
                rows = slice(r_lo - r0, r_hi - r0)
                if c0 < 0:
                    self.read_into(key.level, r_lo, turn - 1, out[rows, :1])
                if c0 + size + 2 > grid.width:
                    self.read_into(key.level, r_lo, 1, out[rows, -1:])
        except TileNotReady:
            raise
        except StoreError as exc:
            # A chunk file damaged (truncated, rewritten) after the store was opened, or a
            # remote one that could not be fetched (the message names its URL and status).
            raise StoreError(f"cannot read tile {tuple(key)}: {exc}") from None
        # A node on the extent's edge belongs to the tile outside it too, which serves NaN:
        # blank each part of the window whose tile lies outside the extent.
        for dy, rows_ in ((-1, slice(0, 1)), (0, slice(1, size + 1)), (1, slice(size + 1, None))):
            for dx, cols_ in (
                (-1, slice(0, 1)),
                (0, slice(1, size + 1)),
                (1, slice(size + 1, None)),
            ):
                jx = ix + dx
                if grid.global_lon:
                    jx %= ncols
                if not (0 <= iy + dy < grid.ny and 0 <= jx < grid.nx):
                    out[rows_, cols_] = np.nan
        return out

    def tile_blocks(self, key: tuple[int, int, int]) -> list[BlockKey]:
        """(level, chunk index, block row, block column) of the chunk blocks a tile's padded
        window touches (the antimeridian wrap of a global level aside: its ring column is
        read by the loader itself)."""
        meta = self._meta
        level, x, y = key
        if not (0 <= level <= meta.max_level):
            return []
        grid = meta.grids[level]
        n = grid.tile_nodes
        iy, ix = y - grid.y0, (x - grid.x0) % meta.ncols[level]
        if not (0 <= iy < grid.ny and 0 <= ix < grid.nx):
            return []
        c_n = meta.levels[level].chunk_nodes
        rows_c, cols_c = meta.chunk_grid_shape(level)
        r_lo, r_hi = max(iy * n - 1, 0), min(iy * n + n + 2, grid.height)
        c_lo, c_hi = max(ix * n - 1, 0), min(ix * n + n + 2, grid.width)
        out = []
        for cy in range(min(r_lo // c_n, rows_c - 1), min((r_hi - 1) // c_n, rows_c - 1) + 1):
            for cx in range(min(c_lo // c_n, cols_c - 1), min((c_hi - 1) // c_n, cols_c - 1) + 1):
                index = meta.chunk_index(level, cy, cx)
                if index is None:
                    continue
                bh, bw = self._handles.block_shapes.get((level, index), (BLOCK, BLOCK))
                ra, rb = max(r_lo - cy * c_n, 0), r_hi - cy * c_n
                ca, cb = max(c_lo - cx * c_n, 0), c_hi - cx * c_n
                out += [
                    (level, index, bi, bj)
                    for bi in range(ra // bh, (rb - 1) // bh + 1)
                    for bj in range(ca // bw, (cb - 1) // bw + 1)
                ]
        return out

    # -- raster windows ------------------------------------------------------------------------

    def read_into(self, level: int, row: int, col: int, out: np.ndarray) -> None:
        """Fill ``out`` with the level raster's nodes from (row, col) on, chunk by chunk (a
        tile's padded window touches up to 4 chunks: its last row/column and its ring may
        lie in the next ones); a chunk without a file (all NaN) reads as NaN."""
        meta = self._meta
        grid = meta.grids[level]
        c_n = meta.levels[level].chunk_nodes
        rows_c, cols_c = meta.chunk_grid_shape(level)
        h, w = out.shape
        for cy in range(min(row // c_n, rows_c - 1), min((row + h - 1) // c_n, rows_c - 1) + 1):
            cr0 = cy * c_n
            cr1 = grid.height if cy == rows_c - 1 else cr0 + c_n
            r_a, r_b = max(row, cr0), min(row + h, cr1)
            for cx in range(min(col // c_n, cols_c - 1), min((col + w - 1) // c_n, cols_c - 1) + 1):
                cc0 = cx * c_n
                cc1 = grid.width if cx == cols_c - 1 else cc0 + c_n
                c_a, c_b = max(col, cc0), min(col + w, cc1)
                part = out[r_a - row : r_b - row, c_a - col : c_b - col]
                index = meta.chunk_index(level, cy, cx)
                if index is None:
                    part[...] = np.nan
                else:
                    self._read_chunk(level, index, r_a - cr0, c_a - cc0, part)

    def _read_chunk(self, level: int, index: int, row: int, col: int, out: np.ndarray) -> None:
        """Fill ``out`` with chunk ``index``'s nodes from (row, col) of the chunk on, from
        whole GDAL blocks kept decoded in `_blocks`: a tile window spans up to 4 blocks, and
        a view's tiles share them (a 67 x 67 window read cost ~0.11 ms, a copy out of cached
        blocks ~0.01 ms; each 256 x 256 block is read and inflated once). The chunk's file
        is opened only when a block is not cached."""
        shape = self._handles.block_shapes.get((level, index))
        if shape is None:
            shape = self._handles.dataset(level, index).block_shapes[0]
        bh, bw = shape
        h, w = out.shape
        for bi in range(row // bh, (row + h - 1) // bh + 1):
            for bj in range(col // bw, (col + w - 1) // bw + 1):
                block = self._block(level, index, bi, bj, bh, bw)
                r_a, r_b = max(row, bi * bh), min(row + h, (bi + 1) * bh)
                c_a, c_b = max(col, bj * bw), min(col + w, (bj + 1) * bw)
                out[r_a - row : r_b - row, c_a - col : c_b - col] = block[
                    r_a - bi * bh : r_b - bi * bh, c_a - bj * bw : c_b - bj * bw
                ]

    def _block(self, level: int, index: int, bi: int, bj: int, bh: int, bw: int) -> np.ndarray:
        """GDAL block (bi, bj) of a chunk file, decoded (an LRU of BLOCK_CACHE blocks)."""
        key = (level, index, bi, bj)
        with self._lock:
            hit = self._blocks.get(key)
            if hit is not None:
                self._blocks.move_to_end(key)
                return hit
        ds = self._handles.dataset(level, index)
        r0, c0 = bi * bh, bj * bw
        window = Window(c0, r0, min(bw, ds.width - c0), min(bh, ds.height - r0))
        take_error()
        # A Ctrl-C while GDAL reads (a remote chunk's bytes come through Python callbacks,
        # which swallow exceptions) is raised when it returns, in place of its result.
        with deferred_sigint():
            try:
                block = ds.read(1, window=window)
            except _READ_ERRORS as exc:
                self._handles.drop(level, index)
                err = take_error()
                if err is not None:
                    raise err from None
                where = self._handles.where(level, index)
                raise StoreError(f"{where}: {short_error(exc)}") from None
            raise_interrupt()
        with self._lock:
            self.blocks_read += 1
            self._blocks[key] = block
            while len(self._blocks) > BLOCK_CACHE:
                self._blocks.popitem(last=False)
        return block
