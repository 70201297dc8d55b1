"""`wavelet`: M-band wavelet LOD after Zhang et al., "Effective techniques for interactive
rendering of global terrain surfaces", §V, vectorised over quadtree tiles.

Zhang partition the visible terrain into tiles by distance, pick for each tile a wavelet
approximation (coarse to fine) and triangulate it hierarchically "until the height error is
smaller than the given height error", with two errors: a *static* error (roughness: rough
areas keep more detail, flat ones are merged) and a *dynamic* error (distance: far regions get
fewer triangles). Here:

- **Tiles and wavelet levels.** The tile store's pyramid *is* a dyadic wavelet approximation:
  quadtree level L of a tile is the approximation a_j with j = (finest level - L), and each
  tile stores the geometric error (metres, max |height - full resolution|) of that
  approximation drawn at index strides 1..64 (`TerrainStack.metadata(...).stride_error`).
- **Level choice** (walk from the root, all candidates at once): a tile is split into its
  children when finer data exists and both
  - its *static* error, the stored error of its approximation (stride 1), exceeds the
    roughness floor ``static_m`` (below it the tile is flat: further wavelet levels add
    nothing visible at any distance), and
  - its *dynamic* error, that error x exaggeration projected to pixels, ``e K / d`` with
    K = viewport height / (2 tan(fovy/2)) and d a lower bound of the eye-tile distance,
    exceeds tau;
  or when the chord sag of the curved globe between its nodes projects beyond tau (geometry
  the flat approximation cannot show, independent of the data); or when, rough with finer
  data, no stride coarser than 1 meets tau (the tile would need its full grid: its children
  draw it with no more triangles, far fewer where the level approximates poorly, and the
  count then never grows with tau).
- **M-band.** With M bands per step a wavelet level divides the resolution by M. The store
  holds dyadic levels only, so: M = 2 may stop at every level; M = 4 = 2^2 only at every
  second level (a split jumps two quadtree levels: 16 children); M = 3 has no dyadic
  counterpart, so a tile may stop only at the dyadic level nearest to, and at least as fine
  as, an exact 3-band level: levels ceil(k log2 3) = 0, 2, 4, 5, 7, 8, 10, ... This keeps the
  3-band *resolution ladder* (each step at least x3 finer), not the 3-band *filter*: the
  filtered heights are the store's dyadic approximations. (`globeview.terrain.mband` can
  compute true 3-band approximations of a tile, but only per tile from its heights — a
  Python loop per tile per frame, which ``select`` must not do.)
- **Triangulation** ("until the height error is below the given error"): the accepted tile is
  drawn with the coarsest index stride whose error (height error x exaggeration + chord sag)
  projects within tau; flat tiles (static error below the floor) take the coarsest stride
  whose *height* error is still below the floor and whose sag projects within tau.
- **Displacement** (a tool's ``view.displace``, e.g. the terrain collapse): culling uses the
  displaced bounding points, and the bend of the displacement over a tile (the collapse's
  fold lines; `culling.displacement_bend_m`, scaled to each stride's edge length) is
  added to the geometry error like the chord sag: a tile whose bend projects beyond tau at
  stride 1 splits, and a stride is only as coarse as keeps it within tau, so long edges
  never cut across a fold and no gap opens between tiles. Nothing changes without one.
- **Crack sewing** (Zhang Fig. 4): same-level neighbours of different strides are stitched
  (`IndexVariant.edge_strides`: the finer tile's edge uses the coarser one's vertices);
  neighbours of different levels meet behind skirts (their heights differ: different wavelet
  approximations).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from globeview.plugins.api import (
    LATTICE,
    N_STRIDES,
    LodProvider,
    RenderSet,
    Setting,
    TerrainStack,
    ViewState,
    bounding_distance,
    chord_sag,
    cull_level,
    displacement_bend_m,
)
from globeview.plugins.builtin.chunked.provider import MAX_LEVEL, stride_errors_m
from globeview.plugins.builtin.regions.provider import push_budget, render_set_from_tiles


def stop_levels(m: int, max_level: int = MAX_LEVEL) -> np.ndarray:
    """(max_level + 1,) bool: the quadtree levels where an M-band ladder may stop.

    M = 2: every level; M = 4: every second level; other M: the dyadic levels
    ceil(k log2 M), the nearest at least as fine as the exact M-band levels."""
    ok = np.zeros(max_level + 1, dtype=bool)
    ok[0] = True
    step = math.log2(m)
    k = 1
    while True:
        lv = math.ceil(k * step - 1e-9)
        if lv > max_level:
            break
        ok[lv] = True
        k += 1
    ok[max_level] = True  # the walk's end is always a stop
    return ok


@dataclass
class WaveletSettings:
    """M: bands per wavelet step (2, 3 or 4); static_m: roughness floor (m); tau_px: screen
    error threshold (px, None = the view's); stitch: sew same-level neighbours."""

    m: int = 2
    static_m: float = 2.0
    tau_px: float | None = None
    stitch: bool = True
    max_tiles: int = 1500


def select_wavelet(
    view: ViewState, terrain: TerrainStack, settings: WaveletSettings | None = None
) -> RenderSet:
    """Zhang §V level and stride choice (module docstring)."""
    st = settings or WaveletSettings()
    t0 = time.perf_counter()
    tau = st.tau_px if st.tau_px else view.tau_px
    size = terrain.tile_size
    exag = view.exaggeration
    k_px = view.sse_factor
    stops = stop_levels(st.m)
    max_stride_idx = min(N_STRIDES - 1, int(math.log2(size - 1)))

    x = np.array([0, 1], dtype=np.int64)
    y = np.zeros(2, dtype=np.int64)
    forced = np.zeros(2, dtype=bool)  # mid-way through an M-band step: must go on
    out_keys, out_stride, out_err = [], [], []
    culled_f = culled_h = 0
    flat_tiles = 0
    drawn = 0
    for level in range(MAX_LEVEL + 1):
        if len(x) == 0:
            break
        cand = cull_level(view, terrain, level, x, y)
        meta = cand.meta
        pts_true, pts, margin = cand.pts_true, cand.pts, cand.margin
        vis_f, vis_h = cand.in_frustum, cand.above_horizon
        culled_f += int(np.count_nonzero(~vis_f))
        culled_h += int(np.count_nonzero(vis_f & ~vis_h))
        keep = vis_f & vis_h
        if not keep.any():
            break
        x, y, forced = x[keep], y[keep], forced[keep]
        herr = meta.stride_error[keep]  # (N, 7) height error of the approximation, metres
        total = stride_errors_m(level, herr, exag, size)
        dist = bounding_distance(view, pts[keep], margin[keep])
        px_per_m = k_px / dist
        static = herr[:, 0]
        dynamic = static * exag * px_per_m
        node_deg = 180.0 / 2**level / (size - 1)
        sag_px = float(chord_sag(node_deg)) * px_per_m
        if view.displace is not None:
            # The displacement's bend (fold lines) counts as geometry, like the sag.
            bend = displacement_bend_m(view, pts_true[keep], pts[keep])
            frac = np.minimum(1.0, 2.0 ** np.arange(N_STRIDES) * (LATTICE - 1) / (size - 1))
            total = total + bend[:, None] * frac[None, :]
            sag_px = sag_px + bend * frac[0] * px_per_m
        rough = static > st.static_m
        finer = meta.has_finer[keep]
        want = (rough & (dynamic > tau) & finer) | (sag_px > tau)
        # A tile whose every coarser stride misses tau needs its full grid at this level: its
        # children draw the same surface with no more triangles (each stride of a level is
        # about the density of the level above), and where the level's approximation is
        # poor - e.g. a layer's border band, a ramp only a few nodes wide here - with far
        # fewer. Refining it keeps the count from growing as tau grows.
        full = ~np.any((total * px_per_m[:, None] <= tau)[:, 1 : max_stride_idx + 1], axis=1)
        want |= full & finer & rough
        if level == MAX_LEVEL:
            want[:] = False
            forced[:] = False
        # At a level that is no stop of the M-band ladder every survivor goes on.
        refine = want | forced | (~stops[level] & (level < MAX_LEVEL))
        room = st.max_tiles - drawn - int(np.count_nonzero(~refine))
        refine = push_budget(refine, np.maximum(dynamic, sag_px) + 1e9 * forced, room, 4)
        acc = ~refine
        if acc.any():
            # Coarsest stride whose total error projects within tau; flat tiles also keep
            # their height error within the roughness floor (they are flat, not invisible).
            sse = total[acc] * px_per_m[acc, None]
            ok = sse <= tau
            flat = ~rough[acc]
            sag_ok = (total[acc] - herr[acc] * exag) * px_per_m[acc, None] <= tau
            ok = np.where(flat[:, None], ok | (sag_ok & (herr[acc] <= st.static_m)), ok)
            ok[:, max_stride_idx + 1 :] = False
            idx = np.where(ok.any(axis=1), N_STRIDES - 1 - np.argmax(ok[:, ::-1], axis=1), 0)
            out_keys.append(np.stack([np.full(len(idx), level), x[acc], y[acc]], axis=1))
            out_stride.append(idx)
            out_err.append(sse[np.arange(len(idx)), idx])
            flat_tiles += int(np.count_nonzero(flat))
            drawn += len(idx)
        rx, ry = x[refine], y[refine]
        # Children of a tile that stopped at a ladder level and still wants detail are forced
        # down to the next stop: that is one M-band step.
        nf = ~stops[min(level + 1, MAX_LEVEL)]
        x = np.concatenate([2 * rx, 2 * rx + 1, 2 * rx, 2 * rx + 1])
        y = np.concatenate([2 * ry, 2 * ry, 2 * ry + 1, 2 * ry + 1])
        forced = np.full(len(x), bool(nf))

    if out_keys:
        rs = render_set_from_tiles(
            np.concatenate(out_keys),
            np.concatenate(out_stride),
            np.concatenate(out_err),
            size,
            st.stitch,
        )
    else:
        rs = RenderSet.empty()
    rs.stats.update(
        {
            "tiles_culled_frustum": culled_f,
            "tiles_culled_horizon": culled_h,
            "tiles_flat": flat_tiles,
            "lod_ms": (time.perf_counter() - t0) * 1e3,
        }
    )
    return rs


class WaveletProvider(LodProvider):
    """Zhang et al.'s M-band wavelet LOD (see the module docstring)."""

    name = "wavelet"
    label = "M-band wavelet (Zhang)"
    settings = (
        Setting("m", "choice", "2", choices=("2", "3", "4"), label="M (bands)",
                help="wavelet bands per level step: resolution divides by M per step."),
        Setting("static_m", "float", 2.0, min=0.0, max=1000.0, label="static error (m)",
                help="roughness floor in metres: tiles whose approximation error is below it "
                "count as flat and are not refined for detail."),
        Setting("tau_px", "float", 0.0, min=0.0, max=64.0, label="tau override (px)",
                help="screen-space error threshold in pixels; 0 uses the view's."),
        Setting("max_tiles", "int", 1500, min=16, max=20000, label="tile budget"),
    )  # fmt: skip

    def select(self, view: ViewState, terrain: TerrainStack) -> RenderSet:
        if terrain is None or not terrain.layers:
            return RenderSet.empty()
        v = self.values
        return select_wavelet(
            view,
            terrain,
            WaveletSettings(
                m=int(v["m"]),
                static_m=v["static_m"],
                tau_px=v["tau_px"] or None,
                max_tiles=v["max_tiles"],
            ),
        )
