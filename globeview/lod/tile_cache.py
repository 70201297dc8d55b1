"""The per-terrain cache of camera-independent tile facts the quadtree traversal reads.

Everything about a tile that does not depend on the camera - its bounding lattice in ECEF for
its height range and the exaggeration, margins, bounding sphere, stride errors, metadata,
horizon peak angle, children - is computed once and kept here, so a frame of the traversal
(`globeview.lod.traversal`) computes only plane distances, the horizon test, distances and
the policy's screen-space errors.

One `TileCache` belongs to one `TerrainStack` (`tile_cache_for`): providers selecting over
the same terrain share it (a switch of provider starts warm), a terrain that is dropped drops
its cache with it, and two terrains never see each other's facts. It is valid while the
terrain's ``version`` (bumped by every layer change), its tile size and the exaggeration stay
the same; any change, or more than `TILE_CACHE_CAP` tiles held, starts it afresh.

Units: metres (ECEF, heights exaggerated), degrees for tile edges unless a column says
radians.
"""

from __future__ import annotations

import threading

import numpy as np

from globeview.lod.culling import (
    LATTICE,
    chord_sag,
    displacement_bend_m,
    horizon_peak_angle,
    norm3,
    tile_bounding_points,
)
from globeview.lod.view_state import ViewState
from globeview.terrain.compose.metadata import N_STRIDES
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.quadtree import tile_bounds_arrays

#: Most tiles one cache holds (all levels together, ~0.8 KB each); a frame that finds it
#: fuller starts it afresh.
TILE_CACHE_CAP = 20_000

# Rows of `LevelTiles.cols` (one column per cached tile), so that the horizon test reads the
# west and east edges as one (2, N) block.
COL_WEST, COL_EAST, COL_SPAN, COL_SOUTH_R, COL_NORTH_R = range(5)  # degrees; span, S/N radians
COL_PEAK, COL_MARGIN, COL_RADIUS, COL_SPHERE = range(5, 9)  # radians; metres
COL_UX, COL_UY, COL_UZ = 9, 10, 11  # unit vector of the box's centre (lon, lat)
COL_SOUTH, COL_NORTH = 12, 13  # degrees
N_COLS = 14
#: Points of a tile's bounding lattice (two heights x LATTICE x LATTICE).
N_LATTICE_POINTS = 2 * LATTICE**2


def stride_errors_m(
    level: int, height_err: np.ndarray, exaggeration: float, size: int
) -> np.ndarray:
    """(N, N_STRIDES) total geometric error (m) of drawing tiles at each stride: the height
    error (m, per stride, from the tile store) scaled by the exaggeration plus the chord sag of
    the curved ellipsoid between vertices a stride apart (flat triangles cut under a curved
    globe; at globe scale that dominates). Strides beyond the tile's grid are infinite."""
    node_deg = 180.0 / 2**level / (size - 1)
    strides = 2 ** np.arange(N_STRIDES)
    sag = chord_sag(node_deg * strides)
    valid = strides <= size - 1
    total = height_err * exaggeration + sag[None, :]
    total[:, ~valid] = np.inf
    return total


