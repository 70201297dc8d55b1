"""The one quadtree traversal every LOD provider steers (Cesium's ``QuadtreePrimitive``).

The quadtree is walked level by level with numpy over all candidate tiles of a level at once:

1. the candidates' camera-independent facts come from the terrain's `TileCache`
   (`tile_cache.tile_cache_for`: bounding lattice, margins, bounding sphere, stride errors,
   metadata, children);
2. they are culled against the frustum and the ellipsoid horizon (`cached_culling`: the
   answers of `culling.frustum_visible` / `culling.horizon_visible`, with conservative
   bounding-sphere / box-centre prefilters settling most tiles), then by the policy's own
   test (`LodPolicy.cull`);
3. the policy (`globeview.lod.policy.LodPolicy`, Cesium's ``QuadtreeTileProvider``) says
   what error each survivor has (`LodPolicy.error_px`), which to refine
   (`LodPolicy.refine`, asked at every level; at ``max_level`` its answer is ignored), and,
   for those drawn, with which index stride (`LodPolicy.stride`);
4. a tile budget (`LodPolicy.max_tiles`) keeps the drawn count bounded: when refining every
   tile that asks would exceed it, the worst (`LodPolicy.priority`) refine first. The
   policy's budget is soft (it bounds the children of refined tiles; a level's visible
   tiles are drawn anyway), and `MAX_TILES` (the render set's limit) is always held
   strictly on top of it, so every selection validates;
5. refined tiles are replaced by their four children at the next level; the others are drawn.

The result goes back to the policy (`LodPolicy.render_set`), which builds the `RenderSet`
(index variants, stitching); the traversal adds the cull counts and ``lod_ms``.

A frame computes only what depends on the camera - plane distances, the horizon test, the
distances, the policy's errors - with few numpy calls per level (take() rather than fancy
indexing: small arrays, so the per-call overhead is what costs).

With a displacement (a tool's ``view.displace``, e.g. the terrain collapse) culling uses the
displaced bounding lattices and the displacement's bend over each tile (the collapse's fold
lines) is added to its geometric error, shrinking with the stride (`TileCandidates.err_m`):
tiles across a fold refine and no gap opens between them. Both are cached per displacement.
"""

from __future__ import annotations

import time

import numpy as np

from globeview.geodesy import lonlat_to_ecef
from globeview.lod.cached_culling import (
    HORIZON_TOL,
    FrustumFrame,
    frustum_prefilter,
    horizon_visible_cached,
)
from globeview.lod.candidates import MAX_LEVEL, Selection, TileCandidates, bend_fractions
from globeview.lod.culling import (
    bounding_distance,
    frustum_visible,
    horizon_cap,
    norm3,
)
from globeview.lod.flat_walk import SelectionState, select_flat
from globeview.lod.policy import LodPolicy
from globeview.lod.render_set import MAX_TILES, RenderSet
from globeview.lod.tile_cache import (
    COL_MARGIN,
    COL_RADIUS,
    COL_SPHERE,
    LevelTiles,
    TileCache,
    tile_cache_for,
)
from globeview.lod.view_state import ViewState
from globeview.lod.walk_rules import BOOL as _BOOL
from globeview.lod.walk_rules import F64 as _F64
from globeview.lod.walk_rules import I64 as _I64
from globeview.lod.walk_rules import budget_refinement
from globeview.lod.walk_rules import checked as _checked
from globeview.terrain.compose.metadata import N_STRIDES
from globeview.terrain.compose.stack import TerrainStack


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


# -- the walk -----------------------------------------------------------------------------------
def traverse(
    view: ViewState,
    terrain: TerrainStack,
    policy: LodPolicy,
    state: SelectionState | None = None,
) -> RenderSet:
    """Select the tiles to draw for ``view`` over ``terrain`` as ``policy`` decides (the
    module docstring): one level-by-level walk, the policy's `LodPolicy.render_set` of what
    it drew, with ``tiles_culled_frustum``, ``tiles_culled_horizon`` and ``lod_ms`` stats.
    An empty terrain (no layers) draws nothing.

    With a ``state`` (a `flat_walk.SelectionState` the caller keeps from frame to frame) and
    a `LodPolicy.per_tile` policy, the flat walk (`flat_walk.select_flat`) selects instead:
    the same tiles, strides and errors, from last frame's candidate tree in one pass, with
    the stats ``lod_rounds``, ``lod_rows_new`` and ``lod_rows`` (`SelectionState`); a state
    with nothing to start from (``lod_cold``) walks level by level and keeps that walk's
    tree for the next frame. Views with a displacement walk level by level."""
    t0 = time.perf_counter()
    if terrain is None or not terrain.layers:
        return RenderSet.empty()
    policy.begin(view, terrain)
    cache = tile_cache_for(terrain)
    flat = state is not None and policy.per_tile and view.displace is None
    with cache.lock:
        cache.sync(terrain, view.exaggeration)
        if flat and state is not None and state.cold(cache):
            # Nothing to start from (a first frame, a new terrain): growing the tree from
            # the roots would cost more than the level walk, which seeds the tree instead.
            record: list[tuple[int, np.ndarray, np.ndarray]] = []
            sel = _walk(view, terrain, policy, cache, record)
            state.seed(cache, record)
        elif flat:
            assert state is not None  # flat implies it
            sel = select_flat(view, terrain, policy, cache, state)
        else:
            sel = _walk(view, terrain, policy, cache)
    rs = policy.render_set(sel, terrain.tile_size)
    rs.stats.update(
        {
            "tiles_culled_frustum": sel.culled_frustum,
            "tiles_culled_horizon": sel.culled_horizon,
            **policy.frame_stats(),
            **(state.stats if flat and state is not None else {}),
            "lod_ms": (time.perf_counter() - t0) * 1e3,
        }
    )
    return rs


