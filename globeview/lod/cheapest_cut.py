"""The cheapest cut of the visited quadtree: which tiles to draw so that every tile meets the
screen-space error threshold with the fewest triangles (chunked-sse's ``min_triangles``).

A top-down walk that refines a tile only when it cannot meet tau is not monotone in tau and
wastes triangles: a tile whose nearest corner needs stride 1 is drawn whole at stride 1
(8 704 triangles at 65 x 65 nodes) where its four children - farther away, or culled, or with
smoother data - could be drawn at coarse strides for a fraction of that. So the walk visits
(`ScreenSpaceErrorPolicy` with ``min_triangles``) the children of every tile that could be
drawn cheaper, and this module picks, bottom-up, per visited tile::

    T(t) = own(t)                                 t not refined by the walk (a leaf)
    T(t) = sum T(c) over t's visible children     t must refine (error > tau, texels)
    T(t) = min(own(t), sum T(c))                  otherwise

``own(t)`` = triangles of t at the coarsest stride within tau (`variant_triangles`).

A refined tile none of whose children is visible covers no pixel (its children's tighter
culling tests all failed, and together they cover it), so any stride is within tau there: it
is drawn at its coarsest stride (one cell, ``floor(t)`` triangles) with error 0 px, whatever
tau is. (The plain walk draws nothing there. Drawing nothing would break monotony: whether a
tile is refined, and so found empty, depends on tau, and an unrefined one costs at least
``floor``.)

Why it is monotone in tau (triangles never grow as tau grows): own(t, tau) does not grow
with tau (the set of strides within tau only grows, and coarser strides cost fewer
triangles), whether a tile *must* refine only turns from yes to no, the visible children do
not depend on tau, so by induction from the deepest level T(t, tau) is a minimum of terms
none of which grows (an empty tile costs ``floor`` at every tau, the least an unrefined
tile costs). The walk's pruning is exact: it does not visit the children of a tile
whose own cost is the cheapest any visible tile can have (stride = whole tile), which no
non-empty set of visible children beats; the tiles it leaves out for other reasons (far
and smooth, deep past the data) are left out at every tau, so they are leaves at every tau.

Where the argument holds: a tile budget that pruned the visited tree by anything that
depends on tau would break it, so the walk has none (`ScreenSpaceErrorPolicy` counts the
tiles visited and gives up past its budget, drawing the plain walk), and the cut's own
budget (`cut_within_budget`) keeps the cut only while it fits; a cut traded for fewer
tiles, and the plain walk, are not monotone in tau.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class VisitedLevel:
    """One level's visited tiles as the policy judged them (arrays (N,) unless noted).

    keys: (N, 3) int64 rows (level, x, y); stride_idx: the coarsest stride index within tau
    (0 where none is); own: triangles at that stride; must: the tile had to refine (error
    over tau at stride 1, or texels magnified); error_px: the projected error at stride_idx;
    asked: what the policy answered (refine); the walk may have refined fewer (budgets);
    floor: triangles at the coarsest stride, index ``coarsest``.
    """

    keys: np.ndarray
    stride_idx: np.ndarray
    own: np.ndarray
    must: np.ndarray
    error_px: np.ndarray
    asked: np.ndarray
    floor: np.ndarray
    coarsest: int


def _xy_codes(keys: np.ndarray, shift: int = 0) -> np.ndarray:
    """int64 codes of the (x >> shift, y >> shift) of one level's keys."""
    return ((keys[:, 1] >> shift) << 31) | (keys[:, 2] >> shift)


def _refined(lv: VisitedLevel, leaves: np.ndarray, n_leaves: int) -> np.ndarray:
    """(N,) which of the level's tiles the walk refined: those it did not draw (``leaves``,
    the (K, 3) drawn keys of this level, ``n_leaves`` of them). The walk draws the tiles it
    was not asked to refine plus those a budget kept from refining, so when the counts
    agree no budget bound and the policy's answer is the walk's."""
    if int(np.count_nonzero(~lv.asked)) == n_leaves:
        return lv.asked
    return ~np.isin(_xy_codes(lv.keys), _xy_codes(leaves))


