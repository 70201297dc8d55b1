"""The global chunk grid of store format 7 and the names of its files (issue #25, design 2.1-2.2).

Everything here is pure integer arithmetic on quadtree indices (no I/O, no numpy beyond
vectorised index maths), shared by the readers (`terrain.store`) and the ingest's planner and
writers (`terrain.ingest`).

Geometry. A level L raster is the whole globe's node grid: global node rows 0..R with
R = 2^L * 2^tile_n (row 0 on the north pole, row R on the south pole) and columns 0..W-1 with
W = 2^(L+1) * 2^tile_n (column 0 on lon -180; column W is column 0 again, one turn east).
Nodes are grid-registered: node (gr, gc) sits at lon = -180 + gc*d, lat = 90 - gr*d degrees,
d = `quadtree.node_spacing(L, tile_n)`.

Chunks. A chunk is C x C node intervals, C = k * 2^tile_n with k = `chunk_tiles(tile_n)` tiles
a side (k = 16, C = 1024 at tile_n 6). Chunk (L, cy, cx) is fixed by the quadtree, not by any
data extent: it *owns* global node rows [cy*C, min((cy+1)*C, R)) (the last chunk row also
row R, the south pole row) and columns [cx*C, min((cx+1)*C, W)) (column W is never stored:
reads fold columns modulo W); a chunk whose neighbour below / east has no data also stores
its closing row / column (`chunk_window`'s flags). Level L's chunk grid has ceil(2^L / k) rows and
ceil(2^(L+1) / k) columns, so levels 0..c0-1 (c0 = log2 k) are one chunk and level c0 is one
row of two. Tile (L, x, y) lies in chunk (y // k, x // k). A chunk exists (has a file) only
where some node it stores is finite; a missing chunk reads as NaN ("no data here").

Chunk tree. Children of chunk (L, cy, cx) for L >= c0 are (L+1, 2cy+i, 2cx+j), i, j in {0, 1};
below c0 each level's single chunk is the parent of the next level's chunk(s).

Metadata shards. Per-chunk metadata is grouped in shards: the *top* shard holds chunk levels
0..c0+1; below, a shard is rooted at one chunk of a root level (`shard_roots`) and holds its
subtree down to the next root level (at most `shard_depth` levels). `shard_of` maps a chunk to
its shard.

File names (relative to the store folder, '/'-separated, integers unpadded decimals):

- ``manifest.json`` (the only file ever replaced)
- ``level_LL.vrt`` (GDAL mosaic of one level)
- ``chunks/LL/<cy>/<cx>-<h16>.tif`` (a chunk GeoTIFF)
- ``meta/top-<h16>.gvm`` and ``meta/LL/<cy>/<cx>-<h16>.gvm`` (metadata shards)
- ``sources-<h16>.json`` (the source records)
- ``facts/LL/<cy>/<cx>.npz`` (a chunk's exact build facts, for incremental updates; those of
  generation g >= 1 under ``generations/facts-<g>/``)
- ``generations/manifest-<g>.json`` (the manifest of generation g; `terrain.store.generations`)

``<h16>`` is the first 16 hex digits of the file's sha256 (content-addressed, immutable files).
"""

from __future__ import annotations

import re
from typing import NamedTuple

import numpy as np

__all__ = [
    "CHUNK_TARGET_NODES",
    "EXTRA_COL",
    "EXTRA_ROW",
    "STORE_DIRS",
    "ChunkSpan",
    "ShardRef",
    "chunk_children",
    "chunk_code",
    "chunk_file_name",
    "chunk_grid_shape",
    "chunk_levels_c0",
    "chunk_nodes",
    "chunk_parent",
    "chunk_spans",
    "chunk_tile_range",
    "chunk_tiles",
    "chunk_window",
    "decode_chunk_code",
    "facts_file_name",
    "facts_root",
    "generation_manifest_name",
    "is_store_path",
    "level_vrt_name",
    "shard_chunks",
    "shard_depth",
    "shard_file_name",
    "shard_of",
    "shard_roots",
    "sources_file_name",
    "tile_chunk",
    "top_levels",
]

#: A chunk is about this many node intervals a side (the ingest's unit of work and file).
CHUNK_TARGET_NODES = 1024


