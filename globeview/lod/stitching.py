"""Render sets from a traversal's tiles: index variants with pole fans, skirts and border
stitching (TREND §4.2.3, Rishe §3.3, Zhang Fig. 4), shared by the LOD policies.

A tile whose same-level neighbour is drawn at a coarser stride gets that edge drawn at the
neighbour's stride (`IndexVariant.edge_strides`), so the two share every edge vertex: no
T-junction, no crack. Tiles of different levels do not share heights (the coarser one is a
coarser approximation), so they meet behind skirts.

The default provider's sets go one step further in the renderer (`stitch_tile_edges`,
issue #27 item 3): an edge shared with a same-level neighbour is drawn by both tiles at the
larger of their strides per 8-cell edge block and has no skirt at all (skirts were over a
third of the triangles at the low benchmark views); only edges to other levels, pole tiles,
and a pattern beside a whole tile coarser than a block keep their skirts.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np

from globeview.lod.block_indices import BLOCKS, N_BLOCK_STRIDES, SKIRTED, pattern_counts
from globeview.lod.render_set import RenderSet
from globeview.lod.tile_indices import IndexVariant, Pole

#: `pole_codes` 0..3 -> `IndexVariant.pole`.
_POLES: tuple[Pole, ...] = (None, "north", "south", "both")


def pole_codes(keys: np.ndarray) -> np.ndarray:
    """(N,) 0 = no pole, 1 = the tile's first row is the north pole, 2 = its last row the
    south pole, 3 = both (a level-0 tile), for keys (N, 3) (level, x, y)."""
    return (keys[:, 2] == 0).astype(np.int64) + 2 * (keys[:, 2] == (1 << keys[:, 0]) - 1)


def _codes(level: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return (level.astype(np.int64) << 50) | (y.astype(np.int64) << 25) | x.astype(np.int64)


def neighbour_edge_strides(keys: np.ndarray, strides: np.ndarray) -> np.ndarray:
    """(N, 4) strides of each tile's (north, south, west, east) edge: the tile's own stride,
    or its same-level neighbour's when that one is drawn coarser (and present in the set).

    The two tiles then share exactly the coarse edge's vertices (same level: same samples).
    Neighbours at another level are left to the skirts.
    """
    keys = np.asarray(keys, dtype=np.int64)
    strides = np.asarray(strides, dtype=np.int64)
    level, x, y = keys[:, 0], keys[:, 1], keys[:, 2]
    codes = _codes(level, x, y)
    order = np.argsort(codes)
    sorted_codes = codes[order]
    ncols = 2 << level  # 2^(L+1) columns; longitude wraps
    nrows = 1 << level
    out = np.repeat(strides[:, None], 4, axis=1)
    for k, (dx, dy) in enumerate(((0, -1), (0, 1), (-1, 0), (1, 0))):  # four edges, not tiles
        ny = y + dy
        nx = (x + dx) % ncols
        valid = (ny >= 0) & (ny < nrows)
        nc = _codes(level, nx, np.clip(ny, 0, None))
        pos = np.clip(np.searchsorted(sorted_codes, nc), 0, len(codes) - 1)
        found = valid & (sorted_codes[pos] == nc) if len(codes) else valid
        nb_stride = np.where(found, strides[order[pos]], 0)
        out[:, k] = np.maximum(out[:, k], nb_stride)
    return out


def render_set_from_tiles(
    keys: np.ndarray,
    stride_idx: np.ndarray,
    error_px: np.ndarray,
    size: int,
    stitch: bool = True,
) -> RenderSet:
    """A RenderSet for tiles ``keys`` (N, 3) drawn at strides 2**stride_idx, with skirts,
    pole fans, and (``stitch``) edges stitched to coarser same-level neighbours; ``error_px``
    (N,) the projected error of each, ``size`` the tiles' nodes per side."""
    if len(keys) == 0:
        return RenderSet.empty()
    keys = np.asarray(keys, dtype=np.int64)
    stride_idx = np.asarray(stride_idx, dtype=np.int64)
    strides = 1 << stride_idx
    pole = pole_codes(keys)
    if stitch:
        edges = np.minimum(neighbour_edge_strides(keys, strides), size - 1)
    else:
        edges = np.repeat(strides[:, None], 4, axis=1)
    combo = np.concatenate([strides[:, None], pole[:, None], edges], axis=1)
    uniq, ids = np.unique(combo, axis=0, return_inverse=True)
    variants = []
    for s, p, en, es, ew, ee in uniq.tolist():  # one per distinct variant (a handful)
        e4 = (en, es, ew, ee)
        variants.append(
            IndexVariant(
                stride=s, skirts=True, pole=_POLES[p], edge_strides=None if max(e4) == s else e4
            )
        )
    return RenderSet(keys, ids.reshape(-1), variants, error_px=np.asarray(error_px, float))