def cheapest_cut(
    levels: list[VisitedLevel], leaf_keys: np.ndarray, per_tile: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tiles to draw (module docstring): (keys (M, 3), stride_idx (M,), error_px (M,),
    hidden (M,) bool: refined tiles with no visible child, drawn at their coarsest stride).

    ``levels`` are the walk's visited levels, consecutive and top-down (the first holds the
    roots); ``leaf_keys`` (K, 3) the tiles the walk drew, i.e. did not refine (the others it
    refined: their visible children are the next level's tiles). ``per_tile``: a cost in
    triangles added per drawn tile (a Lagrange multiplier that trades triangles for fewer
    tiles, `cut_within_budget`). Vectorised per level.
    """
    levels = [lv for lv in levels if len(lv.keys)]
    if not levels:
        e = np.empty(0, dtype=np.int64)
        return np.empty((0, 3), dtype=np.int64), e, np.empty(0), np.empty(0, dtype=bool)
    leaf_keys = np.asarray(leaf_keys, dtype=np.int64).reshape(-1, 3)
    first = int(levels[0].keys[0, 0])
    per_level = np.bincount(leaf_keys[:, 0] - first, minlength=len(levels))
    # Bottom-up: T (cost) and whether each tile draws its children instead of itself
    # (split); parent[i] the row of each tile of level i in level i - 1.
    n = len(levels)
    cost: list[np.ndarray] = [np.empty(0)] * n
    split: list[np.ndarray] = [np.empty(0, dtype=bool)] * n
    empty: list[np.ndarray] = [np.empty(0, dtype=bool)] * n
    parent: list[np.ndarray] = [np.empty(0, dtype=np.int64)] * n
    for i in range(n - 1, -1, -1):
        lv = levels[i]
        k = int(per_level[i]) if i < len(per_level) else 0
        leaves = leaf_keys[leaf_keys[:, 0] == first + i] if k != len(lv.keys) else leaf_keys[:0]
        refined = _refined(lv, leaves, k) if k != len(lv.keys) else np.zeros(len(lv.keys), bool)
        own = lv.own + per_tile
        csum: np.ndarray = np.zeros(len(own))
        n_vis: np.ndarray = np.zeros(len(own), dtype=np.int64)
        if i + 1 < n:
            codes = _xy_codes(lv.keys)
            order = np.argsort(codes)
            at = np.searchsorted(codes.take(order), _xy_codes(levels[i + 1].keys, 1))
            parent[i + 1] = order.take(np.minimum(at, len(codes) - 1))
            csum = np.bincount(parent[i + 1], weights=cost[i + 1], minlength=len(own))
            n_vis = np.bincount(parent[i + 1], minlength=len(own))
        empty[i] = refined & (n_vis == 0)
        split[i] = refined & ~empty[i] & (lv.must | (csum < own))
        cost[i] = np.where(split[i], csum, np.where(empty[i], lv.floor + per_tile, own))
    # Top-down: a tile is drawn when its parent split and was itself reached (every root is
    # reached) and it does not split itself.
    out_k, out_s, out_e, out_h = [], [], [], []
    reached = np.ones(len(levels[0].keys), dtype=bool)
    for i, lv in enumerate(levels):
        if i > 0:
            reached = (reached & split[i - 1]).take(parent[i])
        draw = reached & ~split[i]
        hidden = empty[i].compress(draw)
        out_k.append(lv.keys[draw])
        out_s.append(np.where(hidden, lv.coarsest, lv.stride_idx.compress(draw)))
        out_e.append(np.where(hidden, 0.0, lv.error_px.compress(draw)))
        out_h.append(hidden)
    cat = np.concatenate
    return cat(out_k), cat(out_s), cat(out_e), cat(out_h)


#: `cheapest_cut`'s per-tile cost that makes it the fewest-tiles cut: more than any difference
#: in triangles (at most `render_set.MAX_TILES` tiles of at most ~10 000 triangles each), so
#: a cut with fewer tiles always costs less, and small enough that the sums (<= ~2e13) stay
#: exact integers in float64.
FEWEST_TILES = 1e9


def cut_within_budget(
    levels: list[VisitedLevel], leaf_keys: np.ndarray, max_tiles: int | None
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], str]:
    """`cheapest_cut` held to ``max_tiles`` tiles, and how (the second item):

    - ``"free"``: the cheapest cut draws at most ``max_tiles``; it is returned;
    - ``"over"``: even the cut with the fewest tiles (only the tiles that must refine do)
      draws more; that cut is returned (one pass, found before any search: the caller draws
      something else, `ScreenSpaceErrorPolicy.render_set`);
    - ``"traded"``: the cut with the smallest per-tile cost (bisected, a dozen passes) that
      draws at most ``max_tiles``: the fewest triangles for that many tiles, near enough.
      Here the cut is no longer monotone in tau (the multiplier depends on tau).
    """
    cut = cheapest_cut(levels, leaf_keys)
    if max_tiles is None or len(cut[0]) <= max_tiles:
        return cut, "free"
    best = cheapest_cut(levels, leaf_keys, FEWEST_TILES)
    if len(best[0]) > max_tiles:
        return best, "over"
    lo, hi = 0.0, 1.0
    while hi < FEWEST_TILES:
        trial = cheapest_cut(levels, leaf_keys, hi)
        if len(trial[0]) <= max_tiles:
            best = trial
            break
        lo, hi = hi, hi * 8.0
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        trial = cheapest_cut(levels, leaf_keys, mid)
        if len(trial[0]) <= max_tiles:
            hi, best = mid, trial
        else:
            lo = mid
    return best, "traded"
