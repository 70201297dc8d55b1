"""`chunked-sse`: the default LOD provider, chunked screen-space-error selection (TREND §4.2 /
Cesium style), vectorised. This is the renderer's original selection moved, unchanged, behind
the plugin interface (`LodProvider`).

The quadtree is walked level by level with numpy over all candidate tiles at once:

1. cull candidates against the frustum and the ellipsoid horizon (culling.py);
2. project each tile's geometric error to pixels, ``e * K / d`` with K = viewport height /
   (2 tan(fovy/2)) and d a lower bound of the distance to the tile;
3. refine (replace by its four children) when that exceeds tau and finer data exists, or
   when the tile's texels would be magnified beyond ``texel_px`` pixels and finer data exists;
4. draw the others with the coarsest index stride whose error still projects below tau
   (TREND's per-block resolution pyramid, applied to the whole tile).

The error of a tile drawn with stride s is its height error (from the tile store) times the
vertical exaggeration plus the chord sag of the curved ellipsoid between vertices s nodes
apart: flat triangles cut under a curved globe, and at globe scale that dominates.

Cracks between tiles drawn at different levels or strides are hidden by skirts.

Speed: everything about a tile that does not depend on the camera (its bounding lattice in
ECEF for its height range and the exaggeration, margins, bounding sphere, stride errors,
metadata, horizon peak angle, children) is kept in a bounded per-tile cache (`_TileCache`),
dropped when the terrain (`TerrainStack.version`) or the exaggeration changes. A frame then
computes only plane distances, the horizon test, distances and screen-space errors, with
few numpy calls per level; conservative bounding-sphere / box-centre prefilters settle
most tiles' frustum and horizon tests, and the exact tests (the same floating-point
operations as culling.py) run only on the tiles near a plane or the horizon, so the result
is the same as the plain walk's.
"""

from __future__ import annotations

import math
import threading
import time
import weakref
from dataclasses import dataclass

import numpy as np

from globeview.plugins.api import (
    LATTICE,
    N_STRIDES,
    IndexVariant,
    LodProvider,
    RenderSet,
    Setting,
    TerrainStack,
    ViewState,
    bounding_distance,
    box_angular_distance_pre,
    chord_sag,
    displacement_bend_m,
    frustum_visible,
    horizon_cap,
    horizon_peak_angle,
    lonlat_to_ecef,
    tile_bounding_points,
    tile_bounds_arrays,
)

#: Deepest level the walk goes to even where the data stops (curvature alone).
MAX_LEVEL = 22

#: Most tiles the per-tile cache holds (all levels together, ~0.7 KB each); a frame that
#: finds it fuller starts it afresh.
TILE_CACHE_CAP = 20_000


@dataclass
class ChunkedSettings:
    """Settings of the chunked selection.

    tau_px: screen-space error threshold (pixels); None uses the ViewState's.
    texel_px: refine while a texel of the tile's height/normal textures covers more pixels.
    max_tiles: stop refining beyond this many drawn tiles (a safety budget).
    """

    tau_px: float | None = None
    texel_px: float = 1.5
    max_tiles: int = 600


def stride_errors_m(
    level: int, height_err: np.ndarray, exaggeration: float, size: int
) -> np.ndarray:
    """(N, N_STRIDES) total geometric error (m) of drawing tiles at each stride: the height
    error scaled by the exaggeration plus the chord sag of the stride's vertex spacing."""
    node_deg = 180.0 / 2**level / (size - 1)
    strides = 2 ** np.arange(N_STRIDES)
    sag = chord_sag(node_deg * strides)
    valid = strides <= size - 1
    total = height_err * exaggeration + sag[None, :]
    total[:, ~valid] = np.inf
    return total


# -- per-tile cache of the camera-independent facts ----
# Rows of `_LevelTiles.cols` (one column per cached tile), so that the horizon test reads the
# west and east edges as one (2, N) block.
_WEST, _EAST, _SPAN, _SOUTH_R, _NORTH_R, _PEAK, _MARGIN, _RADIUS, _SPHERE = range(9)
_UX, _UY, _UZ = 9, 10, 11  # unit vector of the box's centre (lon, lat) on the unit sphere
_N_COLS = 12
_N_PTS = 2 * LATTICE**2


