"""Reading a store's heights: a tile's padded window of its level's global node grid,
assembled chunk by chunk (`layout.chunk_spans`) from whole GDAL blocks kept decoded in a
small LRU (a view's tiles share blocks: each 256 x 256 block is read and inflated once), and
which blocks a tile needs (what a remote store's byte prefetch asks for)."""

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
from globeview.terrain.store.layout import (
    EXTRA_COL,
    EXTRA_ROW,
    ChunkSpan,
    chunk_nodes,
    chunk_spans,
)
from globeview.terrain.store.level_chunks import BLOCK
from globeview.terrain.store.metadata import StoreMetadata

__all__ = ["BLOCK_CACHE", "BlockReader"]

#: Decoded raster blocks a store keeps (256 x 256 float32: 256 KB each, so 16 MB).
BLOCK_CACHE = 64
# Reading a window of a level file damaged after the store was opened.
_READ_ERRORS: tuple[type[BaseException], ...] = (*RASTER_ERRORS, ValueError)

#: A decoded block's key: (level, chunk code `layout.chunk_code`, block row, block column).
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
        data. The ring is the level's next node on each side (the same-level neighbour's:
        neighbouring tiles share their edge nodes), wrapping across the antimeridian, NaN
        beyond the poles and where no chunk file holds data."""
        meta = self._meta
        size = self.tile_size
        out = np.full((size + 2, size + 2), np.nan, dtype=np.float32)
        if not (0 <= key.level <= meta.max_level) or not 0 <= key.x < meta.ncols[key.level]:
            return out  # no such tile (`heights` serves NaN, as it always did)
        if not 0 <= key.y < 1 << key.level:
            return out
        n = 1 << meta.tile_n
        try:
            self.read_into(key.level, key.y * n - 1, key.x * n - 1, out)
        except TileNotReady:
            raise
        except StoreError as exc:
            # A chunk file damaged (truncated, rewritten) after the store was opened, or a
            # remote one that could not be fetched (the message names its URL and status).
            raise StoreError(f"cannot read tile {tuple(key)}: {exc}") from None
        return out

    def tile_blocks(self, key: tuple[int, int, int]) -> list[BlockKey]:
        """(level, chunk code, block row, block column) of the chunk blocks a tile's padded
        window touches."""
        meta = self._meta
        level, x, y = key
        if not (0 <= level <= meta.max_level) or not (0 <= x < meta.ncols[level]):
            return []
        if not 0 <= y < 1 << level:
            return []
        n = 1 << meta.tile_n
        out = []
        for rs in chunk_spans(level, meta.tile_n, y * n - 1, n + 3, 0):
            for cs in chunk_spans(level, meta.tile_n, x * n - 1, n + 3, 1):
                if not meta.has_file(level, rs.chunk, cs.chunk):
                    continue
                code = (rs.chunk << 32) | cs.chunk
                bh, bw = self._handles.block_shapes.get((level, code), (BLOCK, BLOCK))
                out += [
                    (level, code, bi, bj)
                    for bi in range(rs.offset // bh, (rs.offset + rs.n - 1) // bh + 1)
                    for bj in range(cs.offset // bw, (cs.offset + cs.n - 1) // bw + 1)
                ]
        return out

    # -- raster windows ------------------------------------------------------------------------

    def read_into(self, level: int, row: int, col: int, out: np.ndarray) -> None:
        """Fill ``out`` with the level's global nodes from (row, col) on (columns folded
        modulo one turn), chunk by chunk (a tile's padded window touches up to 4 chunks); a
        chunk without a file, and rows past the poles, read as NaN, but for its first row /
        column when the chunk above / west of it stores them (`layout.chunk_window`)."""
        meta = self._meta
        h, w = out.shape
        out[...] = np.nan
        for rs in chunk_spans(level, meta.tile_n, row, h, 0):
            for cs in chunk_spans(level, meta.tile_n, col, w, 1):
                part = out[rs.out : rs.out + rs.n, cs.out : cs.out + cs.n]
                if meta.has_file(level, rs.chunk, cs.chunk):
                    code = (rs.chunk << 32) | cs.chunk
                    self._read_chunk(level, code, rs.offset, cs.offset, part)
                elif rs.offset == 0 or cs.offset == 0:
                    self._borrow_edges(level, rs, cs, part)

    def _borrow_edges(self, level: int, rs: ChunkSpan, cs: ChunkSpan, part: np.ndarray) -> None:
        """The first row / column / corner node of a chunk without a file, from the chunks
        above / west / north-west of it that store their closing row / column."""
        meta = self._meta
        c = chunk_nodes(meta.tile_n)
        up, left = rs.chunk - 1, cs.chunk - 1
        if rs.offset == 0 and up >= 0 and meta.chunk_flags(level, up, cs.chunk) & EXTRA_ROW:
            self._read_chunk(level, (up << 32) | cs.chunk, c, cs.offset, part[:1, :])
        if cs.offset == 0 and left >= 0 and meta.chunk_flags(level, rs.chunk, left) & EXTRA_COL:
            self._read_chunk(level, (rs.chunk << 32) | left, rs.offset, c, part[:, :1])
        if rs.offset == 0 and cs.offset == 0 and up >= 0 and left >= 0:
            both = EXTRA_ROW | EXTRA_COL
            if meta.chunk_flags(level, up, left) & both == both:
                self._read_chunk(level, (up << 32) | left, c, c, part[:1, :1])

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
                    raise self._handles.explain(level, index, err) from None
                where = self._handles.where(level, index)
                raise StoreError(f"{where}: {short_error(exc)}") from None
            raise_interrupt()
        with self._lock:
            self.blocks_read += 1
            self._blocks[key] = block
            while len(self._blocks) > BLOCK_CACHE:
                self._blocks.popitem(last=False)
        return block