def render_set_by_stride(
    keys: np.ndarray, stride_idx: np.ndarray, error_px: np.ndarray
) -> RenderSet:
    """A RenderSet for tiles drawn at strides 2**stride_idx with skirts and pole fans and no
    stitching (cracks between strides and levels hidden by the skirts): one variant per
    (stride, pole) pair, the chunked-sse way."""
    if len(keys) == 0:
        return RenderSet.empty()
    combo = np.asarray(stride_idx, dtype=np.int64) * 4 + pole_codes(keys)
    # = np.unique(combo, return_inverse=True) for these few small codes, without its sort.
    present = np.bincount(combo, minlength=1) > 0
    uniq = present.nonzero()[0]
    ids = (np.cumsum(present) - 1).take(combo)
    variants = [IndexVariant(stride=int(2 ** (c // 4)), pole=_POLES[c % 4]) for c in uniq]
    return RenderSet(keys, ids, variants, error_px=error_px)


# -- tile edges of the default provider's sets: stitched instead of skirted -------------------
#: The edge across each of a tile's (north, south, west, east) edges, and the tile offset
#: (dx, dy) of the neighbour there.
_OPPOSITE = (1, 0, 3, 2)
_STEPS = ((0, -1), (0, 1), (-1, 0), (1, 0))


@dataclass
class TileEdges:
    """How a set's tiles meet their same-level neighbours (`stitch_tile_edges`).

    blocks: (N, 8, 8) int8 block strides (`RenderSet.block_strides`), -1 rows drawn by
        their variant; tiles whose plain variant meets a patterned neighbour are drawn as a
        uniform pattern of their stride (the same triangles) so that their edge can follow
        the neighbour's blocks.
    edges: (N, 4, 8) int8 tile edges of the patterned rows (`block_indices.pattern_indices`:
        `SKIRTED`, or the stride index both tiles draw that edge block at).
    variant_ids, variants: the rows drawn by variants, with their stitched edges (edge
        strides and no skirt where stitched).
    stitched: (N, 4) bool: which (north, south, west, east) edges are stitched (no skirt).
    """

    blocks: np.ndarray
    edges: np.ndarray
    variant_ids: np.ndarray
    variants: list[IndexVariant]
    stitched: np.ndarray

    def index_counts(self, render_set: RenderSet, size: int) -> np.ndarray:
        """(N,) indices the renderer draws for each tile of ``render_set`` (the set these
        edges were stitched for) over tiles of ``size`` nodes: the frame's ``triangles``
        stat is their sum over three."""
        stitched = dataclasses.replace(
            render_set, variant_ids=self.variant_ids, variants=self.variants
        )
        counts = stitched.index_counts(size).copy()
        rows = np.flatnonzero(self.blocks[:, 0, 0] >= 0)
        if len(rows):
            counts[rows] = pattern_counts(size, self.blocks[rows], self.edges[rows])
        return counts


def plain_stride_idx(render_set: RenderSet) -> np.ndarray:
    """(N,) the stride index of each tile drawn by a plain variant (skirts, no pole, no
    stitched edges, no custom list: what the default provider draws), -1 for the others."""
    table = np.array(
        [
            int(v.stride).bit_length() - 1
            if v.pole is None and v.edge_strides is None and v.skirts and v.skirt_edges is None
            else -1
            for v in render_set.variants
        ],
        dtype=np.int64,
    )
    out = table[render_set.variant_ids] if len(render_set) else np.empty(0, np.int64)
    if render_set.custom_indices:
        out = out.copy()
        out[np.array(list(render_set.custom_indices), dtype=np.int64)] = -1
    return out


def same_level_neighbours(keys: np.ndarray, present: np.ndarray) -> np.ndarray:
    """(N, 4) row of each tile's same-level neighbour across its (north, south, west, east)
    edge among the rows ``present`` (N,) bool, -1 where there is none (longitude wraps)."""
    keys = np.asarray(keys, dtype=np.int64)
    level, x, y = keys[:, 0], keys[:, 1], keys[:, 2]
    rows = np.flatnonzero(present)
    codes = _codes(level[rows], x[rows], y[rows])
    order = np.argsort(codes)
    sorted_codes = codes[order]
    out = np.full((len(keys), 4), -1, dtype=np.int64)
    if not len(rows):
        return out
    for k, (dx, dy) in enumerate(_STEPS):
        ny = y + dy
        valid = present & (ny >= 0) & (ny < (1 << level))
        nc = _codes(level, (x + dx) % (2 << level), np.clip(ny, 0, None))
        pos = np.minimum(np.searchsorted(sorted_codes, nc), len(codes) - 1)
        found = valid & (sorted_codes[pos] == nc)
        out[:, k] = np.where(found, rows[order[pos]], -1)
    return out


def _edge_profiles(blocks: np.ndarray, stride_idx: np.ndarray) -> np.ndarray:
    """(N, 4, 8) stride index of each tile's edge blocks (north, south, west, east): the
    pattern's edge blocks, or the variant's stride all along."""
    prof = np.repeat(stride_idx[:, None, None], BLOCKS, axis=2).repeat(4, axis=1)
    rows = np.flatnonzero(blocks[:, 0, 0] >= 0)
    b = blocks[rows].astype(np.int64)
    prof[rows] = np.stack([b[:, 0, :], b[:, -1, :], b[:, :, 0], b[:, :, -1]], axis=1)
    return prof


def _fits(patterned: np.ndarray, e: np.ndarray) -> np.ndarray:
    """(M,) whether tiles can draw edges ``e`` (M, 8): a pattern any stride up to a block's
    (8), a variant one stride along the whole edge."""
    return np.where(patterned, e.max(axis=1) < N_BLOCK_STRIDES, (e == e[:, :1]).all(axis=1))


def stitch_tile_edges(render_set: RenderSet, blocks: np.ndarray | None) -> TileEdges:
    """The default provider's tiles with every edge shared with a same-level neighbour drawn
    by both at the larger of their strides there (per edge block; the same nodes, so no
    crack) and without skirts; other edges keep their skirts (`TileEdges`).

    ``blocks``: the (N, 8, 8) block strides the renderer chose (None: none). Only tiles
    drawn by plain variants or patterns take part (`plain_stride_idx`); an edge is stitched
    where both tiles can draw it: a pattern up to stride 8 per edge block, a variant one
    stride along the edge (so a pattern meets a variant of stride 16 or more behind skirts).
    """
    n = len(render_set)
    stride_idx = plain_stride_idx(render_set)
    out_blocks = np.full((n, BLOCKS, BLOCKS), -1, np.int8) if blocks is None else blocks.copy()
    eligible = stride_idx >= 0
    patterned = out_blocks[:, 0, 0] >= 0
    nb = same_level_neighbours(render_set.keys, eligible)
    # A variant tile of stride up to 8 beside a pattern becomes a uniform pattern.
    near_pattern = ((nb >= 0) & patterned[np.maximum(nb, 0)]).any(axis=1)
    convert = eligible & ~patterned & (stride_idx < N_BLOCK_STRIDES) & near_pattern
    out_blocks[convert] = stride_idx[convert, None, None].astype(np.int8)
    patterned |= convert
    prof = _edge_profiles(out_blocks, stride_idx)
    edges = np.full((n, 4, BLOCKS), SKIRTED, dtype=np.int8)
    var_edges = np.repeat(np.maximum(stride_idx, 0)[:, None], 4, axis=1)
    stitched = np.zeros((n, 4), dtype=bool)
    for k in range(4):
        rows = np.flatnonzero(nb[:, k] >= 0)
        other = nb[rows, k]
        e = np.maximum(prof[rows, k], prof[other, _OPPOSITE[k]])
        ok = _fits(patterned[rows], e) & _fits(patterned[other], e)
        rows, e = rows[ok], e[ok]
        stitched[rows, k] = True
        edges[rows, k] = e
        var_edges[rows, k] = e[:, 0]
    edges[~patterned] = SKIRTED
    drawn_by_variant = eligible & ~patterned
    ids, variants = _stitched_variants(
        render_set, drawn_by_variant, stride_idx, var_edges, stitched
    )
    return TileEdges(out_blocks, edges, ids, variants, stitched)


def _stitched_variants(
    render_set: RenderSet,
    plain: np.ndarray,
    stride_idx: np.ndarray,
    var_edges: np.ndarray,
    stitched: np.ndarray,
) -> tuple[np.ndarray, list[IndexVariant]]:
    """The set's variant ids and variants with the rows ``plain`` (N,) drawn with stitched
    edges: edge strides ``var_edges`` (N, 4) stride indices, no skirt where ``stitched``.
    Each row's variant is one small integer code (3 bits a stride index, a bit a skirt), so
    a frame's distinct ones (~100 at the low views) come from one 1-D unique."""
    n_old = len(render_set.variants)
    fields = np.concatenate([stride_idx[:, None], var_edges, stitched], axis=1)[plain]
    codes = (fields.astype(np.int64) << _CODE_SHIFTS).sum(axis=1)
    uniq, inv = np.unique(codes, return_inverse=True)
    variants = list(render_set.variants)
    variants.extend(_variant_of(int(c)) for c in uniq.tolist())
    ids = np.asarray(render_set.variant_ids, dtype=np.int64).copy()
    ids[plain] = n_old + inv.reshape(-1)
    return ids, variants


#: Bit offsets of a stitched variant's code: stride index, four edge stride indices (3 bits
#: each), four stitched flags (a bit each).
_CODE_SHIFTS = np.array([0, 3, 6, 9, 12, 15, 16, 17, 18], dtype=np.int64)


@functools.lru_cache(maxsize=4096)
def _variant_of(code: int) -> IndexVariant:
    """The `IndexVariant` of a stitched variant's code (`_stitched_variants`)."""
    s, en, es, ew, ee = ((code >> int(k)) & 7 for k in _CODE_SHIFTS[:5])
    flags = tuple(not (code >> int(k)) & 1 for k in _CODE_SHIFTS[5:])
    e4 = (1 << en, 1 << es, 1 << ew, 1 << ee)
    return IndexVariant(
        stride=1 << s,
        edge_strides=None if max(e4) == 1 << s else e4,
        skirt_edges=None if all(flags) else (flags[0], flags[1], flags[2], flags[3]),
    )