class _LevelTiles:
    """Camera-independent facts of the tiles of one level seen so far.

    Tiles are stored in append order ("slots", arrays grown by doubling); a sorted array of
    their packed codes ``x << 32 | y`` with each code's slot finds the slots of a whole
    candidate array with one np.searchsorted, and each tile remembers its four children's
    slots in the next level's table (-1 until looked up), so a walk that refines a tile it
    saw before goes down without any lookup.

    Per slot: ``xy`` the tile's (x, y); ``cols`` (_N_COLS, cap) scalars: edges, horizon peak
    angle, bounding margin, bounding-sphere radius with the margin (``_RADIUS``, for the
    distance) and without (``_SPHERE``, for the frustum prefilter), the unit vector of the
    box's centre (for the horizon prefilter); ``pts`` the bounding
    lattice points (ECEF, heights exaggerated) and ``centre`` their mean; ``err`` the stride
    errors (m, exaggerated, chord sag included); ``finer`` whether finer data exists below;
    ``child`` (cap, 4) the children's slots in the order (2x, 2y), (2x+1, 2y), (2x, 2y+1),
    (2x+1, 2y+1).

    With a displacement (a tool's ``view.displace``) also ``dpts``, the displaced lattice, and
    ``bend``, the displacement's bend over it (NaN: not computed yet), for the displacement
    identified by ``dkey`` (`displacement_key`): a still collapse displaces each tile's
    lattice and measures its bend once, not every frame; any other displacement (the
    collapse animating) recomputes them.
    """

    def __init__(self) -> None:
        self.n = 0
        self.codes = np.empty(0, dtype=np.int64)
        self.code_slots = np.empty(0, dtype=np.int64)
        self.xy = np.empty((0, 2), dtype=np.int64)
        self.cols = np.empty((_N_COLS, 0))
        self.pts = np.empty((0, _N_PTS, 3))
        self.centre = np.empty((0, 3))
        self.err = np.empty((0, N_STRIDES))
        self.finer = np.empty(0, dtype=bool)
        self.child = np.empty((0, 4), dtype=np.int64)
        self.dkey: tuple | None = None
        self.dpts = np.empty((0, _N_PTS, 3))
        self.dvalid = np.empty(0, dtype=bool)
        self.bend = np.empty(0)

    def sync_displacement(self, dkey: tuple) -> None:
        """Forget the displaced lattices and bends unless they are for displacement ``dkey``."""
        if dkey != self.dkey:
            self.dkey = dkey
            self.dvalid[:] = False
            self.bend[:] = np.nan

    def displaced(self, slots: np.ndarray, displace) -> np.ndarray:
        """The displaced bounding lattices (M, _N_PTS, 3) of ``slots``, computing the misses."""
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

    def add(self, codes: np.ndarray, xy: np.ndarray, facts: dict[str, np.ndarray]) -> np.ndarray:
        """Store the facts of new (distinct, uncached) tiles; returns their slots."""
        m = len(codes)
        n = self.n
        if n + m > len(self.finer):
            self._grow(max(2 * len(self.finer), n + m, 64))
        slots = np.arange(n, n + m)
        self.xy[n : n + m] = xy
        self.cols[:, n : n + m] = facts["cols"]
        self.pts[n : n + m] = facts["pts"]
        self.centre[n : n + m] = facts["centre"]
        self.err[n : n + m] = facts["err"]
        self.finer[n : n + m] = facts["finer"]
        self.child[n : n + m] = -1
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
        self.pts, self.centre = grown(self.pts), grown(self.centre)
        self.err, self.finer = grown(self.err), grown(self.finer)
        self.dpts, self.dvalid, self.bend = grown(self.dpts), grown(self.dvalid), grown(self.bend)


