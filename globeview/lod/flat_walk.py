"""The flat, incremental quadtree walk: the traversal of a `LodPolicy.per_tile` policy with a
selection state (`traverse(..., state=)`), the same selection as the level-by-level walk
(`globeview.lod.traversal`) in a fraction of its numpy calls (issue #27 item 1).

The level walk pays ~200 numpy calls a level over 15 levels on arrays of 1-350 tiles: per-call
overhead, not work. From one frame to the next most tiles keep their level, so a
`SelectionState` keeps last frame's **candidate tree S** (the roots and the four children of
every tile the walk refined, visible or not), each row with copies of its camera-independent
facts (`tile_cache.TileCache.facts_of`), and a frame is:

1. **evaluate** every row of S in one pass, all levels together: frustum (prefilter, then the
   exact planes of the ambiguous rows), horizon, distance and the policy's answers, the same
   element-wise operations as the level walk on the same operands, so the same floats;
2. **reach**: a row is visited iff it is visible and every ancestor is visible and refines
   (pointer jumping over the parent rows, `candidates.all_ancestors`: no loop over levels);
3. **grow** where the tree is short: visited rows that refine and whose children are not in S
   get them (`TileCache.children_across`: the facts of the misses in one call a level), which
   are evaluated (step 1 on the new rows only) and reached (step 2); repeated until nothing
   grows. A turning camera needs no round; a far jump grows one level a round. An empty
   state (a first frame, a new terrain) is not grown from the roots: `traverse` walks level
   by level then and seeds S from that walk (`SelectionState.seed`), made into rows only if
   a next frame comes;
4. **budgets after the fact**: the policy's stop (`LodPolicy.stop_level`) and the tile budgets
   (`LodPolicy.max_tiles`, `render_set.MAX_TILES`) are per-level counts of the visited tree; a
   level walk takes each decision at the first level where a count passes its bound, and the
   full tree agrees with it on every level above, so the decision is the same. Where a tile
   budget binds, the levels from there are walked one by one (`_FlatWalk._budget_walk`, the
   level walk's rule on S's rows, growing S as it goes);
5. **prune**: S keeps the roots and the children of the rows refined; it is compacted when over
   a quarter of its rows are dead.

Order: every row carries its *walk key*, the digits of its path from the root (child index
c = dx + 2 dy, the deepest the most significant): within a level the level walk visits the
tiles in that order (children of the refined tiles child index first, then by their parent's
order), so the tiles drawn come out level by level in the level walk's order, and the budget
of a level sees its tiles in the same order (its ties fall the same way).

Not here: a displacement (a tool's ``view.displace``: the level walk caches displaced
lattices per tile) and policies that are not `LodPolicy.per_tile` walk level by level.
Frames and units as in the traversal: ECEF metres, pixels.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from globeview.lod.cached_culling import (
    HORIZON_TOL,
    FrustumFrame,
    frustum_prefilter,
    horizon_visible_cached,
)
from globeview.lod.candidates import (
    MAX_LEVEL,
    Selection,
    TileCandidates,
    TreeRows,
    all_ancestors,
    ancestor_jumps,
)
from globeview.lod.culling import horizon_cap, norm3
from globeview.lod.policy import LodPolicy
from globeview.lod.render_set import MAX_TILES
from globeview.lod.tile_cache import COL_MARGIN, COL_RADIUS, COL_SPHERE, TileCache
from globeview.lod.view_state import ViewState
from globeview.lod.walk_rules import BOOL, F64, I64, budget_refinement, checked
from globeview.terrain.compose.metadata import N_STRIDES
from globeview.terrain.compose.stack import TerrainStack

__all__ = ["SelectionState", "select_flat"]

#: Bits of the walk key (`_Rows.wkey` < 2 * 4**level <= 2**45): the order key is level << 46
#: | walk key, level-major.
_WKEY_BITS = 46
#: S is compacted when more than this share of its rows is dead.
_DEAD_SHARE = 0.25


class _Rows:
    """The candidate tree S: per row the tile's ``level``, its ``slot`` in the tile cache's
    level table, its ``parent`` row (-1: a root), its walk key ``wkey`` (module docstring),
    ``kids`` (whether its four children are rows) and copies of its cache facts (``xy``,
    ``cols`` (N_COLS, N), ``pts``, ``centre``, ``err``, ``herr``, ``finer``, ``pole``,
    ``past``: the attributes `TileCandidates` reads by slot, so rows are its slots).
    Immutable once built: growing, sorting and compacting make new ones. Between frames
    the rows are level-major in the walk's order (`order_key`); growth appends, and the
    frame sorts once at its end."""

    FACTS = ("xy", "pts", "centre", "err", "herr", "finer", "pole", "past")

    def __init__(
        self,
        level: np.ndarray,
        slot: np.ndarray,
        parent: np.ndarray,
        wkey: np.ndarray,
        kids: np.ndarray,
        facts: dict[str, np.ndarray],
    ) -> None:
        self.level, self.slot, self.parent, self.wkey, self.kids = level, slot, parent, wkey, kids
        self.cols: np.ndarray = facts["cols"]
        self.xy: np.ndarray = facts["xy"]
        self.pts: np.ndarray = facts["pts"]
        self.centre: np.ndarray = facts["centre"]
        self.err: np.ndarray = facts["err"]
        self.herr: np.ndarray = facts["herr"]
        self.finer: np.ndarray = facts["finer"]
        self.pole: np.ndarray = facts["pole"]
        self.past: np.ndarray = facts["past"]
        self.n = len(level)
        self._jumps: list[np.ndarray] | None = None

    @property
    def root(self) -> np.ndarray:
        return self.parent < 0

    @property
    def jumps(self) -> list[np.ndarray]:
        """`candidates.ancestor_jumps` of the rows (computed once per tree)."""
        if self._jumps is None:
            self._jumps = ancestor_jumps(self.parent, self.level)
        return self._jumps

    @property
    def cached_jumps(self) -> list[np.ndarray] | None:
        """`jumps` if computed already (a tree grown this frame has none yet)."""
        return self._jumps

    @property
    def order_key(self) -> np.ndarray:
        """Level-major walk order: level << 46 | walk key."""
        return (self.level << _WKEY_BITS) | self.wkey

    def _facts(self) -> dict[str, np.ndarray]:
        return {"cols": self.cols, **{k: getattr(self, k) for k in self.FACTS}}

    def append(self, new: _Rows, grown: np.ndarray) -> _Rows:
        """These rows, then ``new`` (whose parents are rows here); ``grown`` the rows whose
        children ``new`` holds."""
        cat = np.concatenate
        kids = self.kids.copy()
        kids[grown] = True
        a, b = self._facts(), new._facts()
        facts = {k: cat([a[k], b[k]], axis=1 if k == "cols" else 0) for k in a}
        return _Rows(
            cat([self.level, new.level]),
            cat([self.slot, new.slot]),
            cat([self.parent, new.parent]),
            cat([self.wkey, new.wkey]),
            cat([kids, new.kids]),
            facts,
        )

    def permute(self, order: np.ndarray) -> _Rows:
        """The rows in ``order`` (a permutation), parents renumbered."""
        new_of = np.empty(self.n, dtype=np.int64)
        new_of[order] = np.arange(self.n)
        parent = self.parent.take(order)
        parent = np.where(parent < 0, -1, new_of.take(np.maximum(parent, 0)))
        facts = {k: v.take(order, axis=1 if k == "cols" else 0) for k, v in self._facts().items()}
        return _Rows(
            self.level.take(order),
            self.slot.take(order),
            parent,
            self.wkey.take(order),
            self.kids.take(order),
            facts,
        )

    def compact(self, keep: np.ndarray, kids: np.ndarray) -> _Rows:
        """The rows ``keep`` (parents of kept rows kept), parents renumbered; ``kids`` the
        new kids flags (of all rows)."""
        idx = np.flatnonzero(keep)
        new_of = np.cumsum(keep) - 1
        parent = self.parent.take(idx)
        parent = np.where(parent < 0, -1, new_of.take(np.maximum(parent, 0)))
        facts = {k: v.take(idx, axis=1 if k == "cols" else 0) for k, v in self._facts().items()}
        return _Rows(
            self.level.take(idx),
            self.slot.take(idx),
            parent,
            self.wkey.take(idx),
            kids.take(idx),
            facts,
        )


def _root_rows(cache: TileCache, terrain: TerrainStack, size: int) -> _Rows:
    """S of an empty state: the two level-0 tiles."""
    slots = cache.roots(terrain, size)
    facts = cache.facts_of(0, slots)
    n = len(slots)
    return _Rows(
        np.zeros(n, dtype=np.int64),
        slots,
        np.full(n, -1, dtype=np.int64),
        facts["xy"][:, 0].astype(np.int64),  # the roots' walk order: x
        np.zeros(n, dtype=bool),
        facts,
    )


def _rows_from_walk(
    cache: TileCache, terrain: TerrainStack, record: list[tuple[int, np.ndarray, np.ndarray]]
) -> _Rows:
    """The rows of S a level walk's ``record`` describes (`SelectionState.seed`): a level's
    candidates are the children of the last level's refined tiles, child index major, then
    in their parents' order (`TileCache.children`), so each row's parent and walk key
    follow from its position."""
    if not record:
        return _root_rows(cache, terrain, terrain.tile_size)
    parts: list[tuple[np.ndarray, ...]] = []
    facts: list[dict[str, np.ndarray]] = []
    offset = 0
    up_rows = up_wkey = np.empty(0, dtype=np.int64)
    for level, slots, refined in record:
        n = len(slots)
        f = cache.facts_of(level, slots)
        if level == 0:
            parent = np.full(n, -1, dtype=np.int64)
            wkey = f["xy"][:, 0].astype(np.int64)  # the roots' walk order: x
        else:
            k = len(up_rows)
            c = np.repeat(np.arange(4, dtype=np.int64), k)
            parent = np.tile(up_rows, 4)
            wkey = (c << (2 * (level - 1) + 1)) | np.tile(up_wkey, 4)
        kids = np.zeros(n, dtype=bool)
        if len(refined):  # refined is a subsequence of slots (distinct slots of one level)
            hit = np.zeros(int(slots.max()) + 1, dtype=bool)
            hit[refined] = True
            kids = hit.take(slots)
        up = np.flatnonzero(kids)
        up_rows, up_wkey = up + offset, wkey.take(up)
        parts.append((np.full(n, level, dtype=np.int64), slots, parent, wkey, kids))
        facts.append(f)
        offset += n
    cat = np.concatenate
    level_, slot, parent_, wkey_, kids_ = (cat([p[i] for p in parts]) for i in range(5))
    merged = {k: cat([f[k] for f in facts], axis=1 if k == "cols" else 0) for k in facts[0]}
    return _Rows(level_, slot, parent_, wkey_, kids_, merged)


class SelectionState:
    """What the flat walk keeps from one frame to the next for one provider (`traverse`'s
    ``state``): the candidate tree S, valid for one tile cache epoch (a new terrain, layers,
    tile size or exaggeration start it afresh), a ``memo`` the policy may keep values in
    (`TreeRows.memo`: chunked-sse's last budget multiplier and the state of its plain-walk
    fallback), and the last frame's counts ``stats`` (``lod_rounds``: growth rounds,
    ``lod_rows_new``: rows added, ``lod_rows``: rows evaluated).

    Any S gives the same selection (rows a frame does not reach are ignored, missing ones
    grown), so nothing else invalidates it: only the cost depends on it. One provider's: not
    shared between threads."""

    def __init__(self) -> None:
        self.memo: dict[str, Any] = {}
        self.stats: dict[str, float] = {}
        self._rows: _Rows | None = None
        self._cache: weakref.ref | None = None
        self._epoch = -1
        # A level walk's record of the tree (`seed`), made into rows when a frame needs them.
        self._record: list[tuple[int, np.ndarray, np.ndarray]] | None = None

    def reset(self) -> None:
        """Forget everything (the next frame starts from the roots)."""
        self._rows, self._cache, self._epoch, self._record = None, None, -1, None
        self.memo.clear()
        self.stats.clear()

    @property
    def rows(self) -> int:
        """Rows of S kept."""
        if self._rows is None:
            return 0 if self._record is None else sum(len(r[1]) for r in self._record)
        return self._rows.n

    def cold(self, cache: TileCache) -> bool:
        """Whether there is no S for ``cache`` (none kept, or kept for another cache or an
        earlier epoch of it)."""
        ref = self._cache
        held = self._rows is not None or self._record is not None
        return not held or ref is None or ref() is not cache or self._epoch != cache.epoch

    def tree(self, cache: TileCache, terrain: TerrainStack, size: int) -> _Rows:
        """S for this frame: last frame's when the cache is the same one in the same epoch,
        else the roots."""
        if self.cold(cache):
            rows = _root_rows(cache, terrain, size)
        elif self._rows is None:
            assert self._record is not None  # not cold: one of them is held
            rows = _rows_from_walk(cache, terrain, self._record)
        else:
            rows = self._rows
        self._rows, self._record = rows, None
        self._cache, self._epoch = weakref.ref(cache), cache.epoch
        return rows

    def seed(self, cache: TileCache, record: list[tuple[int, np.ndarray, np.ndarray]]) -> None:
        """Keep a level walk's ``record`` (`traversal._walk`: per level the candidate slots
        and the slots refined, in the walk's order) as S: the tree a flat walk would have
        grown from the roots for the same frame (the roots and the children of the tiles
        refined). A cold state's frame is the level walk (growing from the roots, one round
        a level, costs more), and the rows are made only when a next frame needs them
        (`tree`): a single headless frame pays nothing for them."""
        self._rows, self._record = None, record
        self._cache, self._epoch = weakref.ref(cache), cache.epoch
        self.stats = {
            "lod_rounds": 0.0,
            "lod_rows_new": float(self.rows),
            "lod_rows": 0.0,
            "lod_cold": 1.0,
        }

    def keep(self, rows: _Rows) -> None:
        """S for the next frame."""
        self._rows = rows


@dataclass
class _Eval:
    """One evaluation of rows (step 1): ``vis_f`` frustum-visible, ``vis_fh`` and the horizon,
    ``vis`` and the policy's cull; ``dist`` (m), ``ppm`` (px per m), ``sse`` (N, N_STRIDES)
    the policy's errors (px), ``asked`` its refine, ``scratch`` its per-row values."""

    vis_f: np.ndarray
    vis_fh: np.ndarray
    vis: np.ndarray
    dist: np.ndarray
    ppm: np.ndarray
    sse: np.ndarray
    asked: np.ndarray
    scratch: dict[str, Any]

    def append(self, new: _Eval) -> _Eval:
        cat = np.concatenate
        n = len(self.vis)
        scratch = dict(self.scratch)
        for k, v in new.scratch.items():
            old = self.scratch.get(k)
            if (
                isinstance(v, np.ndarray)
                and isinstance(old, np.ndarray)
                and v.ndim >= 1
                and old.ndim >= 1
                and old.shape[0] == n
                and v.shape[0] == len(new.vis)
            ):
                scratch[k] = cat([old, v])
            elif k not in scratch:
                scratch[k] = v
        return _Eval(
            cat([self.vis_f, new.vis_f]),
            cat([self.vis_fh, new.vis_fh]),
            cat([self.vis, new.vis]),
            cat([self.dist, new.dist]),
            cat([self.ppm, new.ppm]),
            cat([self.sse, new.sse]),
            cat([self.asked, new.asked]),
            scratch,
        )