def chunk_tiles(tile_n: int) -> int:
    """k: tiles a chunk side, max(1, 1024 >> tile_n) (16 at tile_n 6)."""
    return max(1, CHUNK_TARGET_NODES >> tile_n)


def chunk_nodes(tile_n: int) -> int:
    """C: node intervals a chunk side, k * 2^tile_n."""
    return chunk_tiles(tile_n) << tile_n


def chunk_levels_c0(tile_n: int) -> int:
    """c0 = log2 k: levels 0..c0-1 are one chunk, level c0 is two chunks side by side."""
    return chunk_tiles(tile_n).bit_length() - 1


def chunk_grid_shape(level: int, tile_n: int) -> tuple[int, int]:
    """(chunk rows, chunk columns) of level ``level``: ceil(2^L / k), ceil(2^(L+1) / k)."""
    k = chunk_tiles(tile_n)
    return -(-(1 << level) // k), -(-(1 << (level + 1)) // k)


def chunk_window(
    level: int, tile_n: int, cy: int, cx: int, extra_row: bool = False, extra_col: bool = False
) -> tuple[int, int, int, int]:
    """(gr0, gc0, height, width): the global nodes chunk (level, cy, cx) stores.

    Rows [gr0, gr0 + height), columns [gc0, gc0 + width); the last chunk row includes the
    south pole row R; column W (= column 0) is never stored. ``extra_row`` / ``extra_col``
    (`EXTRA_ROW` / `EXTRA_COL` flags of its record): the chunk also stores its closing row /
    column, which belong to the chunk below / east of it, because that chunk has no data
    (so a tile on the edge of the data keeps its last row and column of nodes).
    """
    c = chunk_nodes(tile_n)
    rows_total = 1 << (level + tile_n)  # R
    cols_total = 1 << (level + 1 + tile_n)  # W
    rows, cols = chunk_grid_shape(level, tile_n)
    if not (0 <= cy < rows and 0 <= cx < cols):
        raise ValueError(f"chunk {level}/{cy}/{cx} is outside level {level}'s chunk grid")
    gr0, gc0 = cy * c, cx * c
    gr1 = rows_total + 1 if cy == rows - 1 else gr0 + c + bool(extra_row)
    gc1 = min(gc0 + c + (bool(extra_col) and cx < cols - 1), cols_total)
    return gr0, gc0, gr1 - gr0, gc1 - gc0


#: Flags of a chunk record: it also stores its closing row / column (`chunk_window`).
EXTRA_ROW = 1
EXTRA_COL = 2


def chunk_tile_range(level: int, tile_n: int, cy: int, cx: int) -> tuple[int, int, int, int]:
    """(x0, y0, nx, ny): the tiles of chunk (level, cy, cx) (clipped to the level)."""
    k = chunk_tiles(tile_n)
    ncols, nrows = 1 << (level + 1), 1 << level
    x0, y0 = cx * k, cy * k
    return x0, y0, min(k, ncols - x0), min(k, nrows - y0)


def tile_chunk(
    x: np.ndarray | int, y: np.ndarray | int, tile_n: int
) -> tuple[np.ndarray, np.ndarray]:
    """(cy, cx) of the chunk holding tiles (x, y) of any level (vectorised)."""
    c0 = chunk_levels_c0(tile_n)
    return np.asarray(y) >> c0, np.asarray(x) >> c0


def chunk_code(cy: np.ndarray | int, cx: np.ndarray | int) -> np.ndarray:
    """One int64 per chunk, (cy << 32) | cx (chunk indices are < 2^31)."""
    return (np.asarray(cy, dtype=np.int64) << 32) | np.asarray(cx, dtype=np.int64)


def decode_chunk_code(code: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
    """(cy, cx) of chunk codes (inverse of `chunk_code`)."""
    c = np.asarray(code, dtype=np.int64)
    return c >> 32, c & 0xFFFFFFFF


def chunk_parent(level: int, cy: int, cx: int, tile_n: int) -> tuple[int, int, int]:
    """The chunk-tree parent (level - 1, pcy, pcx) of a chunk at level >= 1."""
    if level < 1:
        raise ValueError("level 0's chunk has no parent")
    if level - 1 < chunk_levels_c0(tile_n):
        return level - 1, 0, 0
    return level - 1, cy >> 1, cx >> 1


def chunk_children(level: int, cy: int, cx: int, tile_n: int) -> list[tuple[int, int, int]]:
    """The chunk-tree children of chunk (level, cy, cx), all of level + 1."""
    rows, cols = chunk_grid_shape(level + 1, tile_n)
    if level < chunk_levels_c0(tile_n):
        return [(level + 1, r, c) for r in range(rows) for c in range(cols)]
    return [
        (level + 1, 2 * cy + i, 2 * cx + j)
        for i in (0, 1)
        for j in (0, 1)
        if 2 * cy + i < rows and 2 * cx + j < cols
    ]


class ChunkSpan(NamedTuple):
    """Part of a 1-D node range that one chunk stores: output positions [out, out + n) are
    chunk index ``chunk``'s nodes [offset, offset + n) along that axis."""

    chunk: int
    offset: int
    out: int
    n: int


def chunk_spans(level: int, tile_n: int, g0: int, n: int, axis: int) -> list[ChunkSpan]:
    """How global nodes [g0, g0 + n) along ``axis`` (0: rows, 1: columns) split over chunks.

    Columns are folded modulo W (so g0 may be negative or past one turn: the antimeridian);
    rows outside 0..R are left out (no span: the caller's NaN).
    """
    c = chunk_nodes(tile_n)
    rows, _ = chunk_grid_shape(level, tile_n)
    total = 1 << (level + tile_n + axis)  # R for rows, W for columns
    spans: list[ChunkSpan] = []
    pos = 0
    while pos < n:
        g = g0 + pos
        if axis == 1:
            g %= total
        elif g < 0:
            pos = min(n, -g0)
            continue
        elif g > total:
            break
        ci = min(g // c, rows - 1) if axis == 0 else g // c
        off = g - ci * c
        if axis == 0:
            end = total + 1 if ci == rows - 1 else (ci + 1) * c
        else:
            end = min((ci + 1) * c, total)
        m = min(n - pos, end - g)
        spans.append(ChunkSpan(int(ci), int(off), pos, int(m)))
        pos += m
    return spans


# ---------------------------------------------------------------------------------------------
# Metadata shards


def shard_depth(tile_n: int) -> int:
    """D: chunk levels a (non-top) shard spans at most, so a shard holds <= 85 chunks' worth
    of tiles at k = 16 (5 for k <= 4, 4 for k = 8 and 16, 3 for 32, 2 for 64, 1 for >= 128)."""
    k = chunk_tiles(tile_n)
    if k <= 4:
        return 5
    return {8: 4, 16: 4, 32: 3, 64: 2}.get(k, 1)


def top_levels(tile_n: int) -> int:
    """The top shard holds chunk levels 0..top_levels(tile_n) - 1 (= c0 + 1 inclusive)."""
    return chunk_levels_c0(tile_n) + 2


def shard_roots(max_level: int, tile_n: int) -> tuple[int, ...]:
    """The root levels of the non-top shards, increasing: c0 + 2, then max_level - D + 1,
    max_level - 2D + 1, ... (those > c0 + 2), so bottom shards end at the finest level.
    Empty when the top shard holds every level (max_level <= c0 + 1)."""
    first = top_levels(tile_n)
    if max_level < first:
        return ()
    d = shard_depth(tile_n)
    roots = []
    r = max_level - d + 1
    while r > first:
        roots.append(r)
        r -= d
    return (first, *reversed(roots))


class ShardRef(NamedTuple):
    """A shard: root chunk (level, cy, cx) and the number of chunk levels it spans.
    The top shard is ShardRef(0, 0, 0, top_levels)."""

    level: int
    cy: int
    cx: int
    depth: int

    @property
    def is_top(self) -> bool:
        return self.level == 0


def _root_of(level: int, roots: tuple[int, ...]) -> int:
    """The largest root level <= level (0 for the top shard)."""
    r = 0
    for root in roots:
        if root <= level:
            r = root
    return r


def _depth(root: int, roots: tuple[int, ...], max_level: int, tile_n: int) -> int:
    if root == 0:
        return min(top_levels(tile_n), max_level + 1)
    nxt = [r for r in roots if r > root]
    return (nxt[0] if nxt else max_level + 1) - root


def shard_of(level: int, cy: int, cx: int, tile_n: int, max_level: int) -> ShardRef:
    """The shard holding chunk (level, cy, cx) of a store of ``max_level``."""
    roots = shard_roots(max_level, tile_n)
    root = _root_of(level, roots)
    depth = _depth(root, roots, max_level, tile_n)
    if root == 0:
        return ShardRef(0, 0, 0, depth)
    s = level - root
    return ShardRef(root, cy >> s, cx >> s, depth)


def shard_chunks(ref: ShardRef, tile_n: int) -> list[tuple[int, int, int]]:
    """Every chunk slot (level, cy, cx) of shard ``ref`` in its availability order: level by
    level from the root, row-major within each level (the top shard: each level's whole
    chunk grid; others: the root's 2^d x 2^d descendants at depth d, clipped to the grid)."""
    out: list[tuple[int, int, int]] = []
    for d in range(ref.depth):
        lv = ref.level + d
        rows, cols = chunk_grid_shape(lv, tile_n)
        if ref.is_top:
            out += [(lv, r, c) for r in range(rows) for c in range(cols)]
            continue
        r0, c0, n = ref.cy << d, ref.cx << d, 1 << d
        out += [
            (lv, r, c) for r in range(r0, min(r0 + n, rows)) for c in range(c0, min(c0 + n, cols))
        ]
    return out


# ---------------------------------------------------------------------------------------------
# File names

_H16 = "[0-9a-f]{16}"
_INT = r"(0|[1-9]\d{0,9})"
_STORE_PATH = re.compile(
    r"^(manifest\.json"
    r"|level_\d\d\.vrt(\.aux\.xml)?"
    rf"|sources-{_H16}\.json"
    rf"|meta/top-{_H16}\.gvm"
    rf"|meta/\d\d/{_INT}/{_INT}-{_H16}\.gvm"
    rf"|chunks/\d\d/{_INT}/{_INT}-{_H16}\.tif"
    rf"|(generations/facts-{_INT}/)?facts/\d\d/{_INT}/{_INT}\.npz"
    rf"|generations/manifest-{_INT}\.json)$"
)


def _h16(sha256: str) -> str:
    if not re.fullmatch(r"[0-9a-f]{64}", sha256):
        raise ValueError("not a sha256 hex digest")
    return sha256[:16]


def level_vrt_name(level: int) -> str:
    """The GDAL VRT mosaicking level ``level``'s chunks."""
    return f"level_{level:02d}.vrt"


def chunk_file_name(level: int, cy: int, cx: int, sha256: str) -> str:
    """``chunks/LL/<cy>/<cx>-<h16>.tif``: chunk (level, cy, cx) whose bytes have ``sha256``."""
    return f"chunks/{level:02d}/{cy}/{cx}-{_h16(sha256)}.tif"


def shard_file_name(ref: ShardRef, sha256: str) -> str:
    """``meta/top-<h16>.gvm`` or ``meta/LL/<cy>/<cx>-<h16>.gvm``: shard ``ref``'s file."""
    if ref.is_top:
        return f"meta/top-{_h16(sha256)}.gvm"
    return f"meta/{ref.level:02d}/{ref.cy}/{ref.cx}-{_h16(sha256)}.gvm"


def sources_file_name(sha256: str) -> str:
    """``sources-<h16>.json``: the store's source records."""
    return f"sources-{_h16(sha256)}.json"


#: The folders of a format-7 store (everything else is a file at its top).
STORE_DIRS = ("chunks", "meta", "facts", "generations")


def facts_file_name(level: int, cy: int, cx: int) -> str:
    """``facts/LL/<cy>/<cx>.npz``: chunk (level, cy, cx)'s build facts (incremental updates)."""
    return f"facts/{level:02d}/{cy}/{cx}.npz"


def facts_root(generation: int) -> str:
    """The folder (relative to the store, '' or ending in '/') holding generation
    ``generation``'s facts files: the store's top for generation 0 (a first build, and every
    format-7 store written before generations), ``generations/facts-<g>/`` after updates (a
    whole folder renamed into place, so a killed update never mixes two generations' facts)."""
    return "" if generation == 0 else f"generations/facts-{generation}/"


def generation_manifest_name(generation: int) -> str:
    """``generations/manifest-<g>.json``: the manifest of generation ``generation``."""
    return f"generations/manifest-{generation}.json"


def is_store_path(rel: str) -> bool:
    """Whether ``rel`` ('/'-separated, relative to the store) is a file format 7 writes."""
    return bool(_STORE_PATH.match(rel))
