"""`distance-regions`: distance-based region subdivision (Rishe et al., "Level of Detail Control
and Multi-Resolution Model for Online 3D GIS", §3), vectorised over quadtree tiles.

Per frame:

1. **View-culling estimate** (§3.1): the four corner rays of the frustum are intersected with
   the ground plane z = 0 of the ENU frame at the camera's nadir (rays that miss it stop at
   the paper's far distance, 9999 x height); the quadrilateral is enlarged by 20 % about its
   centroid. Tiles whose footprint (projected into that frame) misses it are culled, on top
   of the exact frustum and horizon tests of `globeview.lod.culling`.
2. **Region subdivision** (§3.2): R = Height tan(max(|pitch|, |roll|, fovy) / 2)
   max(1, aspect); a tile's projected distance D = max(|dx|, |dy|) (nadir ENU frame, metres)
   to its nearest point puts it in ring 1 (D <= 2R), 2 (<= 8R), 3 (<= 20R) or 4 (cut off).
3. **Resolution** (§3.2, Table 2): ring k gets mesh resolution R_m 2^(k-1) metres per grid
   cell, with R_t = Height / (HR_RATIO tan(fovy/2)) / Speed_Factor and
   R_m = R_t (Tile_Size / Mesh_Grid_Size) / Speed_Factor. The quadtree is refined while a
   tile's node spacing (level L: (180 / 2^L) / (size - 1) degrees along a meridian) exceeds its
   ring's R_m; an accepted tile is drawn with the coarsest power-of-two index stride whose
   cell is still within R_m.
4. **Border stitching** (§3.3): a tile whose same-level neighbour is drawn at a coarser stride
   gets that edge drawn at the neighbour's stride (`IndexVariant.edge_strides`), so the two
   share every edge vertex: no T-junction, no crack. Tiles of different levels do not share
   heights (the coarser one is a wavelet approximation), so they meet behind skirts.

Displacement (a tool's ``view.displace``, e.g. the terrain collapse): culling uses the displaced
bounding points, and the collapse's fold lines, where the displacement is not affine, bend the drawn
surface away from long straight edges, so a ring's resolution alone would leave gaps between tiles a
fold crosses. The bend over a tile (`culling.displacement_bend_m`: the tool's cheap bound, or the
exact measure; scaled to each stride's edge length) is therefore projected to pixels like
chunked-sse's error: tiles where it exceeds tau at stride 1 refine beyond their ring's level, and an
accepted tile takes no stride coarser than the one that keeps it within tau. The region test then
covers the whole displaced lattice (its bounding box, grown by the bend) rather than its four
corners. With no displacement nothing changes.

Departures from the paper (see each place for the why): the speed factor divides the
resolution (coarser when moving fast, as §2 intends; the printed formula multiplies);
Tile_Size / Mesh_Grid_Size is 4 (a 256 px imagery tile over our 64-cell mesh tile); the
x/y ratio is the viewport's width / height (the side that widens the footprint).

The stitching helpers here (`neighbour_edge_strides`, `render_set_from_tiles`) are shared with
the `wavelet` provider.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from globeview.plugins.api import (
    LATTICE,
    N_STRIDES,
    WGS84,
    IndexVariant,
    LodProvider,
    RenderSet,
    Setting,
    TerrainStack,
    ViewState,
    bounding_distance,
    cull_level,
    displacement_bend_m,
    enu_basis,
    lonlat_to_ecef,
)
from globeview.plugins.builtin.chunked.provider import MAX_LEVEL, stride_errors_m

#: Metres per degree of latitude (mean), to turn node spacings into metres.
M_PER_DEG = math.pi * WGS84.a / 180.0
#: Rishe §3.1: the far side of the estimated frustum is 9999 x the viewing height.
FAR_FACTOR = 9999.0
#: Rishe §3.1: the ground-region estimate is enlarged by 20 %.
ENLARGE = 1.2
_POLES = (None, "north", "south", "both")


# -- Rishe's formulas (pure functions) ---------------------------------------------------------
def rishe_pitch_roll(view: ViewState) -> tuple[float, float]:
    """The camera's pitch and roll (degrees) in Rishe's convention.

    Our pitch (Cesium's) is -90 looking straight down and 0 at the horizon; Rishe's pitch is 0
    looking straight down (the viewpoint is rotated away from the nadir by it), so
    rishe_pitch = our_pitch + 90. Roll is the same in both: the rotation about the view axis.
    """
    lon, lat, _ = view.eye_lonlat_h
    u = enu_basis(lon, lat)[2]
    right, _up, back = view.rotation
    fwd = -back
    pitch = math.degrees(math.asin(float(np.clip(fwd @ u, -1.0, 1.0))))
    # Roll: how far the right vector tilts out of the horizontal plane.
    roll = math.degrees(math.asin(float(np.clip(right @ u, -1.0, 1.0))))
    return pitch + 90.0, roll


def region_factor(
    height_m: float, pitch_deg: float, roll_deg: float, fovy_deg: float, xy_ratio: float
) -> float:
    """Rishe's sub-division factor R (metres): Height tan(max(|pitch|, |roll|, fovy)/2)
    max(1, xy_ratio). ``pitch_deg`` is in Rishe's convention (0 = looking straight down)."""
    ang = max(abs(pitch_deg), abs(roll_deg), fovy_deg)
    # Beyond 180 degrees the tangent turns negative; the widest meaningful cone is a half-space.
    ang = min(ang, 179.0)
    return max(height_m, 1.0) * math.tan(math.radians(ang) / 2.0) * max(1.0, xy_ratio)


def speed_factor(speed_mps: float, frame_rate_hz: float, c: float = 100.0) -> float:
    """Rishe's Speed_Factor = 1 - min(HSpeed / (FrameRate C), 0.5), in [0.5, 1]."""
    return 1.0 - min(speed_mps / (max(frame_rate_hz, 1e-6) * c), 0.5)


def mesh_resolution(
    height_m: float,
    fovy_deg: float,
    hr_ratio: float = 400.0,
    speed: float = 1.0,
    tile_over_grid: float = 1.0,
) -> float:
    """Ring-1 mesh resolution R_m (metres per grid cell).

    R_t = Height / (HR_RATIO tan(fovy/2)) is the texel size (m); R_m = R_t Tile_Size /
    Mesh_Grid_Size. The speed factor (<= 1) *divides* both, so faster navigation coarsens the
    mesh (Rishe's §2 aim: less data per frame when more of the scene changes per frame; the
    paper's printed formula multiplies, which would refine it instead).
    """
    r_t = max(height_m, 1.0) / (hr_ratio * math.tan(math.radians(fovy_deg) / 2.0)) / speed
    return r_t * tile_over_grid / speed


def ring_of(
    d: np.ndarray, r: float, factors: tuple[float, float, float] = (2.0, 8.0, 20.0)
) -> np.ndarray:
    """Ring (1, 2, 3, or 4 = beyond the cut-off) of projected distances ``d`` (metres) for the
    sub-division factor ``r`` (metres), Rishe Table 1."""
    d = np.asarray(d, dtype=np.float64)
    f1, f2, f3 = factors
    return np.where(d <= f1 * r, 1, np.where(d <= f2 * r, 2, np.where(d <= f3 * r, 3, 4)))


def ring_resolution(rings: np.ndarray, r_m: float) -> np.ndarray:
    """Mesh resolution (metres per cell) of each ring: R_m, R_m/2, R_m/4 *in detail* (Table 2),
    i.e. cells of R_m, 2 R_m, 4 R_m metres. Ring 4 (not cut off) keeps ring 3's."""
    return r_m * 2.0 ** (np.minimum(np.asarray(rings), 3) - 1)


def node_spacing_m(level: int | np.ndarray, size: int) -> np.ndarray:
    """North-south node spacing (m) of quadtree level ``level`` for tiles of ``size`` nodes."""
    return 180.0 / 2.0 ** np.asarray(level, dtype=np.float64) / (size - 1) * M_PER_DEG


def level_and_stride(res_m: np.ndarray | float, size: int, max_level: int = MAX_LEVEL):
    """The (level, stride) drawing cells of at most ``res_m`` metres with the fewest tiles:
    the coarsest level whose node spacing is within res_m, stride 1 (a coarser level drawn
    at stride 1 always beats a finer level at stride 2 on tile count)."""
    res = np.asarray(res_m, dtype=np.float64)
    top = node_spacing_m(0, size)
    level = np.ceil(np.log2(np.maximum(top / np.maximum(res, 1e-9), 1.0)))
    return np.minimum(level, max_level).astype(np.int64), np.ones_like(level, dtype=np.int64)


# -- the ground-region estimate ----------------------------------------------------------------
def ground_region(view: ViewState, enlarge: float = ENLARGE) -> tuple[np.ndarray, np.ndarray]:
    """Rishe §3.1: the frustum intersected with the ground plane under the camera.

    Returns (polygon (4, 2) metres, counter-clockwise, in the ENU frame at the nadir, enlarged
    by ``enlarge`` about its centroid; basis (3, 3) rows E, N, U of that frame). A corner ray
    that does not reach the plane (looking above the horizon) stops at the paper's far
    distance, 9999 x height, projected onto the plane.
    """
    lon, lat, h = view.eye_lonlat_h
    basis = enu_basis(lon, lat)
    height = max(h, 1.0)
    t = math.tan(math.radians(view.fovy_deg) / 2.0)
    ta = t * view.aspect
    corners_cam = np.array([[-ta, -t, -1.0], [ta, -t, -1.0], [ta, t, -1.0], [-ta, t, -1.0]])
    d = corners_cam @ view.rotation @ basis.T  # camera -> ECEF -> ENU, (4, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    far = FAR_FACTOR * height
    with np.errstate(divide="ignore"):
        t_hit = np.where(d[:, 2] < -1e-12, height / -d[:, 2], far)
    t_hit = np.minimum(t_hit, far)
    pts = d[:, :2] * t_hit[:, None]
    # Counter-clockwise order (a roll or a camera looking up can flip it).
    area2 = np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    if area2 < 0:
        pts = pts[::-1]
    c = pts.mean(axis=0)
    return c + (pts - c) * enlarge, basis


def polygons_overlap(region: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(N,) bool: does convex ``region`` (K, 2) overlap each convex quad of ``quads`` (N, 4, 2)?

    Separating-axis test over the edge normals of both, vectorised over the N quads."""

    def normals(poly: np.ndarray) -> np.ndarray:  # (..., K, 2) -> (..., K, 2)
        e = np.roll(poly, -1, axis=-2) - poly
        return np.stack([-e[..., 1], e[..., 0]], axis=-1)

    n = len(quads)
    axes = np.concatenate(
        [np.broadcast_to(normals(region)[None], (n, len(region), 2)), normals(quads)], axis=1
    )  # (N, A, 2)
    pr = np.einsum("kj,naj->nak", region, axes)
    pq = np.einsum("nkj,naj->nak", quads, axes)
    sep = (pr.max(axis=2) < pq.min(axis=2)) | (pq.max(axis=2) < pr.min(axis=2))
    return ~np.any(sep, axis=1)


# -- stitching and the render set (shared with the wavelet provider) --------------------------
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
    for k, (dx, dy) in enumerate(((0, -1), (0, 1), (-1, 0), (1, 0))):
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
    """A RenderSet for tiles ``keys`` drawn at strides 2**stride_idx, with skirts, pole fans,
    and (``stitch``) edges stitched to coarser same-level neighbours."""
    if len(keys) == 0:
        return RenderSet.empty()
    keys = np.asarray(keys, dtype=np.int64)
    stride_idx = np.asarray(stride_idx, dtype=np.int64)
    strides = 1 << stride_idx
    pole = (keys[:, 2] == 0).astype(np.int64) + 2 * (keys[:, 2] == (1 << keys[:, 0]) - 1)
    if stitch:
        edges = np.minimum(neighbour_edge_strides(keys, strides), size - 1)
    else:
        edges = np.repeat(strides[:, None], 4, axis=1)
    combo = np.concatenate([strides[:, None], pole[:, None], edges], axis=1)
    uniq, ids = np.unique(combo, axis=0, return_inverse=True)
    variants = []
    for s, p, en, es, ew, ee in uniq.tolist():
        e4 = (en, es, ew, ee)
        variants.append(
            IndexVariant(
                stride=s, skirts=True, pole=_POLES[p], edge_strides=None if max(e4) == s else e4
            )
        )
    rs = RenderSet(keys, ids.reshape(-1), variants, error_px=np.asarray(error_px, float))
    return rs


def _bounding_quads(points: np.ndarray, grow: np.ndarray) -> np.ndarray:
    """(N, 4, 2) counter-clockwise axis-aligned boxes around each tile's 2-D points
    (N, K, 2), grown by ``grow`` (N,) metres on every side."""
    lo = points.min(axis=1) - grow[:, None]
    hi = points.max(axis=1) + grow[:, None]
    return np.stack(
        [lo, np.stack([hi[:, 0], lo[:, 1]], 1), hi, np.stack([lo[:, 0], hi[:, 1]], 1)], axis=1
    )


def push_budget(refine: np.ndarray, score: np.ndarray, room: int, fanout: int) -> np.ndarray:
    """Limit refinement so the drawn tiles stay within the budget: refine the worst first."""
    n_ref = int(np.count_nonzero(refine))
    if n_ref * fanout <= room or n_ref == 0:
        return refine
    allowed = max(room // fanout, 0)
    order = np.argsort(-score)
    idx = order[refine[order]][:allowed]
    out = np.zeros_like(refine)
    out[idx] = True
    return out


# -- the provider ------------------------------------------------------------------------------
@dataclass
class RegionSettings:
    """Settings of the distance-region selection (see the module docstring)."""

    hr_ratio: float = 400.0
    c: float = 100.0
    factors: tuple[float, float, float] = (2.0, 8.0, 20.0)
    cutoff: bool = True
    stitch: bool = True
    max_tiles: int = 1500
    #: Rishe's Tile_Size / Mesh_Grid_Size: texels of a (256 px) texture tile per mesh cell of
    #: our 64-cell tiles. With 1 (one mesh cell per texel) the mesh is ~2 cells per pixel.
    tile_over_grid: float = 4.0


def select_regions(
    view: ViewState, terrain: TerrainStack, settings: RegionSettings | None = None
) -> RenderSet:
    """Rishe's distance-based region subdivision on the quadtree (module docstring)."""
    st = settings or RegionSettings()
    t0 = time.perf_counter()
    size = terrain.tile_size
    exag = view.exaggeration
    lon0, lat0, h0 = view.eye_lonlat_h
    pitch_r, roll = rishe_pitch_roll(view)
    height = max(h0, 1.0)
    r = region_factor(height, pitch_r, roll, view.fovy_deg, view.aspect)
    r_m = mesh_resolution(
        height,
        view.fovy_deg,
        st.hr_ratio,
        speed_factor(view.speed_mps, view.frame_rate_hz, st.c),
        st.tile_over_grid,
    )
    region, basis = ground_region(view)
    nadir = np.asarray(lonlat_to_ecef(lon0, lat0, 0.0), dtype=np.float64).reshape(3)
    far_ring = 4 if st.cutoff else 5  # ring 4 = beyond the cut-off distance

    x = np.array([0, 1], dtype=np.int64)
    y = np.zeros(2, dtype=np.int64)
    out_keys, out_stride, out_err, out_ring = [], [], [], []
    culled_f = culled_h = culled_r = culled_c = 0
    drawn = 0
    for level in range(MAX_LEVEL + 1):
        if len(x) == 0:
            break
        cand = cull_level(view, terrain, level, x, y)
        w, s, e, n, meta = cand.west, cand.south, cand.east, cand.north, cand.meta
        pts_true, pts, margin = cand.pts_true, cand.pts, cand.margin
        vis_f, vis_h = cand.in_frustum, cand.above_horizon
        # Ground-plane footprint of each tile in the nadir ENU frame: the lattice points
        # (first half of pts: lowest height) and the nearest point of the lon/lat box.
        enu = (pts - nadir) @ basis.T  # (N, K, 3)
        # Points far below the tangent plane (past the horizon, e.g. the far side of a big
        # tile) project back towards the nadir; they would pull D down for nothing.
        front = enu[..., 2] > -1.5 * (height + 2.0 * max(exag, 1.0) * 9000.0)
        near_lon = np.clip((lon0 - w + 180.0) % 360.0 - 180.0 + w, w, e)
        near_lat = np.clip(lat0, s, n)
        near = (np.asarray(lonlat_to_ecef(near_lon, near_lat, 0.0)).reshape(-1, 3) - nadir) @ (
            basis.T
        )
        d_pts = np.where(front, np.max(np.abs(enu[..., :2]), axis=2), np.inf).min(axis=1)
        d = np.minimum(d_pts, np.max(np.abs(near[:, :2]), axis=1))
        if level == 0:
            d[:] = np.minimum(d, 0.0)  # the two hemispheres are always in range
        ring = ring_of(d, r, st.factors)
        # The region test only makes sense for footprints in front of the tangent plane's
        # horizon; big tiles (curvature) and the nadir's own tile always pass.
        quad_idx = np.array([0, 2, 8, 6])  # lattice corners (NW, NE, SE, SW) at the lowest h
        quads = enu[:, quad_idx, :2]
        bend = np.zeros(len(x))
        if view.displace is not None:
            # Displaced, the four corners no longer span the footprint (a fold bends its
            # sides): test the box around every lattice point, grown by the bend.
            bend = displacement_bend_m(view, pts_true, pts)
            quads = _bounding_quads(enu[:, : enu.shape[1] // 2, :2], bend)
        in_reg = polygons_overlap(region, quads) | (level < 4) | (d == 0.0)
        keep = vis_f & vis_h & in_reg & (ring < far_ring)
        culled_f += int(np.count_nonzero(~vis_f))
        culled_h += int(np.count_nonzero(vis_f & ~vis_h))
        culled_r += int(np.count_nonzero(vis_f & vis_h & ~in_reg))
        culled_c += int(np.count_nonzero(vis_f & vis_h & in_reg & (ring >= far_ring)))
        if not keep.any():
            break
        x, y, ring, bend = x[keep], y[keep], ring[keep], bend[keep]
        err = stride_errors_m(level, meta.stride_error[keep], exag, size)
        dist = bounding_distance(view, pts[keep], margin[keep])
        res = ring_resolution(ring, r_m)
        spacing = float(node_spacing_m(level, size))
        refine = (spacing > res) & (level < MAX_LEVEL)
        score = spacing / res
        bend_ok = None
        if view.displace is not None:
            # The fold's bend at each stride, in pixels (chunked-sse's measure): refine where
            # even stride 1 leaves more than tau, else cap the stride where it stays within.
            frac = np.minimum(1.0, 2.0 ** np.arange(N_STRIDES) * (LATTICE - 1) / (size - 1))
            bend_px = bend[:, None] * frac[None, :] * (view.sse_factor / dist)[:, None]
            err = err + bend[:, None] * frac[None, :]
            bend_ok = bend_px <= view.tau_px
            refine |= ~bend_ok[:, 0] & (level < MAX_LEVEL)
            score = np.maximum(score, bend_px[:, 0] / view.tau_px)
        room = st.max_tiles - drawn - int(np.count_nonzero(~refine))
        refine = push_budget(refine, score, room, 4)
        acc = ~refine
        if acc.any():
            # The coarsest power-of-two stride whose cell is still within the ring's R_m.
            k = np.floor(np.log2(np.maximum(res[acc] / spacing, 1.0))).astype(np.int64)
            k = np.clip(k, 0, min(N_STRIDES - 1, int(math.log2(size - 1))))
            if bend_ok is not None:
                # ... and whose chord error across a fold projects within tau.
                ok = bend_ok[acc]
                k_bend = np.where(ok.any(axis=1), N_STRIDES - 1 - np.argmax(ok[:, ::-1], 1), 0)
                k = np.minimum(k, k_bend)
            out_keys.append(np.stack([np.full(len(k), level), x[acc], y[acc]], axis=1))
            out_stride.append(k)
            out_err.append(err[acc][np.arange(len(k)), k] * view.sse_factor / dist[acc])
            out_ring.append(ring[acc])
            drawn += len(k)
        rx, ry = x[refine], y[refine]
        x = np.concatenate([2 * rx, 2 * rx + 1, 2 * rx, 2 * rx + 1])
        y = np.concatenate([2 * ry, 2 * ry, 2 * ry + 1, 2 * ry + 1])

    if out_keys:
        keys = np.concatenate(out_keys)
        rs = render_set_from_tiles(
            keys, np.concatenate(out_stride), np.concatenate(out_err), size, st.stitch
        )
        rings = np.concatenate(out_ring)
    else:
        rs, rings = RenderSet.empty(), np.empty(0, np.int64)
    rs.stats.update(
        {
            "tiles_culled_frustum": culled_f,
            "tiles_culled_horizon": culled_h,
            "tiles_culled_region": culled_r,
            "tiles_culled_cutoff": culled_c,
            "region_R_m": r,
            "mesh_res_m": r_m,
            **{f"tiles_ring{k}": int(np.count_nonzero(rings == k)) for k in (1, 2, 3)},
            "lod_ms": (time.perf_counter() - t0) * 1e3,
        }
    )
    return rs


class DistanceRegionsProvider(LodProvider):
    """Rishe et al.'s distance-based region subdivision (see the module docstring)."""

    name = "distance-regions"
    label = "Distance regions (Rishe)"
    settings = (
        Setting("hr_ratio", "float", 400.0, min=10.0, max=10000.0, label="HR_RATIO",
                help="Rishe's empirical constant: larger = finer mesh (unitless)."),
        Setting("c", "float", 100.0, min=1.0, max=10000.0, label="speed constant C",
                help="Speed_Factor = 1 - min(speed / (frame rate * C), 0.5); metres."),
        Setting("ring1", "float", 2.0, min=0.1, max=100.0, label="ring 1 (x R)",
                help="outer edge of ring 1 in units of R."),
        Setting("ring2", "float", 8.0, min=0.1, max=1000.0, label="ring 2 (x R)",
                help="outer edge of ring 2 in units of R."),
        Setting("ring3", "float", 20.0, min=0.1, max=10000.0, label="ring 3 (x R)",
                help="outer edge of ring 3 (the cut-off) in units of R."),
        Setting("cutoff", "bool", True, label="cut off beyond ring 3",
                help="drop tiles farther than ring 3 (Rishe's artificial horizon)."),
        Setting("max_tiles", "int", 1500, min=16, max=20000, label="tile budget"),
    )  # fmt: skip

    def select(self, view: ViewState, terrain: TerrainStack) -> RenderSet:
        if terrain is None or not terrain.layers:
            return RenderSet.empty()
        v = self.values
        f = sorted((v["ring1"], v["ring2"], v["ring3"]))
        return select_regions(
            view,
            terrain,
            RegionSettings(
                hr_ratio=v["hr_ratio"],
                c=v["c"],
                factors=(f[0], f[1], f[2]),
                cutoff=v["cutoff"],
                max_tiles=v["max_tiles"],
            ),
        )