class LevelTiles:
    """Camera-independent facts of the tiles of one level seen so far.

    Tiles are stored in append order ("slots", arrays grown by doubling); a sorted array of
    their packed codes ``x << 32 | y`` with each code's slot finds the slots of a whole
    candidate array with one np.searchsorted, and each tile remembers its four children's
    slots in the next level's table (-1 until looked up), so a walk that refines a tile it
    saw before goes down without any lookup.

    Per slot: ``xy`` the tile's (x, y); ``cols`` (N_COLS, cap) scalars (the ``COL_*`` rows:
    edges, horizon peak angle, bounding margin, bounding-sphere radius with the margin
    (``COL_RADIUS``, for the distance) and without (``COL_SPHERE``, for the frustum
    prefilter), the unit vector of the box's centre (for the horizon prefilter)); ``pts``
    the bounding lattice points (ECEF, heights exaggerated) and ``centre`` their mean;
    ``herr`` the store's height errors per stride (m, not exaggerated); ``err`` the stride
    errors (m, exaggerated, chord sag included, `stride_errors_m`); ``finer`` whether finer
    data exists below; ``child`` (cap, 4) the children's slots in the order (2x, 2y),
    (2x+1, 2y), (2x, 2y+1), (2x+1, 2y+1); ``pole`` the tile's pole code
    (`stitching.pole_codes`: 1 its first row is the north pole, 2 its last the south pole);
    ``past`` how many levels the tile lies below the finest data under it (0 where its
    parent has finer data, else the parent's + 1; the roots 0; -1 until the tile is reached
    as a child, `TileCache.children`): chunked-sse's `BEYOND_DATA_LEVELS` reads it.

    With a displacement (a tool's ``view.displace``) also ``dpts``, the displaced lattice, and
    ``bend``, the displacement's bend over it (NaN: not computed yet), for the displacement
    identified by ``dkey`` (`traversal.displacement_key`): a still collapse displaces each
    tile's lattice and measures its bend once, not every frame; any other displacement (the
    collapse animating) recomputes them.
    """

    def __init__(self) -> None:
        self.n = 0
        self.codes = np.empty(0, dtype=np.int64)
        self.code_slots = np.empty(0, dtype=np.int64)
        self.xy = np.empty((0, 2), dtype=np.int64)
        self.cols = np.empty((N_COLS, 0))
        self.pts = np.empty((0, N_LATTICE_POINTS, 3))
        self.centre = np.empty((0, 3))
        self.herr = np.empty((0, N_STRIDES))
        self.err = np.empty((0, N_STRIDES))
        self.finer = np.empty(0, dtype=bool)
        self.child = np.empty((0, 4), dtype=np.int64)
        self.pole = np.empty(0, dtype=np.int64)
        self.past = np.empty(0, dtype=np.int64)
        self.dkey: tuple | None = None
        self.dpts = np.empty((0, N_LATTICE_POINTS, 3))
        self.dvalid = np.empty(0, dtype=bool)
        self.bend = np.empty(0)

    def sync_displacement(self, dkey: tuple | None) -> None:
        """Forget the displaced lattices and bends unless they are for displacement ``dkey``."""
        if dkey != self.dkey:
            self.dkey = dkey
            self.dvalid[:] = False
            self.bend[:] = np.nan

    def displaced(self, slots: np.ndarray, displace) -> np.ndarray:
        """The displaced bounding lattices (M, N_LATTICE_POINTS, 3) of ``slots``, computing
        the misses."""
        valid = self.dvalid.take(slots)
        if not valid.all():
            miss = np.unique(slots[~valid])
            pts = self.pts.take(miss, axis=0)
            d = np.asarray(displace(pts.reshape(-1, 3)), dtype=np.float64)
            self.dpts[miss] = d.reshape(pts.shape)
            self.dvalid[miss] = True
        return self.dpts.take(slots, axis=0)

    def bends(self, slots: np.ndarray, view: ViewState) -> np.ndarray:
        """The displacement's bend (m) over the lattices of ``slots`` (`displaced` already
        called for them), computing the misses with `culling.displacement_bend_m`."""
        bend = self.bend.take(slots)
        miss = np.isnan(bend)
        if miss.any():
            ms = np.unique(slots[miss])
            self.bend[ms] = displacement_bend_m(
                view, self.pts.take(ms, axis=0), self.dpts.take(ms, axis=0)
            )
            bend = self.bend.take(slots)
        return bend

    def find(self, codes: np.ndarray) -> np.ndarray:
        """Slots of the tiles with these codes; -1 for those not cached."""
        if self.n == 0:
            return np.full(len(codes), -1, dtype=np.int64)
        pos = np.minimum(np.searchsorted(self.codes, codes), self.n - 1)
        return np.where(self.codes[pos] == codes, self.code_slots[pos], -1)

    def add(
        self, level: int, codes: np.ndarray, xy: np.ndarray, facts: dict[str, np.ndarray]
    ) -> np.ndarray:
        """Store the facts of new (distinct, uncached) tiles of ``level``; returns their
        slots."""
        m = len(codes)
        n = self.n
        if n + m > len(self.finer):
            self._grow(max(2 * len(self.finer), n + m, 64))
        slots = np.arange(n, n + m)
        self.xy[n : n + m] = xy
        self.cols[:, n : n + m] = facts["cols"]
        self.pts[n : n + m] = facts["pts"]
        self.centre[n : n + m] = facts["centre"]
        self.herr[n : n + m] = facts["herr"]
        self.err[n : n + m] = facts["err"]
        self.finer[n : n + m] = facts["finer"]
        self.child[n : n + m] = -1
        y = xy[:, 1]
        self.pole[n : n + m] = (y == 0) + 2 * (y == (1 << level) - 1)
        self.past[n : n + m] = 0 if level == 0 else -1
        self.dvalid[n : n + m] = False
        self.bend[n : n + m] = np.nan
        order = np.argsort(codes)
        at = np.searchsorted(self.codes, codes[order])
        self.codes = np.insert(self.codes, at, codes[order])
        self.code_slots = np.insert(self.code_slots, at, slots[order])
        self.n = n + m
        return slots

    def _grow(self, cap: int) -> None:
        n = self.n

        def grown(a: np.ndarray, axis: int = 0) -> np.ndarray:
            shape = list(a.shape)
            shape[axis] = cap
            out = np.empty(shape, dtype=a.dtype)
            if axis == 0:
                out[:n] = a[:n]
            else:
                out[:, :n] = a[:, :n]
            return out

        self.cols = grown(self.cols, axis=1)
        self.xy, self.child = grown(self.xy), grown(self.child)
        self.pole, self.past = grown(self.pole), grown(self.past)
        self.pts, self.centre = grown(self.pts), grown(self.centre)
        self.herr, self.err, self.finer = grown(self.herr), grown(self.err), grown(self.finer)
        self.dpts, self.dvalid, self.bend = grown(self.dpts), grown(self.dvalid), grown(self.bend)