def _permute_eval(ev: _Eval, order: np.ndarray) -> _Eval:
    """``ev`` with its rows in ``order`` (the per-row scratch arrays too)."""
    n = len(ev.vis)
    scratch = {
        k: v.take(order, axis=0) if isinstance(v, np.ndarray) and v.ndim >= 1 and
        v.shape[0] == n else v
        for k, v in ev.scratch.items()
    }  # fmt: skip
    return _Eval(
        ev.vis_f.take(order), ev.vis_fh.take(order), ev.vis.take(order), ev.dist.take(order),
        ev.ppm.take(order), ev.sse.take(order, axis=0), ev.asked.take(order), scratch,
    )  # fmt: skip


class _FlatWalk:
    """One frame of the flat walk (module docstring) for ``policy`` (begun) over ``terrain``;
    `run` returns the `Selection`."""

    def __init__(
        self,
        view: ViewState,
        terrain: TerrainStack,
        policy: LodPolicy,
        cache: TileCache,
        state: SelectionState,
    ) -> None:
        self.view, self.terrain, self.policy, self.cache, self.state = (
            view,
            terrain,
            policy,
            cache,
            state,
        )
        self.size = terrain.tile_size
        self.frame = FrustumFrame(view)
        self.cap = horizon_cap(view)  # None: eye at or below the ellipsoid, nothing hidden
        self.u0 = None
        if self.cap is not None and self.cap > 1e3 * HORIZON_TOL:
            lon0, lat0 = np.radians(view.eye_lonlat_h[:2])
            self.u0 = np.array(
                [np.cos(lat0) * np.cos(lon0), np.cos(lat0) * np.sin(lon0), np.sin(lat0)]
            )
        self.max_level = min(int(policy.max_level), MAX_LEVEL)
        # The level walk's budgets (traversal._walk): the policy's soft one, MAX_TILES strict.
        self.soft = None if policy.max_tiles is None else min(int(policy.max_tiles), MAX_TILES)
        self.rounds = 0
        self.rows_new = 0
        self.rows_evaluated = 0

    # -- step 1 ---------------------------------------------------------------------------------
    def candidates(
        self, rows: _Rows, ev_dist: np.ndarray, ppm: np.ndarray, scratch: dict[str, Any]
    ) -> TileCandidates:
        """The policy's view of every row of ``rows`` (`TileCandidates.flat`)."""
        return TileCandidates(
            self.view, self.terrain, rows.level, self.size, np.arange(rows.n), rows.cols,
            ev_dist, ppm, rows.err, None, None, rows, None, scratch,
        )  # fmt: skip

    def evaluate(self, rows: _Rows) -> _Eval:
        """Step 1 on ``rows``: the level walk's tests and the policy's answers, all levels
        at once."""
        n = rows.n
        self.rows_evaluated += n
        c = rows.cols
        rel = rows.centre - self.view.eye
        vis_f, amb, open_p = frustum_prefilter(self.frame, rel, c[COL_MARGIN], c[COL_SPHERE])
        if np.count_nonzero(amb):
            ai = amb.nonzero()[0]
            vis_f[ai] = self.frame.exact_planes(
                rows.pts.take(ai, axis=0), c[COL_MARGIN].take(ai), open_p.take(ai, axis=0)
            )
        vis_fh = vis_f.copy()
        if self.cap is not None:
            fi = vis_f.nonzero()[0]
            if len(fi):
                vis_fh[fi] = horizon_visible_cached(
                    self.view, self.cap, c.take(fi, axis=1), self.u0
                )
        dist = np.maximum(norm3(rel) - c[COL_RADIUS], 1.0)
        ppm = self.view.sse_factor / dist
        tiles = self.candidates(rows, dist, ppm, {})
        p = self.policy
        keep = checked(p, "cull", p.cull(tiles), (n,), BOOL, none_ok=True)
        vis = vis_fh if keep is None else vis_fh & keep
        sse = checked(p, "error_px", p.error_px(tiles), (n, N_STRIDES), F64)
        asked = checked(p, "refine", p.refine(tiles, sse), (n,), BOOL)
        return _Eval(vis_f, vis_fh, vis, dist, ppm, sse, asked, tiles.scratch)

    # -- step 3 ---------------------------------------------------------------------------------
    def grow(self, rows: _Rows, ev: _Eval, at: np.ndarray) -> tuple[_Rows, _Eval]:
        """S with the four children of rows ``at`` added and evaluated."""
        lv, slot, pi, c, facts = self.cache.children_across(
            self.terrain, rows.level.take(at), rows.slot.take(at), self.size
        )
        parent = at.take(pi)
        # The child's digit is the most significant of its walk key: 2 * 4**parent level.
        wkey = (c << (2 * rows.level.take(parent) + 1)) | rows.wkey.take(parent)
        new = _Rows(lv, slot, parent, wkey, np.zeros(len(lv), dtype=bool), facts)
        self.rounds += 1
        self.rows_new += new.n
        return rows.append(new, at), ev.append(self.evaluate(new))

    # -- steps 2 and 4 ----------------------------------------------------------------------------
    def refinable(self, rows: _Rows, ev: _Eval, cap: int) -> np.ndarray:
        return ev.asked & (rows.level < cap)

    def stop(
        self, rows: _Rows, ev: _Eval, reach: np.ndarray, refine: np.ndarray
    ) -> tuple[int, np.ndarray]:
        """(the level from which nothing refines: ``max_level`` or the policy's stop, the
        rows visited down to it), from the rows visited and refining as if nothing stopped
        the walk (``reach``, ``refine``)."""
        tree = TreeRows(
            np.empty((0, 3), dtype=np.int64), rows.level, rows.parent, reach, refine,
            ev.scratch, self.state.memo, rows.cached_jumps,
        )  # fmt: skip
        stop = self.policy.stop_level(tree)
        if stop is None or stop >= self.max_level:
            return self.max_level, reach
        return int(stop), reach & (rows.level <= stop)

    def first_bound(self, rows: _Rows, reach: np.ndarray, refine: np.ndarray) -> int | None:
        """The first level where the level walk's tile budget would bind (traversal._walk:
        the policy's soft budget, then MAX_TILES strictly), from the per-level counts of the
        tree visited without budgets; None: nowhere."""
        n_vis = int(np.count_nonzero(reach))
        bound = MAX_TILES if self.soft is None else self.soft
        if 4 * n_vis <= bound:  # drawn + m + 3 n_ref <= 4 x visited: cannot pass
            return None
        lv = rows.level.compress(reach)
        m = np.bincount(lv, minlength=MAX_LEVEL + 1)
        r = np.bincount(lv, weights=refine.compress(reach), minlength=MAX_LEVEL + 1)
        drawn_before = np.cumsum(m - r) - (m - r)
        binds = (r > 0) & (drawn_before + m + 3 * r > bound)
        if not binds.any():
            return None
        return int(np.argmax(binds))

    # -- the frame --------------------------------------------------------------------------
    def run(self) -> Selection:
        rows = self.state.tree(self.cache, self.terrain, self.size)
        ev = self.evaluate(rows)
        # What the walk visits and refines as if nothing stopped it (step 2); rows grown
        # are children of rows visited and refining, so theirs follow from their own tests.
        refine0 = self.refinable(rows, ev, self.max_level)
        reach0 = ev.vis & all_ancestors(ev.vis & refine0, rows.parent, rows.jumps)
        while True:
            cap, reach = self.stop(rows, ev, reach0, refine0)
            refine = refine0 if cap >= self.max_level else refine0 & (rows.level < cap)
            bound = self.first_bound(rows, reach, refine)
            # Rows below the level a budget binds at are the budget walk's to grow.
            limit = cap if bound is None else bound
            grow = reach & refine & ~rows.kids & (rows.level < limit)
            if not grow.any():
                break
            n0 = rows.n
            rows, ev = self.grow(rows, ev, np.flatnonzero(grow))
            new_level, new_ev = rows.level[n0:], ev.asked[n0:]
            refine0 = np.concatenate([refine0, new_ev & (new_level < self.max_level)])
            reach0 = np.concatenate([reach0, ev.vis[n0:]])
        if bound is None:
            visited, refined = reach, reach & refine
        else:
            rows, ev, visited, refined = self._budget_walk(rows, ev, reach, refine, bound, cap)
        if self.rounds:
            # Level-major walk order again (grown rows were appended): the tiles drawn and
            # the visited tree come out in the level walk's order, and the next frame
            # starts sorted.
            order = np.argsort(rows.order_key)
            rows, ev = rows.permute(order), _permute_eval(ev, order)
            visited, refined = visited.take(order), refined.take(order)
        sel = self._selection(rows, ev, visited, refined)
        self._prune(rows, refined)
        self.state.stats = {
            "lod_rounds": float(self.rounds),
            "lod_rows_new": float(self.rows_new),
            "lod_rows": float(self.rows_evaluated),
        }
        return sel

    def _budget_walk(
        self,
        rows: _Rows,
        ev: _Eval,
        reach: np.ndarray,
        refine: np.ndarray,
        bound: int,
        cap: int,
    ) -> tuple[_Rows, _Eval, np.ndarray, np.ndarray]:
        """The level walk's budget from level ``bound`` down (traversal._walk, step 4), over
        S's rows in walk order, growing S where a refined row has no children yet. Levels
        above ``bound`` are the tree's as visited without budgets; ``refine`` what the
        policy asks where the level (below ``cap``) allows."""
        above = reach & (rows.level < bound)
        refined = above & refine
        # Tiles drawn above the level: the budget's rule counts them before the level's own.
        drawn = int(np.count_nonzero(above & ~refined))
        visited = reach & (rows.level <= bound)
        cur = np.flatnonzero(reach & (rows.level == bound))
        while True:
            cur = cur.take(np.argsort(rows.wkey.take(cur), kind="stable"))
            m = len(cur)
            if m == 0:
                break
            ref = refine.take(cur)
            n_ref = int(np.count_nonzero(ref))
            priority = None
            soft = self.soft
            if n_ref and soft is not None and n_ref * 4 > soft - drawn - (m - n_ref):
                priority = self._priority(rows, ev, cur)
                ref = budget_refinement(ref, priority, soft - drawn - (m - n_ref), 4)
                n_ref = int(np.count_nonzero(ref))
            if n_ref and drawn + m + 3 * n_ref > MAX_TILES:
                if priority is None:
                    priority = self._priority(rows, ev, cur)
                ref = budget_refinement(ref, priority, MAX_TILES - drawn - m, 3)
                n_ref = int(np.count_nonzero(ref))
            drawn += m - n_ref
            if n_ref == 0:
                break
            up = cur.compress(ref)
            refined[up] = True
            short = up.compress(~rows.kids.take(up))
            if len(short):
                n0 = rows.n
                rows, ev = self.grow(rows, ev, short)
                pad = np.zeros(rows.n - n0, dtype=bool)
                visited, refined = np.concatenate([visited, pad]), np.concatenate([refined, pad])
                refine = np.concatenate([refine, self.refinable(rows, ev, cap)[n0:]])
            mark = np.zeros(rows.n, dtype=bool)
            mark[up] = True
            cur = np.flatnonzero(mark.take(np.maximum(rows.parent, 0)) & ~rows.root & ev.vis)
            visited[cur] = True
        return rows, ev, visited, refined

    def _priority(self, rows: _Rows, ev: _Eval, at: np.ndarray) -> np.ndarray:
        """The policy's priority of rows ``at`` (a per-tile policy: asked about those only)."""
        scratch = {
            k: v.take(at, axis=0) if isinstance(v, np.ndarray) and v.ndim >= 1 and
            v.shape[0] == rows.n else v
            for k, v in ev.scratch.items()
        }  # fmt: skip
        tiles = TileCandidates(
            self.view, self.terrain, rows.level.take(at), self.size, at,
            rows.cols.take(at, axis=1), ev.dist.take(at), ev.ppm.take(at),
            rows.err.take(at, axis=0), None, None, rows, None, scratch,
        )  # fmt: skip
        sse = ev.sse.take(at, axis=0)
        return checked(self.policy, "priority", self.policy.priority(tiles, sse), at.shape, F64)

    def _selection(
        self, rows: _Rows, ev: _Eval, visited: np.ndarray, refined: np.ndarray
    ) -> Selection:
        """What the walk drew, in the level walk's order, with its cull counts."""
        # Candidates: the roots and the children of refined rows (what the level walk tests).
        cand = rows.root | refined.take(np.maximum(rows.parent, 0)) & ~rows.root
        culled_f = int(np.count_nonzero(cand & ~ev.vis_f))
        culled_h = int(np.count_nonzero(cand & ev.vis_f & ~ev.vis_fh))
        di = np.flatnonzero(visited & ~refined)  # S is in the walk's order
        p = self.policy
        tiles = self.candidates(rows, ev.dist, ev.ppm, ev.scratch)
        sse = ev.sse.take(di, axis=0)
        idx = checked(p, "stride", p.stride(tiles, sse, di), di.shape, I64)
        if len(idx) and (idx.min() < 0 or idx.max() >= N_STRIDES):
            name = type(p).__name__
            raise ValueError(f"{name}.stride returned indices outside 0..{N_STRIDES - 1}")
        err = sse.ravel().take(np.arange(0, len(idx) * N_STRIDES, N_STRIDES) + idx)
        keys = np.empty((len(di), 3), dtype=np.int64)
        keys[:, 0] = rows.level.take(di)
        keys[:, 1:] = rows.xy.take(di, axis=0)
        memo = self.state.memo

        def tree() -> TreeRows:
            k = np.empty((rows.n, 3), dtype=np.int64)
            k[:, 0] = rows.level
            k[:, 1:] = rows.xy
            return TreeRows(
                k, rows.level, rows.parent, visited, refined, ev.scratch, memo, rows.jumps
            )

        return Selection(keys, idx, err, culled_f, culled_h, tree)

    def _prune(self, rows: _Rows, refined: np.ndarray) -> None:
        """Step 5: S for the next frame (dead rows, the children of rows not refined, stay
        until they are a quarter of S: a tile that refines again finds them)."""
        alive = rows.root | refined.take(np.maximum(rows.parent, 0)) & ~rows.root
        if rows.n - int(np.count_nonzero(alive)) > _DEAD_SHARE * rows.n:
            # The children of the rows kept are kept exactly when those refined.
            rows = rows.compact(alive, rows.kids & refined)
        self.state.keep(rows)


def select_flat(
    view: ViewState,
    terrain: TerrainStack,
    policy: LodPolicy,
    cache: TileCache,
    state: SelectionState,
) -> Selection:
    """The flat walk of one frame (module docstring): what the level walk
    (`traversal._walk`) would select for ``policy`` (`LodPolicy.per_tile`, begun for this
    frame), over ``cache`` (synced, its lock held), keeping and updating ``state``."""
    return _FlatWalk(view, terrain, policy, cache, state).run()