def _tile_facts(
    terrain: TerrainStack, level: int, x: np.ndarray, y: np.ndarray, exag: float, size: int
) -> dict[str, np.ndarray]:
    """The camera-independent facts `_LevelTiles` keeps, computed for tiles (level, x, y).

    Every value is computed per tile exactly as the uncached walk computed it (the same
    operations in the same order), so cached and fresh selections agree bit for bit."""
    w, s, e, n = tile_bounds_arrays(level, x, y)
    meta = terrain.metadata(level, x, y)
    pts, margin = tile_bounding_points(w, s, e, n, meta.hmin, meta.hmax, exag)
    centre = pts.mean(axis=1)
    sphere = np.max(np.linalg.norm(pts - centre[:, None, :], axis=2), axis=1)
    cols = np.empty((_N_COLS, len(x)))
    cols[_WEST], cols[_EAST], cols[_SPAN] = w, e, np.radians(e - w)
    cols[_SOUTH_R], cols[_NORTH_R] = np.radians(s), np.radians(n)
    cols[_PEAK] = horizon_peak_angle(meta.hmax, exag)
    cols[_MARGIN], cols[_RADIUS], cols[_SPHERE] = margin, sphere + margin, sphere
    lon_c, lat_c = np.radians((w + e) / 2.0), np.radians((s + n) / 2.0)
    cols[_UX], cols[_UY] = np.cos(lat_c) * np.cos(lon_c), np.cos(lat_c) * np.sin(lon_c)
    cols[_UZ] = np.sin(lat_c)
    return {
        "cols": cols,
        "pts": pts,
        "centre": centre,
        "err": stride_errors_m(level, meta.stride_error, exag, size),
        "finer": meta.has_finer,
    }


