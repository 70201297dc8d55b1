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

from globeview.lod.candidates import all_ancestors


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


# -- the flat walk's cut: parent pointers, many multipliers a pass ----------------------------
@dataclass
class CutTree:
    """The flat walk's tree (`candidates.TreeRows`, level-major, in the walk's order within a
    level, candidates not visited included) with what the cut reads per row (arrays (N,)):
    ``parent`` the parent's row (-1: a root), ``level``, ``visited``, ``refined`` (the walk
    refined it) and `VisitedLevel`'s ``stride_idx``, ``own``, ``must``, ``error_px``,
    ``floor`` and ``coarsest``; ``keys`` (N, 3); ``jumps`` `candidates.ancestor_jumps` of
    the rows. Rows not visited cost nothing and are never drawn."""

    keys: np.ndarray
    level: np.ndarray
    parent: np.ndarray
    visited: np.ndarray
    refined: np.ndarray
    stride_idx: np.ndarray
    own: np.ndarray
    must: np.ndarray
    error_px: np.ndarray
    floor: np.ndarray
    coarsest: int
    jumps: list[np.ndarray]

    def __post_init__(self) -> None:
        n = len(self.level)
        first = int(self.level[0]) if n else 0
        last = int(self.level[-1]) if n else -1
        # Rows of level first + i: starts[i]:starts[i + 1] (rows are level-major).
        self.starts: list[int] = np.searchsorted(self.level, np.arange(first, last + 2)).tolist()
        # A parent's row relative to the start of its level (for the per-level bincounts).
        par = np.maximum(self.parent, 0)
        self.parent_local = par - np.take(self.starts, np.maximum(self.level - first - 1, 0))
        n_vis = np.bincount(par.compress(self.visited & (self.parent >= 0)), minlength=n)
        # A refined tile with no visible child covers no pixel (module docstring).
        self.empty = self.refined & (n_vis == 0)
        self.splittable = self.refined & ~self.empty
        # Levels with a tile that may split (the others keep their own cost).
        self.split_levels = np.bincount(
            self.level.compress(self.splittable) - first, minlength=len(self.starts)
        ).tolist()
        self.base = np.where(self.empty, self.floor, self.own) * self.visited
        # A tile splits where its children cost less than this: +inf where it must (any
        # finite sum is less), -inf where it may not (none is).
        self.split_below = np.where(self.splittable, np.where(self.must, np.inf, 0.0), -np.inf)


def cut_costs(tree: CutTree, per_tile: np.ndarray, count: bool) -> tuple[np.ndarray, np.ndarray]:
    """`cheapest_cut`'s bottom-up pass for K per-tile costs at once: (split (N, K) bool: the
    tile draws its children instead of itself, tiles (K,) int: how many tiles each cut
    draws, only with ``count``, else zeros). One loop over the levels with a tile that may
    split, ~5 numpy calls a level whatever K (the K costs of a level's children are summed
    by one bincount).

    The costs are integers (triangles) plus multiples of the per-tile cost, dyadic
    rationals with few bits (`cut_within_budget`'s), so every sum is exact in float64 and
    the comparisons do not depend on the order of the additions: the same cut as
    `cheapest_cut` for each per-tile cost."""
    n, k = len(tree.level), len(per_tile)
    vis = tree.visited
    # Rows not visited cost nothing (their parent's sum skips them) and count no tile.
    base = tree.base[:, None] + per_tile[None, :] * vis[:, None]
    # Split where the children cost less than the tile drawn itself (split_below: must
    # refine, may not): split = splittable & (must | csum < base), one comparison.
    below = np.where(tree.split_below[:, None] == 0.0, base, tree.split_below[:, None])
    cost = base.copy()
    split = np.zeros((n, k), dtype=bool)
    tiles = np.repeat(vis[:, None].astype(np.float64), k, axis=1) if count else None
    s = tree.starts
    cols = np.arange(k)
    pl = tree.parent_local
    for i in range(len(s) - 3, -1, -1):
        a, b, c = s[i], s[i + 1], s[i + 2]
        if c == b or not tree.split_levels[i]:
            continue
        m = b - a
        if k == 1:  # the common case, without the reshapes
            at = pl[b:c]
            csum = np.bincount(at, weights=cost[b:c, 0], minlength=m)[:, None]
        else:
            at = (pl[b:c, None] * k + cols).ravel()
            csum = np.bincount(at, weights=cost[b:c].ravel(), minlength=m * k).reshape(m, k)
        sp = split[a:b] = csum < below[a:b]
        cost[a:b] = np.where(sp, csum, base[a:b])
        if tiles is not None:
            ct = np.bincount(at, weights=tiles[b:c].ravel(), minlength=m * k).reshape(m, k)
            tiles[a:b] = np.where(sp, ct, tiles[a:b])
    if tiles is None:
        return split, np.zeros(k, dtype=np.int64)
    return split, tiles.compress(tree.parent < 0, axis=0).sum(axis=0).astype(np.int64)