def _walk(
    view: ViewState,
    terrain: TerrainStack,
    policy: LodPolicy,
    cache: TileCache,
    record: list[tuple[int, np.ndarray, np.ndarray]] | None = None,
) -> Selection:
    """The level-by-level walk (module docstring). Per level the candidates are slots in the
    cache's level table. With ``record`` the walk appends (level, candidate slots, slots
    refined) per level it tests, in its order (the flat walk's tree, `SelectionState.seed`)."""
    size = terrain.tile_size
    k_px = view.sse_factor
    eye = view.eye
    displace = view.displace
    dkey = displacement_key(view)
    cap = horizon_cap(view)  # None: eye at or below the ellipsoid, nothing hidden
    u0 = None
    if cap is not None and cap > 1e3 * HORIZON_TOL:
        lon0, lat0 = np.radians(view.eye_lonlat_h[:2])
        u0 = np.array([np.cos(lat0) * np.cos(lon0), np.cos(lat0) * np.sin(lon0), np.sin(lat0)])
    frame = FrustumFrame(view)
    # A displacement's bend shrinks with the stride (edges LATTICE-1 spans of the lattice).
    bend_frac = bend_fractions(size)
    max_level = min(int(policy.max_level), MAX_LEVEL)
    # The policy's budget is soft (chunked-sse's from the start): it bounds the children of
    # refined tiles, not the tiles a level must draw anyway. The render set's limit is then
    # held strictly on top of it, with or without a policy budget (a tile refined adds three
    # to the drawn ones, which with the level's candidates stay within it, so the next
    # level's candidates do too): a policy that refines everything would otherwise quadruple
    # its candidates every level, and a soft budget near MAX_TILES could pass it.
    soft = None if policy.max_tiles is None else min(int(policy.max_tiles), MAX_TILES)

    slots = cache.roots(terrain, size)
    out: list[tuple[int, LevelTiles, np.ndarray]] = []
    out_stride: list[np.ndarray] = []
    out_err: list[np.ndarray] = []
    culled_f = culled_h = 0
    drawn = 0
    for level in range(max_level + 1):
        lv = cache.level(level)
        n = len(slots)
        if record is not None:
            record.append((level, slots, slots[:0]))
        c = lv.cols.take(slots, axis=1)
        pts = None
        if displace is None:
            rel_centre = lv.centre.take(slots, axis=0) - eye
            vis_f, amb, open_p = frustum_prefilter(frame, rel_centre, c[COL_MARGIN], c[COL_SPHERE])
            if np.count_nonzero(amb):
                ai = amb.nonzero()[0]
                vis_f[ai] = frame.exact_planes(
                    lv.pts.take(slots.take(ai), axis=0),
                    c[COL_MARGIN].take(ai),
                    open_p.take(ai, axis=0),
                )
        else:
            lv.sync_displacement(dkey)
            pts = lv.displaced(slots, displace)
            vis_f = frustum_visible(view, pts, c[COL_MARGIN])
        # The horizon test only matters for tiles inside the frustum.
        fi = vis_f.nonzero()[0]
        culled_f += n - len(fi)
        if len(fi) < n:
            c = c.take(fi, axis=1)
        if cap is not None and len(fi):
            vis_h = horizon_visible_cached(view, cap, c, u0)
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
            d = norm3(d) - c[COL_RADIUS]
            dist = np.maximum(d, 1.0)
            bend = bend_s = dpts = None
        else:
            assert pts is not None  # set above whenever displaced
            bend = lv.bends(ks, view)
            bend_s = bend[:, None] * bend_frac[None, :]
            err = err + bend_s
            dpts = pts[fi]
            dist = bounding_distance(view, dpts, c[COL_MARGIN])
        tiles = TileCandidates(
            view, terrain, level, size, ks, c, dist, k_px / dist, err, bend, bend_s, lv, dpts, {}
        )
        # The policy's own culling (e.g. Rishe's ground region), on the visible tiles only.
        # What a policy returns is checked (`_checked`: the plain case returns at once).
        keep = _checked(policy, "cull", policy.cull(tiles), (m,), _BOOL, none_ok=True)
        if keep is not None and not keep.all():
            ki = keep.nonzero()[0]
            if len(ki) == 0:
                break
            tiles = _subset(tiles, ki)
            ks, m = tiles._slots, len(ki)
        sse = _checked(policy, "error_px", policy.error_px(tiles), (m, N_STRIDES), _F64)
        # Asked at every level (so what it leaves in tiles.scratch is there for stride());
        # at the deepest level nothing refines.
        refine = _checked(policy, "refine", policy.refine(tiles, sse), (m,), _BOOL)
        if level >= max_level:
            refine = np.zeros(m, dtype=bool)
        # Budget: if refining everything would exceed the tile budget, refine the worst
        # first: the policy's (soft) budget, then the render set's limit (strict).
        n_ref = int(np.count_nonzero(refine))
        priority = None
        if n_ref and soft is not None and n_ref * 4 > soft - drawn - (m - n_ref):
            priority = _checked(policy, "priority", policy.priority(tiles, sse), (m,), _F64)
            refine = budget_refinement(refine, priority, soft - drawn - (m - n_ref), 4)
            n_ref = int(np.count_nonzero(refine))
        if n_ref and drawn + m + 3 * n_ref > MAX_TILES:
            if priority is None:
                priority = _checked(policy, "priority", policy.priority(tiles, sse), (m,), _F64)
            refine = budget_refinement(refine, priority, MAX_TILES - drawn - m, 3)
            n_ref = int(np.count_nonzero(refine))
        if n_ref < m:
            ai = (~refine).nonzero()[0] if n_ref else np.arange(m)
            sse_acc = sse.take(ai, axis=0) if n_ref else sse
            idx = _checked(policy, "stride", policy.stride(tiles, sse_acc, ai), ai.shape, _I64)
            out.append((level, lv, ks.take(ai) if n_ref else ks))
            out_stride.append(idx)
            rows = np.arange(0, len(idx) * N_STRIDES, N_STRIDES)
            out_err.append(sse_acc.ravel().take(rows + idx, mode="clip"))  # checked below
            drawn += len(idx)
        if n_ref == 0:
            break
        refined = ks.take(refine.nonzero()[0]) if n_ref < m else ks
        if record is not None:
            record[-1] = (level, slots, refined)
        slots = cache.children(terrain, level, refined, size)

    if not out:
        empty = np.empty(0, dtype=np.int64)
        return Selection(np.empty((0, 3), dtype=np.int64), empty, np.empty(0), culled_f, culled_h)
    stride_idx = np.concatenate(out_stride)
    # Checked once per frame (the errors taken with a bad index above are dropped with it).
    if stride_idx.min() < 0 or stride_idx.max() >= N_STRIDES:
        name = type(policy).__name__
        raise ValueError(f"{name}.stride returned indices outside 0..{N_STRIDES - 1}")
    keys = np.empty((drawn, 3), dtype=np.int64)
    keys[:, 0] = np.repeat([lvl for lvl, _, _ in out], [len(s) for _, _, s in out])
    keys[:, 1:] = np.concatenate([lv.xy.take(s, axis=0) for _, lv, s in out])
    return Selection(keys, stride_idx, np.concatenate(out_err), culled_f, culled_h)


def _subset(tiles: TileCandidates, idx: np.ndarray) -> TileCandidates:
    """``tiles`` restricted to rows ``idx`` (the policy's scratch follows row-wise where it
    holds per-tile arrays: first axis of length N; scalars and other shapes stay)."""
    n = len(tiles)
    scratch = {
        k: v.take(idx, axis=0)
        if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == n
        else v
        for k, v in tiles.scratch.items()
    }
    return TileCandidates(
        tiles.view,
        tiles.terrain,
        tiles.level,
        tiles.size,
        tiles._slots.take(idx),
        tiles._cols.take(idx, axis=1),
        tiles.dist_m.take(idx),
        tiles.px_per_m.take(idx),
        tiles.err_m.take(idx, axis=0),
        None if tiles._bend is None else tiles._bend.take(idx),
        None if tiles._bend_strides is None else tiles._bend_strides.take(idx, axis=0),
        tiles._lv,
        None if tiles._dpts is None else tiles._dpts.take(idx, axis=0),
        scratch,
    )
