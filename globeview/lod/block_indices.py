"""Index lists of tiles drawn with a stride per block (issue #27 item 3, design §5.3).

A tile of ``size`` = 65 nodes (64 x 64 cells) is cut into 8 x 8 blocks of 8 x 8 cells
(9 x 9 nodes, neighbours share their edge nodes). A *block pattern* is an (8, 8) array of
stride indices (0..3: strides 1, 2, 4, 8), row 0 the northern blocks, column 0 the western.

Crack-free inside the tile: the edge between two blocks is drawn at the larger of their two
strides by both (the finer block's border cells become fans onto the coarse edge's nodes,
`tile_indices._stitch_edges` on a 9 x 9 grid); the coarse edge's nodes are a subset of the
fine ones, so no T-junction. The tile's own edges: by default skirts, each edge block's at
its stride (the skirt vertices of `render/tile_mesh.py`'s layout); with *tile edges*
(``edges`` (4, 8): north, south, west, east, each edge block west to east or north to
south) an edge block may instead be drawn at a stride stitched to the same-level neighbour
across that edge (the larger of the two tiles' blocks there, `stitching.stitch_tile_edges`)
and then has no skirt: both tiles draw the same nodes there.

Every block's triangles come from a precomputed *piece* per (block stride, its four edge
strides) in node offsets relative to the block's origin node ``8 bi size + 8 bj``, and every
edge block's skirt from a piece per (tile edge, block position, stride) in absolute indices:
a tile's list is a gather of its pieces (`pattern_indices`, vectorised over many patterns).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from globeview.lod.tile_indices import IndexVariant, grid_indices

#: Blocks per tile side and cells per block side.
BLOCKS = 8
BLOCK_CELLS = 8
#: Stride indices a block may have (strides 1, 2, 4, 8).
N_BLOCK_STRIDES = 4
#: (north, south, west, east) edges, as in `tile_indices._skirt_triangles`.
_EDGES = 4
#: A tile edge block's entry in ``edges`` that keeps its skirt at the block's own stride.
SKIRTED = -1


@dataclass(frozen=True)
class BlockPieces:
    """The precomputed pieces of one tile size (read-only arrays).

    table: int64 node offsets of every piece, concatenated.
    grid_start, grid_len: (4, 4, 4, 4, 4) where each grid piece (block stride index, north,
        south, west, east edge stride indices) starts in ``table`` and how many indices it
        has (0 where an edge stride is finer than the block's: never used).
    skirt_start, skirt_len: (4 edges, 8 positions, 4 strides) the same for skirt pieces
        (absolute vertex indices: their offset is 0).
    """

    size: int
    table: np.ndarray
    grid_start: np.ndarray
    grid_len: np.ndarray
    skirt_start: np.ndarray
    skirt_len: np.ndarray


def _check_size(size: int) -> None:
    if size != BLOCKS * BLOCK_CELLS + 1:
        raise ValueError(
            f"block patterns need tiles of {BLOCKS * BLOCK_CELLS + 1} nodes, not {size}"
        )


def _grid_piece(size: int, s: int, edges: tuple[int, int, int, int]) -> np.ndarray:
    """One block's triangles at stride ``s`` with edge strides ``edges`` (N, S, W, E), as
    offsets in the tile's node layout from the block's origin node."""
    n9 = BLOCK_CELLS + 1
    variant = IndexVariant(stride=s, skirts=False, edge_strides=None if max(edges) == s else edges)
    local = grid_indices(n9, variant).astype(np.int64)
    return (local // n9) * size + local % n9


def _skirt_piece(size: int, edge: int, pos: int, s: int) -> np.ndarray:
    """The skirt of edge block ``pos`` along tile edge ``edge`` at stride ``s`` (absolute
    vertex indices: `tile_indices._skirt_triangles` over that block's span of the edge)."""
    n = size - 1
    base = size * size
    i = np.arange(pos * BLOCK_CELLS, (pos + 1) * BLOCK_CELLS, s)
    j = i + s
    if edge == 0:
        top0, top1 = i, j
    elif edge == 1:
        top0, top1 = n * size + i, n * size + j
    elif edge == 2:
        top0, top1 = i * size, j * size
    else:
        top0, top1 = i * size + n, j * size + n
    bot0, bot1 = base + edge * size + i, base + edge * size + j
    tris = np.concatenate([np.stack([top0, bot0, top1], -1), np.stack([top1, bot0, bot1], -1)])
    return tris.reshape(-1)


@functools.lru_cache(maxsize=2)
def block_pieces(size: int) -> BlockPieces:
    """Every grid and skirt piece of tiles of ``size`` nodes (computed once: 354 grid
    pieces, 128 skirt pieces)."""
    _check_size(size)
    k = N_BLOCK_STRIDES
    chunks: list[np.ndarray] = []
    used = 0
    grid_start = np.zeros((k,) * 5, dtype=np.int64)
    grid_len = np.zeros((k,) * 5, dtype=np.int64)
    for si in range(k):
        for en in range(si, k):
            for es in range(si, k):
                for ew in range(si, k):
                    for ee in range(si, k):
                        edges = (1 << en, 1 << es, 1 << ew, 1 << ee)
                        piece = _grid_piece(size, 1 << si, edges)
                        grid_start[si, en, es, ew, ee] = used
                        grid_len[si, en, es, ew, ee] = len(piece)
                        chunks.append(piece)
                        used += len(piece)
    skirt_start = np.zeros((_EDGES, BLOCKS, k), dtype=np.int64)
    skirt_len = np.zeros((_EDGES, BLOCKS, k), dtype=np.int64)
    for edge in range(_EDGES):
        for pos in range(BLOCKS):
            for si in range(k):
                piece = _skirt_piece(size, edge, pos, 1 << si)
                skirt_start[edge, pos, si] = used
                skirt_len[edge, pos, si] = len(piece)
                chunks.append(piece)
                used += len(piece)
    out = BlockPieces(size, np.concatenate(chunks), grid_start, grid_len, skirt_start, skirt_len)
    for a in (out.table, grid_start, grid_len, skirt_start, skirt_len):
        a.flags.writeable = False
    return out


def _edge_strides(bs: np.ndarray, edges: np.ndarray | None) -> tuple[np.ndarray, ...]:
    """(north, south, west, east) edge stride indices (M, 8, 8) of every block of patterns
    ``bs``: the larger of the two blocks' strides inside the tile; on the tile's edges the
    block's own, or the stitched stride of ``edges`` (M, 4, 8) where it is not `SKIRTED`."""
    north = bs.copy()
    north[:, 1:] = np.maximum(bs[:, 1:], bs[:, :-1])
    south = bs.copy()
    south[:, :-1] = np.maximum(bs[:, :-1], bs[:, 1:])
    west = bs.copy()
    west[:, :, 1:] = np.maximum(bs[:, :, 1:], bs[:, :, :-1])
    east = bs.copy()
    east[:, :, :-1] = np.maximum(bs[:, :, :-1], bs[:, :, 1:])
    if edges is not None:
        for out, line in ((north[:, 0, :], 0), (south[:, -1, :], 1)):
            np.maximum(out, edges[:, line], out=out)
        for out, line in ((west[:, :, 0], 2), (east[:, :, -1], 3)):
            np.maximum(out, edges[:, line], out=out)
    return north, south, west, east


def _check_patterns(
    patterns: np.ndarray, edges: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """``patterns`` as (M, 8, 8) int64 and ``edges`` as (M, 4, 8) int64 (or None), checked:
    stride indices 0..3, tile edges `SKIRTED` or a stride no finer than the edge block's."""
    bs = np.asarray(patterns, dtype=np.int64).reshape(-1, BLOCKS, BLOCKS)
    if bs.size and (bs.min() < 0 or bs.max() >= N_BLOCK_STRIDES):
        raise ValueError("block stride indices must be 0..3")
    if edges is None:
        return bs, None
    ed = np.asarray(edges, dtype=np.int64).reshape(-1, _EDGES, BLOCKS)
    if len(ed) != len(bs):
        raise ValueError(f"{len(ed)} tile edges for {len(bs)} block patterns")
    own = np.stack([bs[:, 0, :], bs[:, -1, :], bs[:, :, 0], bs[:, :, -1]], axis=1)
    stitched = ed != SKIRTED
    if ((ed >= N_BLOCK_STRIDES) | (stitched & (ed < own))).any():
        raise ValueError("a tile edge stride must be -1 or 0..3, no finer than its block's")
    return bs, ed


def _segments(
    size: int, patterns: np.ndarray, edges: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M, 96) start in the piece table, length and node offset of each pattern's 64 grid
    pieces (blocks row-major) and 32 skirt pieces (north, south, west, east edges; length 0
    where ``edges`` stitches the edge block)."""
    p = block_pieces(size)
    bs, ed = _check_patterns(patterns, edges)
    north, south, west, east = _edge_strides(bs, ed)
    m = len(bs)
    g_start = p.grid_start[bs, north, south, west, east].reshape(m, -1)
    g_len = p.grid_len[bs, north, south, west, east].reshape(m, -1)
    bi, bj = np.divmod(np.arange(BLOCKS * BLOCKS), BLOCKS)
    g_off = np.broadcast_to(BLOCK_CELLS * (bi * size + bj), (m, BLOCKS * BLOCKS))
    pos = np.arange(BLOCKS)
    edge_strides = np.concatenate([bs[:, 0, :], bs[:, -1, :], bs[:, :, 0], bs[:, :, -1]], axis=1)
    edge = np.repeat(np.arange(_EDGES), BLOCKS)
    s_start = p.skirt_start[edge, np.tile(pos, _EDGES), edge_strides]
    s_len = p.skirt_len[edge, np.tile(pos, _EDGES), edge_strides]
    if ed is not None:
        s_len = np.where(ed.reshape(m, -1) == SKIRTED, s_len, 0)
    starts = np.concatenate([g_start, s_start], axis=1)
    lens = np.concatenate([g_len, s_len], axis=1)
    offs = np.concatenate([g_off, np.zeros_like(s_start)], axis=1)
    return starts, lens, offs


def pattern_counts(size: int, patterns: np.ndarray, edges: np.ndarray | None = None) -> np.ndarray:
    """(M,) int64 indices (3 per triangle) of each block pattern (M, 8, 8) over tiles of
    ``size`` nodes, with tile edges ``edges`` (M, 4, 8) or None (all skirted): what
    `pattern_indices` returns for it, skirts included."""
    _, lens, _ = _segments(size, patterns, edges)
    counts: np.ndarray = lens.sum(axis=1)
    return counts


def pattern_indices(
    size: int, patterns: np.ndarray, edges: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The triangle lists of block patterns (M, 8, 8) with tile edges ``edges`` (M, 4, 8)
    (None: every edge block skirted at its stride) over tiles of ``size`` nodes, as one
    uint32 array of the M lists one after the other and (M + 1,) int64 bounds (list i is
    ``out[bounds[i]:bounds[i + 1]]``). One gather over every piece of every pattern."""
    p = block_pieces(size)
    starts, lens, offs = _segments(size, patterns, edges)
    flat_len = lens.reshape(-1)
    total = int(flat_len.sum())
    seg_first = np.cumsum(flat_len) - flat_len  # where each segment lands in the output
    src = np.arange(total, dtype=np.int64) + np.repeat(starts.reshape(-1) - seg_first, flat_len)
    out = (p.table[src] + np.repeat(offs.reshape(-1), flat_len)).astype(np.uint32)
    bounds = np.concatenate([[0], np.cumsum(lens.sum(axis=1))]).astype(np.int64)
    return out, bounds
