"""Render sets from a traversal's tiles: index variants with pole fans, skirts and border
stitching (TREND §4.2.3, Rishe §3.3, Zhang Fig. 4), shared by the LOD policies.

A tile whose same-level neighbour is drawn at a coarser stride gets that edge drawn at the
neighbour's stride (`IndexVariant.edge_strides`), so the two share every edge vertex: no
T-junction, no crack. Tiles of different levels do not share heights (the coarser one is a
coarser approximation), so they meet behind skirts.
"""

from __future__ import annotations

import numpy as np

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
