"""`ScreenSpaceErrorPolicy`: chunked screen-space-error selection, the built-in default
policy (chunked-sse's and the tile choice of quadtree-clod), on the shared traversal.

It lives apart from the `LodPolicy` interface (`globeview.lod.policy`) because it walks the
quadtree itself when its fewest-triangles cut is over budget (`traverse` with a plain
policy): the traversal imports the interface, this module imports the traversal.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from globeview.lod.candidates import MAX_LEVEL, Selection, TileCandidates, TreeRows
from globeview.lod.cheapest_cut import (
    CutTree,
    VisitedLevel,
    cut_within_budget,
    cut_within_budget_flat,
)
from globeview.lod.flat_walk import SelectionState
from globeview.lod.policy import LodPolicy, coarsest_stride_within
from globeview.lod.render_set import MAX_TILES, RenderSet
from globeview.lod.stitching import render_set_by_stride
from globeview.lod.tile_indices import IndexVariant, Pole, grid_indices
from globeview.lod.traversal import traverse
from globeview.lod.view_state import ViewState
from globeview.terrain.compose.metadata import N_STRIDES
from globeview.terrain.compose.stack import TerrainStack
from globeview.validate import TAU_RANGE_PX

__all__ = [
    "BEYOND_DATA_LEVELS",
    "NEAR_RATIO",
    "WALK_BUDGET",
    "ScreenSpaceErrorPolicy",
    "variant_triangles",
]

#: How many levels below the finest data *under each tile* (where ``has_finer`` turns false)
#: the fewest-triangles cut may look: tiles there are their ancestor's data upsampled, and
#: splitting a tile whose near corner needs a fine stride lets its far children draw coarser.
BEYOND_DATA_LEVELS = 4
#: The walk's budget with min_triangles, in tiles visited, in units of the cut's budget
#: (`ScreenSpaceErrorPolicy`): a bound on its work (the benchmark views visit 40-640 tiles;
#: exaggeration 30 at 5 km in the White Mountains would visit over 5 000).
WALK_BUDGET = 8
#: Tiles nearer than this many tile widths are worth visiting the children of whatever their
#: error (`ScreenSpaceErrorPolicy.refine`).
NEAR_RATIO = 4.0
#: `variant_triangles` for a stride beyond the tile's grid (never the cheapest choice).
_NO_VARIANT = 1 << 40
#: Width (m) of a tile of each level on a sphere of the mean radius (what `_tile_m` computes
#: for one level, the same floats), for the flat walk's rows of many levels.
_TILE_M = np.array([math.radians(180.0 / 2**level) * 6.371e6 for level in range(MAX_LEVEL + 1)])
#: What a subclass must leave as they are for the policy to stay `LodPolicy.per_tile`.
_PER_TILE_METHODS = ("cull", "error_px", "refine", "priority", "stride", "_must_refine")


#: `_judges_per_tile`'s answers, per class (asked once per frame: policies are made per frame).
_PER_TILE_CLASSES: dict[type, bool] = {}


def _judges_per_tile(cls: type) -> bool:
    """Whether ``cls`` judges tiles as `ScreenSpaceErrorPolicy` does (so it is per tile): a
    subclass overriding how could keep values across levels."""
    got = _PER_TILE_CLASSES.get(cls)
    if got is None:
        base = ScreenSpaceErrorPolicy
        got = _PER_TILE_CLASSES[cls] = all(
            getattr(cls, m) is getattr(base, m) for m in _PER_TILE_METHODS
        )
    return got


def _tile_m(level: int | np.ndarray) -> float | np.ndarray:
    """The width (m) of a tile of ``level`` (an int, or an array of levels: per row) on a
    sphere of the mean radius."""
    if isinstance(level, np.ndarray):
        return _TILE_M.take(level)
    return math.radians(180.0 / 2**level) * 6.371e6


@functools.lru_cache(maxsize=4)
def variant_triangles(size: int) -> np.ndarray:
    """(N_STRIDES, 4) triangles of a tile of ``size`` nodes per side drawn at stride 2**i with
    skirts (`render_set_by_stride`'s variants) and pole code p (`pole_codes`: none, north,
    south, both); `_NO_VARIANT` where the stride exceeds the grid. Read-only."""
    poles: tuple[Pole, ...] = (None, "north", "south", "both")
    out = np.full((N_STRIDES, 4), _NO_VARIANT, dtype=np.int64)
    for i in range(N_STRIDES):
        if (size - 1) % (1 << i) == 0:
            for p, pole in enumerate(poles):
                out[i, p] = len(grid_indices(size, IndexVariant(stride=1 << i, pole=pole))) // 3
    out.flags.writeable = False
    return out


class ScreenSpaceErrorPolicy(LodPolicy):
    """Chunked screen-space-error selection (TREND §4.2, Cesium style): the built-in default.

    1. a tile's geometric error at stride s (height error x exaggeration + the chord sag of
       the curved ellipsoid between vertices s nodes apart, `tile_cache.stride_errors_m`) is
       projected to pixels, ``e * K / d`` with K = viewport height / (2 tan(fovy/2)) and d a
       lower bound of the distance to the tile;
    2. refine (replace by its four children) when that exceeds tau at stride 1, or when the
       tile's texels would be magnified beyond ``texel_px`` pixels and finer data exists;
    3. draw the others with the coarsest index stride whose error still projects below tau
       (TREND's per-block resolution pyramid, applied to the whole tile);
    4. a budget of ``max_tiles`` drawn tiles: past it, the worst tiles refine first.

    With ``min_triangles`` (chunked-sse's default) step 2 also visits the children of every
    tile that could be drawn cheaper (its stride is not the whole tile), down to
    `BEYOND_DATA_LEVELS` below the finest data, and the tiles drawn are the cheapest cut of
    that tree (`cheapest_cut`): the fewest triangles meeting tau. Budgets, and where the
    guarantee "never more triangles as tau grows" holds (render set stats say which case a
    frame is in):

    - the walk visits at most `WALK_BUDGET` x ``max_tiles`` tiles (counted in `refine`, no
      pruning: the tree visited is the same as without a budget, or the walk stops); a view
      tau cannot meet within it, or whose fewest-tiles cut draws more than ``max_tiles``, is
      drawn by the plain walk above (stat ``cut_over_budget``). Both counts never grow with
      tau, so these views are those under some tau*: one interval of a tau ladder;
    - where the cheapest cut draws more than ``max_tiles`` but the fewest-tiles cut does
      not, the cut trades triangles for tiles (stat ``cut_traded``, `cut_within_budget`);
    - otherwise (no stat; every benchmark view at exaggeration 1 and the default budget)
      the cut is drawn as is, every tile within tau, and its triangles never grow with tau
      over any range of tau drawn this way (the argument in `globeview.lod.cheapest_cut`).
      Across the cases it may: the plain walk is not monotone in tau (the reason for the
      cut), and it leaves tiles over tau where the cut at a larger tau draws them finer.

    Cracks between tiles drawn at different levels or strides are hidden by skirts.

    It is `LodPolicy.per_tile` (unless a subclass overrides how it judges tiles): with a
    selection state the flat walk selects for it, the walk's budget and the fewest-tiles
    bound become `stop_level`, and the cut is taken on the flat tree with parent pointers
    (`cheapest_cut.cut_within_budget_flat`), the budget's multiplier warm-started from the
    last frame's.
    """

    def __init__(
        self,
        tau_px: float | None = None,
        texel_px: float = 1.5,
        max_tiles: int = 600,
        min_triangles: bool = False,
    ) -> None:
        super().__init__(tau_px)
        self.texel_px = float(texel_px)
        self.min_triangles = bool(min_triangles)
        # With min_triangles the budget bounds the cut (`cut_within_budget`), and the walk gets
        # WALK_BUDGET times as much (a bound on its work), held by `refine` itself, not the
        # traversal's budget: that one prunes by a priority, which would make the tree visited,
        # and so the cut, depend on tau. A walk that would pass it stops and the plain walk is
        # drawn instead (`render_set`).
        self.tile_budget = int(max_tiles)
        self._walk_budget = min(WALK_BUDGET * self.tile_budget, MAX_TILES)
        self.max_tiles = None if self.min_triangles else self.tile_budget
        self._cut = self.min_triangles
        self._visited: list[VisitedLevel] = []
        self._hidden = 0
        self._seen = 0
        self._over = False
        self.per_tile = _judges_per_tile(type(self))

    def begin(self, view: ViewState, terrain: TerrainStack) -> None:
        super().begin(view, terrain)
        self._cut = self.min_triangles
        self.max_tiles = None if self._cut else self.tile_budget
        self._visited = []
        # Tiles the walk has visited so far, and whether it passed _walk_budget.
        self._seen = 0
        self._over = False
        # The last level's tiles: has_finer and levels past the data (_levels_past_data).
        self._finer: np.ndarray | None = None
        self._past_data: np.ndarray | None = None
        # This level's parent rows (_parent_rows), and the fewest-tiles cut's lower bound:
        # the last level's tiles it refines (must, all ancestors must too; None at the roots)
        # and the tiles it draws at the levels above (`refine`).
        self._parents: np.ndarray | None = None
        self._fewest_refines: np.ndarray | None = None
        self._fewest_drawn = 0
        # The flat walk's (`_refine_flat`): whether it selects, and the coarsest stride.
        self._flat = False
        self._coarsest = 0

    def _parent_rows(self, keys: np.ndarray) -> np.ndarray:
        """(N,) the row of each tile's parent in the last level visited (tiles of a level are
        children of refined tiles of the one before), computed once per level."""
        if self._parents is None:
            prev = self._visited[-1].keys
            codes = (prev[:, 1] << 31) | prev[:, 2]
            order = np.argsort(codes)
            at = np.searchsorted(codes.take(order), ((keys[:, 1] >> 1) << 31) | (keys[:, 2] >> 1))
            self._parents = order.take(np.minimum(at, len(codes) - 1))
        return self._parents

    def _levels_past_data(self, keys: np.ndarray, has_finer: np.ndarray) -> np.ndarray:
        """(N,) how many levels each tile lies below the finest data under it (0 within
        the data: its level is the data's or coarser), from its parent's, the last level
        visited (tiles of a level are children of refined tiles of the one before)."""
        prev = self._visited[-1] if self._visited else None
        finer = self._finer
        if prev is None or self._past_data is None or finer is None or finer.all():
            # Every parent had finer data below it (the common case above the data's depth).
            return np.zeros(len(keys), dtype=np.int64)
        parent = self._parent_rows(keys)
        up = self._past_data.take(parent)
        # A parent with finer data below it has this tile within the data.
        return np.where(finer.take(parent), 0, up + 1)

    def _fewest_over(self, keys: np.ndarray, must: np.ndarray) -> bool:
        """Whether the fewest-tiles cut (`cut_within_budget`: only tiles that must refine
        do) is sure to draw more than ``tile_budget`` tiles, from the levels walked so far:
        it draws each tile it reaches that need not refine, and at least one tile for each
        it refines (a lower bound). Also keeps the bound's state for the next level."""
        prev = self._fewest_refines
        if prev is None or prev.all():
            refines = must  # every parent refined in the fewest-tiles cut (the roots: none)
            self._fewest_drawn += len(must) - int(np.count_nonzero(must))
        elif not prev.any():
            refines = np.zeros(len(must), dtype=bool)
        else:
            reached = prev.take(self._parent_rows(keys))
            refines = reached & must
            self._fewest_drawn += int(np.count_nonzero(reached & ~must))
        self._fewest_refines = refines
        return self._fewest_drawn + int(np.count_nonzero(refines)) > self.tile_budget

    def frame_stats(self) -> dict[str, Any]:
        if not self._cut:
            return {}
        # The level walk's visited levels add up to _seen; the flat walk has only the count.
        visited = self._seen if self._flat else sum(len(v.keys) for v in self._visited)
        return {"tiles_visited": visited, "tiles_hidden": self._hidden}

    def _must_refine(self, tiles: TileCandidates, error_px: np.ndarray) -> np.ndarray:
        # A texel of the tile's height/normal textures: the level's tile width (m, on a
        # sphere of the mean radius) over its cells, projected.
        tile_m = _tile_m(tiles.level)
        texel = tile_m / (tiles.size - 1) * tiles.px_per_m
        return (error_px[:, 0] > self.tau_px) | ((texel > self.texel_px) & tiles.has_finer)

    def _explore(
        self,
        tiles: TileCandidates,
        error_px: np.ndarray,
        pole: np.ndarray,
        past: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
        """(stride index, own triangles, whether to visit the children for the cut, the
        floor (one cell), the coarsest stride index) of each tile (`refine`)."""
        idx = coarsest_stride_within(error_px, self.tau_px)
        table = variant_triangles(tiles.size)
        own = table[idx, pole]
        coarsest = int(np.flatnonzero(table[:, 0] < _NO_VARIANT)[-1])
        # Which tiles' children to visit. All that could be drawn cheaper (own over the one
        # cell, the least any visible child costs) would be exact (cheapest_cut) but visits
        # thousands of tiles whose children rarely pay, so only those within the data or
        # BEYOND_DATA_LEVELS past it, and near
        # ones (NEAR_RATIO tile widths) or far ones with a stride-1 error over the smallest
        # tau a view accepts. A tile these leave out is one that no tau makes refine for its
        # error (texels do not depend on tau), so whether it is a leaf does not depend on
        # tau and the cut stays monotone in tau.
        tile_m = _tile_m(tiles.level)
        may_refine = error_px[:, 0] > TAU_RANGE_PX[0]
        worth = (tiles.dist_m < NEAR_RATIO * tile_m) | may_refine
        deeper = tiles.has_finer | (past < BEYOND_DATA_LEVELS) | may_refine
        floor = table[coarsest, pole]
        explore = deeper & worth & (own > floor)
        return idx, own, explore, floor, coarsest

    def refine(self, tiles: TileCandidates, error_px: np.ndarray) -> np.ndarray:
        must = self._must_refine(tiles, error_px)
        if not self._cut:
            return must
        if tiles.flat:
            return self._refine_flat(tiles, error_px, must)
        self._parents = None
        if self._fewest_over(tiles.keys, must):
            # The fewest-tiles cut will draw more than the cut's budget (`render_set` would
            # find so after the walk, `cut_within_budget`): stop now.
            self._over = True
            return np.zeros(len(must), dtype=bool)
        keys = tiles.keys
        y = keys[:, 2]
        # = pole_codes(keys) for one level, without its casts (a dozen calls per frame).
        pole = (y == 0) + 2 * (y == (1 << tiles.level) - 1)
        has_finer = tiles.has_finer
        past = self._levels_past_data(keys, has_finer)
        idx, own, explore, floor, coarsest = self._explore(tiles, error_px, pole, past)
        if tiles.view.displace is not None:
            # Not where a displacement (a tool's, e.g. the collapse) bends the tile: culling
            # tests displaced bounding lattices, which a fold likely bends past between their
            # points, and a cut that keeps some children and drops culled ones opened a hole
            # at the collapse's fold (tests/collapse). The bend does not depend on tau; where
            # it is zero (an identity displacement, or away from the folds) nothing changes.
            explore &= tiles.bend_m <= 0.0
        rows = np.arange(len(idx))
        asked = must | explore
        self._visited.append(
            VisitedLevel(keys, idx, own, must, error_px[rows, idx], asked, floor, coarsest)
        )
        self._finer, self._past_data = has_finer, past
        # The walk's budget, all or nothing: past it the walk stops here and `render_set` draws
        # the plain walk. It counts the tiles visited so far and the refined tiles' four
        # children each: a larger tau asks fewer tiles to refine (must and own only shrink), so
        # it visits a subtree of what a smaller tau visits, and a view within the budget at
        # one tau is within it at every larger tau. The tiles a walk within it visits do not
        # depend on the budget.
        m = len(asked)
        n_ref = int(np.count_nonzero(asked)) if tiles.level < min(self.max_level, MAX_LEVEL) else 0
        self._seen += m
        if self._seen + 4 * n_ref > self._walk_budget:
            self._over = True
            return np.zeros(m, dtype=bool)
        return asked

    def _refine_flat(
        self, tiles: TileCandidates, error_px: np.ndarray, must: np.ndarray
    ) -> np.ndarray:
        """`refine` on the flat walk's rows (several levels, no displacement): what to visit
        for the cut, per tile, and the values the cut reads kept in ``scratch`` per row; the
        walk's budget and the fewest-tiles bound are `stop_level`'s."""
        idx, own, explore, floor, coarsest = self._explore(
            tiles, error_px, tiles.pole, tiles.levels_past_data
        )
        rows = np.arange(len(idx))
        tiles.scratch.update(
            must=must, stride_idx=idx, own=own, floor=floor, cut_error_px=error_px[rows, idx]
        )
        self._flat, self._coarsest = True, coarsest
        return must | explore

    def stop_level(self, rows: TreeRows) -> int | None:
        """With min_triangles: the level where the level walk's `refine` stops (the
        fewest-tiles cut sure to pass ``tile_budget``, or the walk's budget passed), from
        per-level counts of the tree (module docstring of `globeview.lod.flat_walk`)."""
        self._over = False
        if not self._cut or not len(rows):
            return None
        vis, level = rows.visited, rows.level
        n_vis = int(np.count_nonzero(vis))
        n_ref = int(np.count_nonzero(vis & rows.refine))
        if n_vis <= self.tile_budget and n_vis + 4 * n_ref <= self._walk_budget:
            # Neither bound can pass (each counts a part of these at some level).
            self._seen = n_vis
            return None
        must = rows.scratch["must"]
        n = MAX_LEVEL + 2

        def per_level(mask: np.ndarray) -> np.ndarray:
            return np.bincount(level.compress(mask), minlength=n)

        # The fewest-tiles cut reaches the visible tiles all of whose ancestors must refine;
        # it draws those that need not and at least one tile for each that must
        # (`_fewest_over`): by level L, the first sum over the levels to L, the second L's.
        reached = vis & rows.all_ancestors(must)
        fewest = np.cumsum(per_level(reached & ~must)) + per_level(reached & must)
        fewest_over = fewest > self.tile_budget
        # The walk's budget: the tiles visited to L and the four children of L's refined.
        seen = per_level(vis)
        walk_over = np.cumsum(seen) + 4 * per_level(vis & rows.refine) > self._walk_budget
        over = fewest_over | walk_over
        if not over.any():
            self._seen = int(seen.sum())
            return None
        stop = int(np.argmax(over))
        self._over = True
        # The level walk keeps the stop level's tiles as visited unless the bound stopped it.
        self._seen = int(seen[:stop].sum()) + (0 if fewest_over[stop] else int(seen[stop]))
        return stop

    def stride(self, tiles: TileCandidates, error_px: np.ndarray, index: np.ndarray) -> np.ndarray:
        if tiles.flat and "stride_idx" in tiles.scratch:
            # `refine` computed it for every row (`_explore`: the same formula).
            return tiles.scratch["stride_idx"].take(index)
        return super().stride(tiles, error_px, index)

    def _render_set_flat(self, selection: Selection) -> RenderSet:
        """`render_set` after the flat walk: the cut of its tree, or the plain walk where a
        bound stopped it (with its own selection state)."""
        assert selection.tree is not None  # the flat walk's
        tree = selection.tree()
        if self._over:
            assert self.view is not None and self.terrain is not None  # set by begin
            plain = ScreenSpaceErrorPolicy(self.tau_px, self.texel_px, self.tile_budget)
            state = tree.memo.get("plain")
            if not isinstance(state, SelectionState):
                state = tree.memo["plain"] = SelectionState()
            rs = traverse(self.view, self.terrain, plain, state=state)
            rs.stats["cut_over_budget"] = 1.0
            return rs
        sc = tree.scratch
        cut = CutTree(
            tree.keys, tree.level, tree.parent, tree.visited, tree.refine, sc["stride_idx"],
            sc["own"], sc["must"], sc["cut_error_px"], sc["floor"], self._coarsest, tree.jumps,
        )  # fmt: skip
        (keys, stride_idx, error_px, hidden), how = cut_within_budget_flat(
            cut, self.tile_budget, tree.memo
        )
        if how == "over":
            self._over = True
            return self._render_set_flat(selection)
        self._hidden = int(np.count_nonzero(hidden))
        rs = render_set_by_stride(keys, stride_idx, error_px)
        rs.block_tau_px = self.tau_px  # the renderer draws blocks coarser where tau allows
        if how == "traded":
            rs.stats["cut_traded"] = 1.0
        return rs

    def render_set(self, selection: Selection, size: int) -> RenderSet:
        if not self._cut:
            return super().render_set(selection, size)
        if selection.tree is not None:
            return self._render_set_flat(selection)
        how = "over"
        if not self._over:
            (keys, stride_idx, error_px, hidden), how = cut_within_budget(
                self._visited, selection.keys, self.tile_budget
            )
        if how == "over":
            # The walk passed its budget, or tau asks for more tiles than the cut's even with
            # the fewest tiles (an extreme exaggeration or tau): the plain walk, whose budget
            # refines the worst tiles first and leaves the rest over tau, as without
            # min_triangles. Both are found early (the walk stops, `cut_within_budget` tries
            # the fewest-tiles cut first), so this costs about one plain walk more.
            assert self.view is not None and self.terrain is not None  # set by begin
            plain = ScreenSpaceErrorPolicy(self.tau_px, self.texel_px, self.tile_budget)
            rs = traverse(self.view, self.terrain, plain)
            rs.stats["cut_over_budget"] = 1.0
            return rs
        self._hidden = int(np.count_nonzero(hidden))
        rs = render_set_by_stride(keys, stride_idx, error_px)
        rs.block_tau_px = self.tau_px  # the renderer draws blocks coarser where tau allows
        if how == "traded":
            rs.stats["cut_traded"] = 1.0
        return rs