def tile_facts(
    terrain: TerrainStack, level: int, x: np.ndarray, y: np.ndarray, exag: float, size: int
) -> dict[str, np.ndarray]:
    """The camera-independent facts `LevelTiles` keeps, computed for tiles (level, x, y).

    Every value is computed per tile exactly as an uncached walk computes it (the same
    operations in the same order as `culling.cull_level` and `culling.bounding_distance`),
    so cached and fresh selections agree bit for bit."""
    w, s, e, n = tile_bounds_arrays(level, x, y)
    meta = terrain.metadata(level, x, y)
    pts, margin = tile_bounding_points(w, s, e, n, meta.hmin, meta.hmax, exag)
    centre = pts.mean(axis=1)
    sphere = np.max(norm3(pts - centre[:, None, :]), axis=1)
    cols = np.empty((N_COLS, len(x)))
    cols[COL_WEST], cols[COL_EAST], cols[COL_SPAN] = w, e, np.radians(e - w)
    cols[COL_SOUTH_R], cols[COL_NORTH_R] = np.radians(s), np.radians(n)
    cols[COL_SOUTH], cols[COL_NORTH] = s, n
    cols[COL_PEAK] = horizon_peak_angle(meta.hmax, exag)
    cols[COL_MARGIN], cols[COL_RADIUS], cols[COL_SPHERE] = margin, sphere + margin, sphere
    lon_c, lat_c = np.radians((w + e) / 2.0), np.radians((s + n) / 2.0)
    cols[COL_UX], cols[COL_UY] = np.cos(lat_c) * np.cos(lon_c), np.cos(lat_c) * np.sin(lon_c)
    cols[COL_UZ] = np.sin(lat_c)
    return {
        "cols": cols,
        "pts": pts,
        "centre": centre,
        "herr": meta.stride_error,
        "err": stride_errors_m(level, meta.stride_error, exag, size),
        "finer": meta.has_finer,
    }