class _TileCache:
    """The per-level `_LevelTiles` of one terrain at one exaggeration.

    Valid while the terrain object, its ``version`` (bumped by every layer change), its tile
    size and the exaggeration stay the same; any change, or more than `TILE_CACHE_CAP` tiles
    held, starts it afresh (all levels at once, so children slots never dangle)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self._terrain: weakref.ref | None = None
        self._key: tuple | None = None
        self.levels: dict[int, _LevelTiles] = {}

    def sync(self, terrain: TerrainStack, exag: float) -> None:
        """Drop everything unless it was computed for this terrain state and exaggeration."""
        key = (terrain.version, terrain.tile_size, exag)
        same = self._terrain is not None and self._terrain() is terrain and self._key == key
        if not same or sum(lv.n for lv in self.levels.values()) > TILE_CACHE_CAP:
            self._terrain, self._key = weakref.ref(terrain), key
            self.levels = {}

    def roots(self, terrain: TerrainStack, size: int) -> np.ndarray:
        """Slots of the two level-0 tiles (0, 0, 0) and (0, 1, 0)."""
        lv = self.levels.get(0)
        if lv is not None and lv.n >= 2 and lv.xy[0, 0] == 0 and lv.xy[1, 0] == 1:
            return np.arange(2)
        return self.slots(terrain, 0, np.array([0, 1]), np.array([0, 0]), size)

    def level(self, level: int) -> _LevelTiles:
        lv = self.levels.get(level)
        if lv is None:
            lv = self.levels[level] = _LevelTiles()
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
            facts = _tile_facts(terrain, level, x[miss], y[miss], self._key[2], size)
            xy = np.stack([x[miss], y[miss]], axis=1)
            slots[miss] = lv.add(codes[miss], xy, facts)
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
        return ch.T.ravel()


_TILE_CACHE = _TileCache()


def _probe_points(n: int = 64) -> np.ndarray:
    """(n, 3) ECEF points spread over the globe (a Fibonacci lattice, 0 and 5 km high)."""
    k = np.arange(n) + 0.5
    lat = np.degrees(np.arcsin(1.0 - 2.0 * k / n))
    lon = (np.degrees(np.pi * (1.0 + 5.0**0.5) * k) + 180.0) % 360.0 - 180.0
    h = np.where(np.arange(n) % 2 == 0, 0.0, 5000.0)
    return np.asarray(lonlat_to_ecef(lon, lat, h), dtype=np.float64).reshape(n, 3)


_PROBES = _probe_points()


def displacement_key(view: ViewState) -> tuple | None:
    """Identifies ``view.displace`` (and which bend measure the view carries) for the caches:
    the tool's ``view.displacement_key`` and the exact bytes of where the displacement moves
    a fixed set of probe points (None: no displacement). Without a tool key, a displacement
    that moves no probe point differently (a local one elsewhere) would pass for the same."""
    if view.displace is None:
        return None
    moved = np.asarray(view.displace(_PROBES), dtype=np.float64).tobytes()
    return (view.displacement_key, moved, view.displacement_bend is not None)


def select_tiles(
    view: ViewState, terrain: TerrainStack, settings: ChunkedSettings | None = None
) -> RenderSet:
    """Choose the tiles (and each one's index stride) for a view.

    Camera-independent per-tile facts (bounding points, margins, stride errors, metadata)
    come from a cache shared across frames (`_TileCache`); a frame computes only what depends
    on the camera: plane distances, the horizon test, distance and screen-space error."""
    settings = settings or ChunkedSettings()
    t0 = time.perf_counter()
    with _TILE_CACHE.lock:
        _TILE_CACHE.sync(terrain, view.exaggeration)
        keys, stride_idx, err_px, culled_f, culled_h = _walk(view, terrain, settings)

    if len(keys) == 0:
        rs = RenderSet.empty()
    else:
        pole = (keys[:, 2] == 0).astype(np.int64) + 2 * (keys[:, 2] == (1 << keys[:, 0]) - 1)
        combo = stride_idx * 4 + pole
        uniq, ids = np.unique(combo, return_inverse=True)
        poles = (None, "north", "south", "both")
        variants = [IndexVariant(stride=int(2 ** (c // 4)), pole=poles[c % 4]) for c in uniq]
        rs = RenderSet(keys, ids, variants, error_px=err_px)
    rs.stats.update(
        {
            "tiles_culled_frustum": culled_f,
            "tiles_culled_horizon": culled_h,
            "lod_ms": (time.perf_counter() - t0) * 1e3,
        }
    )
    return rs


class _FrustumFrame:
    """Per-view constants of the frustum tests: the eye, the plane normals (as
    `culling.frustum_visible` slices them, and as contiguous columns), each plane's signed
    distance of the eye, and the prefilter's slack ``tol`` (m)."""

    def __init__(self, view: ViewState) -> None:
        planes = view.frustum_planes
        self.eye = view.eye
        self.normals = planes[:, :3]
        self.normals_t = np.ascontiguousarray(planes[:, :3].T)
        self.d_eye = planes[:, :3] @ view.eye + planes[:, 3]
        self.tol = 1e-3 + 1e-12 * (float(np.abs(view.eye).sum()) + view.far)
        self.d_tol = self.d_eye + self.tol

    def exact(self, points: np.ndarray, margin: np.ndarray) -> np.ndarray:
        """`culling.frustum_visible`, the same operations on the same operands (so the same
        floats), with the per-view terms computed once."""
        dist = np.einsum("nkj,pj->npk", points - self.eye, self.normals).max(axis=2)
        return ((dist + self.d_eye) >= -margin[:, None]).all(axis=1)


def _frustum_prefilter(
    frame: _FrustumFrame, rel_centre: np.ndarray, margin: np.ndarray, sphere: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`frustum_visible` decided from each tile's bounding sphere where that is conclusive.

    With c the mean of a tile's points (``rel_centre`` = c - eye, (N, 3)) and r their
    farthest distance from c (``sphere``), every point's signed plane distance lies in
    [dist(c) - r, dist(c) + r], and their mean is dist(c). So a plane has some point within
    the margin when dist(c) >= -margin, and all of them beyond it when dist(c) + r < -margin.
    Both tests keep a slack (orders of magnitude above float64 rounding at these
    magnitudes), so they never disagree with the exact test; tiles neither decides come back
    as ambiguous, for the exact `frustum_visible` (`_FrustumFrame.exact`).

    Returns (visible, ambiguous), both (N,) bool; ``visible`` is False where ambiguous."""
    # Over the planes, the least dist(c) + margin + tol.
    m = (rel_centre @ frame.normals_t + frame.d_tol).min(axis=1) + margin
    inside = m >= 2.0 * frame.tol  # dist(c) + margin >= tol on every plane
    outside = m + sphere < 0.0  # dist(c) + r + margin < -tol on some plane
    return inside, ~(inside | outside)


#: Slack (radians) of the horizon prefilter, far above the rounding of the exact test.
_HORIZON_TOL = 1e-6


def _horizon_visible(
    view: ViewState, cap: float, c: np.ndarray, u0: np.ndarray | None
) -> np.ndarray:
    """`culling.horizon_visible` of tiles from their cached columns ``c`` (_N_COLS, N), with
    ``cap`` = `culling.horizon_cap` and ``u0`` the unit vector of the eye's (lon, lat).

    `culling.box_angular_distance` is the spherical distance from the eye's (lon, lat) to
    the nearest point of the box whenever that is below 90 degrees, hence at most the
    distance to the box's centre. So a tile whose centre is within min(cap + peak, 90 deg)
    minus a slack is visible without the exact test, which then runs only on the others
    (those near the horizon). ``u0`` None skips the prefilter (eye almost on the ground)."""
    limit = cap + c[_PEAK]
    if u0 is not None:
        thr = np.cos(np.minimum(limit - _HORIZON_TOL, math.pi / 2 - _HORIZON_TOL))
        vis = u0 @ c[_UX : _UZ + 1] >= thr
        n_vis = np.count_nonzero(vis)
        if n_vis == len(vis):
            return vis
        ai = (~vis).nonzero()[0]
        c, limit = c.take(ai, axis=1), limit.take(ai)
    lon0, lat0, _ = view.eye_lonlat_h
    exact = (
        box_angular_distance_pre(
            lon0, lat0, c[_WEST : _EAST + 1], c[_SPAN], c[_SOUTH_R], c[_NORTH_R]
        )
        <= limit
    )
    if u0 is None:
        return exact
    vis[ai] = exact
    return vis


#: Weights picking the coarsest acceptable stride (see `_walk`).
_STRIDE_RANK = np.arange(1, N_STRIDES + 1)


def _walk(
    view: ViewState, terrain: TerrainStack, settings: ChunkedSettings
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """The level-by-level walk (see the module docstring): returns the drawn keys (N, 3),
    their stride indices and projected errors (px), and the frustum / horizon cull counts.

    Per level the candidates are slots in the cache's level table; only camera-dependent
    values are computed here, each with as few numpy calls as possible (take() rather than
    fancy indexing, one reduction where the original used several): small arrays, so the
    per-call overhead is what costs."""
    tau = settings.tau_px if settings.tau_px is not None else view.tau_px
    size = terrain.tile_size
    k_px = view.sse_factor
    eye = view.eye
    displace = view.displace
    dkey = displacement_key(view)
    cap = horizon_cap(view)  # None: eye at or below the ellipsoid, nothing hidden
    u0 = None
    if cap is not None and cap > 1e3 * _HORIZON_TOL:
        lon0, lat0 = np.radians(view.eye_lonlat_h[:2])
        u0 = np.array([np.cos(lat0) * np.cos(lon0), np.cos(lat0) * np.sin(lon0), np.sin(lat0)])
    frame = _FrustumFrame(view)
    # A displacement's bend shrinks with the stride (see below).
    bend_frac = np.minimum(1.0, 2.0 ** np.arange(N_STRIDES) * (LATTICE - 1) / (size - 1))

    slots = _TILE_CACHE.roots(terrain, size)
    out_slots, out_stride, out_err = [], [], []
    culled_f = culled_h = 0
    drawn = 0
    for level in range(MAX_LEVEL + 1):
        lv = _TILE_CACHE.level(level)
        n = len(slots)
        c = lv.cols.take(slots, axis=1)
        if displace is None:
            rel_centre = lv.centre.take(slots, axis=0) - eye
            vis_f, amb = _frustum_prefilter(frame, rel_centre, c[_MARGIN], c[_SPHERE])
            if np.count_nonzero(amb):
                ai = amb.nonzero()[0]
                pts = lv.pts.take(slots.take(ai), axis=0)
                vis_f[ai] = frame.exact(pts, c[_MARGIN].take(ai))
        else:
            lv.sync_displacement(dkey)
            pts = lv.displaced(slots, displace)
            vis_f = frustum_visible(view, pts, c[_MARGIN])
        # The horizon test only matters for tiles inside the frustum.
        fi = vis_f.nonzero()[0]
        culled_f += n - len(fi)
        if len(fi) < n:
            c = c.take(fi, axis=1)
        if cap is not None and len(fi):
            vis_h = _horizon_visible(view, cap, c, u0)
            n_vis = int(np.count_nonzero(vis_h))
            culled_h += len(fi) - n_vis
            if n_vis < len(fi):
                vi = vis_h.nonzero()[0]
                fi, c = fi.take(vi), c.take(vi, axis=1)
        m = len(fi)
        if m == 0:
            break
        ks = slots.take(fi) if m < n else slots
        err = lv.err.take(ks, axis=0)
        if displace is None:
            d = rel_centre.take(fi, axis=0) if m < n else rel_centre
            # = np.linalg.norm(d, axis=1) (the same operations, without its overhead)
            d = np.sqrt(np.add.reduce(d * d, axis=1)) - c[_RADIUS]
            dist = np.maximum(d, 1.0)
        else:
            # A displacement that bends the surface (the collapse's fold lines) bends it away
            # from straight triangle edges: count that as geometric error, shrinking with the
            # stride, so tiles across a fold refine and no gap opens between them.
            bend = lv.bends(ks, view)
            err = err + bend[:, None] * bend_frac[None, :]
            dist = bounding_distance(view, pts[fi], c[_MARGIN])
        px_per_m = k_px / dist
        sse = err * px_per_m[:, None]
        if level < MAX_LEVEL:
            tile_m = math.radians(180.0 / 2**level) * 6.371e6
            texel = tile_m / (size - 1) * px_per_m
            refine = (sse[:, 0] > tau) | ((texel > settings.texel_px) & lv.finer.take(ks))
        else:
            refine = np.zeros(m, dtype=bool)
        # Budget: if refining everything would exceed the tile budget, refine the worst first.
        n_ref = int(np.count_nonzero(refine))
        room = settings.max_tiles - drawn - (m - n_ref)
        if n_ref * 4 > room and n_ref > 0:
            allowed = max(room // 4, 0)
            order = np.argsort(-sse[:, 0])
            ref_idx = order[refine[order]][:allowed]
            refine[:] = False
            refine[ref_idx] = True
            n_ref = len(ref_idx)
        if n_ref < m:
            if n_ref:
                ai = (~refine).nonzero()[0]
                sse_acc, acc_slots = sse.take(ai, axis=0), ks.take(ai)
            else:
                sse_acc, acc_slots = sse, ks
            # Coarsest stride whose error projects within tau (stride 1 if none does): the
            # highest rank among the acceptable strides, minus one, or 0.
            idx = np.maximum((sse_acc <= tau) * _STRIDE_RANK, 1).max(axis=1) - 1
            out_slots.append((level, lv, acc_slots))
            out_stride.append(idx)
            rows = np.arange(0, len(idx) * N_STRIDES, N_STRIDES)
            out_err.append(sse_acc.ravel().take(rows + idx))
            drawn += len(idx)
        if n_ref == 0:
            break
        refined = ks.take(refine.nonzero()[0]) if n_ref < m else ks
        slots = _TILE_CACHE.children(terrain, level, refined, size)

    if not out_slots:
        empty = np.empty(0, dtype=np.int64)
        return np.empty((0, 3), dtype=np.int64), empty, np.empty(0), culled_f, culled_h
    keys = np.empty((drawn, 3), dtype=np.int64)
    keys[:, 0] = np.repeat([lvl for lvl, _, _ in out_slots], [len(s) for _, _, s in out_slots])
    keys[:, 1:] = np.concatenate([lv.xy.take(s, axis=0) for _, lv, s in out_slots])
    return keys, np.concatenate(out_stride), np.concatenate(out_err), culled_f, culled_h


class ChunkedSseProvider(LodProvider):
    """The built-in default LOD provider (see the module docstring)."""

    name = "chunked-sse"
    label = "Chunked (screen-space error)"
    settings = (
        Setting(
            "texel_px",
            "float",
            1.5,
            min=0.5,
            max=8.0,
            label="texel size (pixels)",
            help="refine while a texel of the tile textures covers more pixels",
        ),
        Setting("max_tiles", "int", 600, min=16, max=2000, label="tile budget"),
    )

    def __init__(self, context=None) -> None:
        super().__init__(context)
        self._cache_key: tuple | None = None
        self._cache: RenderSet | None = None

    def reset(self) -> None:
        self._cache_key = self._cache = None

    def select(self, view: ViewState, terrain: TerrainStack) -> RenderSet:
        if terrain is None or not terrain.layers:
            return RenderSet.empty()
        # A repaint with an unchanged view (window expose, overlay redraw) reuses the last
        # selection; any camera move, setting or layer change recomputes it.
        key = (
            view.eye.tobytes(),
            view.rotation.tobytes(),
            view.viewport,
            view.fovy_deg,
            view.tau_px,
            view.exaggeration,
            view.displace is None,
            id(terrain),
            terrain.version,
            tuple(sorted(self.values.items())),
        )
        if key == self._cache_key and self._cache is not None and view.displace is None:
            rs = self._cache
            rs.stats["lod_ms"] = 0.0
            rs.stats["lod_cached"] = 1.0
            return rs
        v = self.values
        rs = select_tiles(
            view,
            terrain,
            # tau comes with the view (ViewState.tau_px): one threshold for every provider.
            ChunkedSettings(texel_px=v["texel_px"], max_tiles=v["max_tiles"]),
        )
        self._cache_key, self._cache = key, rs
        return rs