def cut_of(
    tree: CutTree, split: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The tiles of the cut ``split`` (N,) bool (one column of `cut_costs`): `cheapest_cut`'s
    result, in the same order. A tile is drawn when every ancestor splits and it does not
    (pointer jumping, `candidates.all_ancestors`)."""
    draw = tree.visited & ~split & all_ancestors(split, tree.parent, tree.jumps)
    hidden = tree.empty.compress(draw)
    stride = np.where(hidden, tree.coarsest, tree.stride_idx.compress(draw))
    error = np.where(hidden, 0.0, tree.error_px.compress(draw))
    return tree.keys.compress(draw, axis=0), stride, error, hidden


#: Grid of one pass of the budget search: 2**_GRID_BITS - 1 points of a bracket a pass, and
#: 12 / _GRID_BITS passes = `cut_within_budget`'s 12 halvings (its grid, the same floats).
#: Few points a pass: a pass costs about its fixed per-level calls plus K times the rows,
#: so 4 passes of 7 points cost less than 2 of 63 on a 600-tile cut.
_GRID_BITS = 3
_GRID = 1 << _GRID_BITS
_PASSES = 12 // _GRID_BITS
#: The bracket's ends: 0, then the powers of 8 below FEWEST_TILES (`cut_within_budget`).
_POWERS = 8.0 ** np.arange(10)


def cut_within_budget_flat(
    tree: CutTree, max_tiles: int | None, memo: dict
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], str]:
    """`cut_within_budget` on the flat walk's tree: the same cut and case, in a few passes
    of `cut_costs` with many per-tile costs each instead of ~16 one after the other.

    The bisection's result is the least point of a dyadic grid in its bracket whose cut fits
    the budget, when the tiles a cut draws never grow with the per-tile cost (true of an
    exact minimiser: `tests/lod/test_flat_walk.py` checks it on trading views). So: one
    pass at 0 and FEWEST_TILES (free, over); the ten powers of 8 (the bracket); then
    `_PASSES` passes of the `_GRID` - 1 inner points of the bracket left (12 halvings in
    all: the same grid, the same floats). A pass whose counts do grow (a counter-example)
    falls back to the bisection.

    Warm start: ``memo`` keeps the last traded multiplier and its grid step; where that
    cut still fits and the point below does not, it is the answer (two more columns in the
    first pass, no search)."""
    warm = memo.get("cut_multiplier")
    if max_tiles is None or not warm:
        # The common case first: the cheapest cut, counted as drawn.
        split, _ = cut_costs(tree, np.zeros(1), False)
        cut = cut_of(tree, split[:, 0])
        if max_tiles is None or len(cut[0]) <= max_tiles:
            return cut, "free"
    lams = [0.0, FEWEST_TILES] + ([warm[0], warm[0] - warm[1]] if warm else [])
    split, tiles = cut_costs(tree, np.array(lams), True)
    if tiles[0] <= max_tiles:
        memo.pop("cut_multiplier", None)
        return cut_of(tree, split[:, 0]), "free"
    if tiles[1] > max_tiles:
        memo.pop("cut_multiplier", None)
        return cut_of(tree, split[:, 1]), "over"
    if warm and tiles[2] <= max_tiles < tiles[3]:
        return cut_of(tree, split[:, 2]), "traded"
    found = _search(tree, max_tiles, split[:, 1])
    if found is None:
        found = _bisect(tree, max_tiles, split[:, 1])
    best, value, step = found
    if step is None:
        memo.pop("cut_multiplier", None)
    else:
        memo["cut_multiplier"] = (value, step)
    return cut_of(tree, best), "traded"


def _first_fit(tree: CutTree, lams: np.ndarray, max_tiles: int) -> tuple[int, np.ndarray] | None:
    """(index of the least of ``lams`` (ascending) whose cut fits, the splits (N, K)), K
    when none does; None when the counts grow somewhere (not monotone)."""
    split, tiles = cut_costs(tree, lams, True)
    if np.any(np.diff(tiles) > 0):
        return None
    fits = tiles <= max_tiles
    return (int(np.argmax(fits)) if fits.any() else len(lams)), split


def _search(
    tree: CutTree, max_tiles: int, fewest: np.ndarray
) -> tuple[np.ndarray, float, float | None] | None:
    """The vectorised bisection (`cut_within_budget_flat`): (split of the answer, its per-tile
    cost, the grid step there (None: the answer is the fewest-tiles cut)); None: a pass was
    not monotone."""
    got = _first_fit(tree, _POWERS, max_tiles)
    if got is None:
        return None
    j, split = got
    if j < len(_POWERS):
        lo, hi, hi_split, hi_value = (
            (0.0 if j == 0 else _POWERS[j - 1]),
            _POWERS[j],
            split[:, j],
            _POWERS[j],
        )
    else:
        # No power of 8 fits: the bisection runs between 8**9 and 8**10 and keeps the
        # fewest-tiles cut where no point fits.
        lo, hi, hi_split, hi_value = _POWERS[-1], _POWERS[-1] * 8.0, fewest, FEWEST_TILES
    step: float | None = None
    for _ in range(_PASSES):
        step = (hi - lo) / _GRID
        pts = lo + step * np.arange(1, _GRID)
        got = _first_fit(tree, pts, max_tiles)
        if got is None:
            return None
        i, split = got
        if i < len(pts):
            lo, hi, hi_split, hi_value = pts[i] - step, pts[i], split[:, i], pts[i]
        else:
            lo = pts[-1]
    return hi_split, float(hi_value), (step if hi_value != FEWEST_TILES else None)


def _bisect(
    tree: CutTree, max_tiles: int, fewest: np.ndarray
) -> tuple[np.ndarray, float, float | None]:
    """`cut_within_budget`'s sequential bracket and bisection on the flat tree (the fallback
    where counts were found to grow with the per-tile cost)."""

    def fits(lam: float) -> tuple[bool, np.ndarray]:
        split, tiles = cut_costs(tree, np.array([lam]), True)
        return bool(tiles[0] <= max_tiles), split[:, 0]

    best, value = fewest, FEWEST_TILES
    lo, hi = 0.0, 1.0
    while hi < FEWEST_TILES:
        ok, split = fits(hi)
        if ok:
            best, value = split, hi
            break
        lo, hi = hi, hi * 8.0
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        ok, split = fits(mid)
        if ok:
            hi, best, value = mid, split, mid
        else:
            lo = mid
    return best, value, None