class TileCache:
    """The per-level `LevelTiles` of one terrain at one exaggeration (see the module
    docstring). ``lock`` serialises traversals of the same terrain (the facts tables are
    appended to during a walk). ``epoch`` counts the restarts: slots are valid within one
    epoch (a `flat_walk.SelectionState` holding slots starts afresh when it changes)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self._key: tuple | None = None
        self.levels: dict[int, LevelTiles] = {}
        self.epoch = 0
        self._held = 0

    @property
    def held(self) -> int:
        """Tiles held, all levels together."""
        return self._held

    def sync(self, terrain: TerrainStack, exag: float) -> None:
        """Drop everything unless it was computed for this terrain state and exaggeration
        (and keep the cache bounded: beyond `TILE_CACHE_CAP` tiles it starts afresh, all
        levels at once, so children slots never dangle). The cache belongs to one terrain
        (`tile_cache_for`), so its state is the terrain's version."""
        key = (terrain.version, terrain.tile_size, exag)
        if self._key != key or self.held > TILE_CACHE_CAP:
            self._key = key
            self.clear()

    def clear(self) -> None:
        """Drop every tile (a new epoch: a cold cache, as `sync` makes it)."""
        self.levels = {}
        self.epoch += 1
        self._held = 0

    def roots(self, terrain: TerrainStack, size: int) -> np.ndarray:
        """Slots of the two level-0 tiles (0, 0, 0) and (0, 1, 0)."""
        lv = self.levels.get(0)
        if lv is not None and lv.n >= 2 and lv.xy[0, 0] == 0 and lv.xy[1, 0] == 1:
            return np.arange(2)
        return self.slots(terrain, 0, np.array([0, 1]), np.array([0, 0]), size)

    def level(self, level: int) -> LevelTiles:
        """The facts table of ``level`` (created empty on first use)."""
        lv = self.levels.get(level)
        if lv is None:
            lv = self.levels[level] = LevelTiles()
        return lv

    def slots(
        self, terrain: TerrainStack, level: int, x: np.ndarray, y: np.ndarray, size: int
    ) -> np.ndarray:
        """Slots of tiles (level, x, y) in the level's table, computing the misses."""
        lv = self.level(level)
        codes = (x << 32) | y
        slots = lv.find(codes)
        miss = slots < 0
        if miss.any():
            assert self._key is not None  # sync() ran
            facts = tile_facts(terrain, level, x[miss], y[miss], self._key[2], size)
            xy = np.stack([x[miss], y[miss]], axis=1)
            slots[miss] = lv.add(level, codes[miss], xy, facts)
            self._held += len(xy)
        return slots

    def children(
        self, terrain: TerrainStack, level: int, parents: np.ndarray, size: int
    ) -> np.ndarray:
        """Slots (in the next level's table) of the children of tiles ``parents`` (slots at
        ``level``), in the walk's order: all (2x, 2y) children, then (2x+1, 2y), (2x, 2y+1)
        and (2x+1, 2y+1)."""
        lv = self.levels[level]
        ch = lv.child.take(parents, axis=0)
        if ch.min() < 0:
            unknown = (ch < 0).any(axis=1)
            up = parents[unknown]
            x2, y2 = 2 * lv.xy[up, 0], 2 * lv.xy[up, 1]
            cx = np.concatenate([x2, x2 + 1, x2, x2 + 1])
            cy = np.concatenate([y2, y2, y2 + 1, y2 + 1])
            found = self.slots(terrain, level + 1, cx, cy, size).reshape(4, -1).T
            lv.child[up] = found
            ch[unknown] = found
            # Levels past the data, from the parent (camera independent): set as the link is
            # made, the only way a tile below the roots enters a walk.
            past = np.where(lv.finer.take(up), 0, lv.past.take(up) + 1)
            self.levels[level + 1].past[found] = past[:, None]
        return ch.T.ravel()

    def children_across(
        self, terrain: TerrainStack, levels: np.ndarray, parents: np.ndarray, size: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """The children of tiles of several levels at once (``parents`` slots at ``levels``):
        (child level, child slot, index of the parent in ``parents``, child index c =
        dx + 2 dy, copies of the children's facts as `facts_of` gives them); levels
        ascending, each level's children in `children`'s order. The misses of a level are
        computed in one `tile_facts` call."""
        parts: list[tuple[np.ndarray, ...]] = []
        facts: list[dict[str, np.ndarray]] = []
        for level in np.unique(levels).tolist():
            at = np.flatnonzero(levels == level)
            ch = self.children(terrain, level, parents.take(at), size)
            k = len(at)
            parts.append(
                (
                    np.full(4 * k, level + 1, dtype=np.int64),
                    ch,
                    np.tile(at, 4),
                    np.repeat(np.arange(4, dtype=np.int64), k),
                )
            )
            facts.append(self.facts_of(level + 1, ch))
        cat = np.concatenate
        lv, sl, pi, c = (cat([p[i] for p in parts]) for i in range(4))
        if len(facts) == 1:
            return lv, sl, pi, c, facts[0]
        axis = {"cols": 1}
        return lv, sl, pi, c, {k: cat([f[k] for f in facts], axis=axis.get(k, 0)) for k in facts[0]}

    def facts_of(self, level: int, slots: np.ndarray) -> dict[str, np.ndarray]:
        """Copies of the facts of tiles ``slots`` of ``level`` (`LevelTiles`' arrays, rows in
        the order of ``slots``; ``cols`` (N_COLS, N))."""
        lv = self.levels[level]
        return {
            "xy": lv.xy.take(slots, axis=0),
            "cols": lv.cols.take(slots, axis=1),
            "pts": lv.pts.take(slots, axis=0),
            "centre": lv.centre.take(slots, axis=0),
            "err": lv.err.take(slots, axis=0),
            "herr": lv.herr.take(slots, axis=0),
            "finer": lv.finer.take(slots),
            "pole": lv.pole.take(slots),
            "past": lv.past.take(slots),
        }


def tile_cache_for(terrain: TerrainStack) -> TileCache:
    """The `TileCache` of ``terrain`` (created on first use, freed with the terrain).

    It lives in the terrain's opaque ``lod_cache`` slot, so it goes with the terrain and two
    terrains never share one. Two threads asking at once for a terrain's first cache may each
    build one; the last stored wins and the other is dropped after its one use (harmless: a
    cache holds only facts recomputable from the terrain)."""
    cache = terrain.lod_cache
    if not isinstance(cache, TileCache):
        cache = terrain.lod_cache = TileCache()
    return cache
