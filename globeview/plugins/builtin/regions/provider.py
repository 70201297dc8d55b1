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

The quadtree walk itself (culling, the per-terrain tile cache, the tile budget) is the shared
traversal (`traverse`); this module is Rishe's policy on it (`RishePolicy`: the ground-region
and cut-off culling, the rings' resolutions, the strides) and the formulas it uses. Stitching
is the shared traversal's (`LodPolicy.stitch`: `render_set_from_tiles`), and the provider is
a `PolicyProvider` naming the policy.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from globeview.plugins.api import (
    MAX_LEVEL,
    MAX_TILES,
    N_STRIDES,
    TILE_BUDGET,
    WGS84,
    LodPolicy,
    PolicyProvider,
    Setting,
    TerrainStack,
    TileCandidates,
    ViewState,
    enu_basis,
    lonlat_to_ecef,
)

#: Metres per degree of latitude (mean), to turn node spacings into metres.
M_PER_DEG = math.pi * WGS84.a / 180.0
#: Rishe §3.1: the far side of the estimated frustum is 9999 x the viewing height.
FAR_FACTOR = 9999.0
#: Rishe §3.1: the ground-region estimate is enlarged by 20 %.
ENLARGE = 1.2


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


def level_and_stride(
    res_m: np.ndarray | float, size: int, max_level: int = MAX_LEVEL
) -> tuple[np.ndarray, np.ndarray]:
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


def _edge_normals(poly: np.ndarray) -> np.ndarray:
    """(..., K, 2) the edge normals of polygons (..., K, 2): those of `polygons_overlap`
    (np.roll(poly, -1) is poly at (i + 1) % K), indexed rather than rolled."""
    k = poly.shape[-2]
    e = poly[..., (np.arange(k) + 1) % k, :] - poly
    return np.stack([-e[..., 1], e[..., 0]], axis=-1)


class RegionOverlap:
    """`polygons_overlap` of one convex ``region`` (K, 2) with many quads, the region's own
    axes and projections computed once (per frame) instead of per level: the same
    separating-axis test with the same floating-point operations per tile, so the same
    answers."""

    def __init__(self, region: np.ndarray) -> None:
        self.region = region
        self.axes = _edge_normals(region)  # (K, 2)
        pr = np.einsum("kj,aj->ak", region, self.axes)
        self.lo, self.hi = pr.min(axis=1), pr.max(axis=1)

    def __call__(self, quads: np.ndarray) -> np.ndarray:
        """(N,) bool: does the region overlap each convex quad of ``quads`` (N, 4, 2)?"""
        # The region's axes.
        pq = np.einsum("nkj,aj->nak", quads, self.axes)
        sep = (self.hi < pq.min(axis=2)) | (pq.max(axis=2) < self.lo)
        # The quads' axes.
        axes = _edge_normals(quads)  # (N, 4, 2)
        pr = np.einsum("kj,naj->nak", self.region, axes)
        pq = np.einsum("nkj,naj->nak", quads, axes)
        sep_q = (pr.max(axis=2) < pq.min(axis=2)) | (pq.max(axis=2) < pr.min(axis=2))
        return ~(sep.any(axis=1) | sep_q.any(axis=1))


# -- helpers of the region test ---------------------------------------------------------------
def _bounding_quads(points: np.ndarray, grow: np.ndarray) -> np.ndarray:
    """(N, 4, 2) counter-clockwise axis-aligned boxes around each tile's 2-D points
    (N, K, 2), grown by ``grow`` (N,) metres on every side."""
    lo = points.min(axis=1) - grow[:, None]
    hi = points.max(axis=1) + grow[:, None]
    return np.stack(
        [lo, np.stack([hi[:, 0], lo[:, 1]], 1), hi, np.stack([lo[:, 0], hi[:, 1]], 1)], axis=1
    )


def _on_ellipsoid(lon_deg: np.ndarray, lat_deg: np.ndarray) -> np.ndarray:
    """(N, 3) ECEF (m) of points on the ellipsoid: `lonlat_to_ecef` at height 0, the same
    operations (adding a zero height is exact) without its broadcasting and copies."""
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    sin_lat = np.sin(lat)
    n = WGS84.a / np.sqrt(1.0 - WGS84.e2 * sin_lat * sin_lat)
    rho = n * np.cos(lat)
    out = np.empty((len(lon), 3))
    out[:, 0] = rho * np.cos(lon)
    out[:, 1] = rho * np.sin(lon)
    out[:, 2] = n * (1.0 - WGS84.e2) * sin_lat
    return out


# -- the provider ------------------------------------------------------------------------------
class RishePolicy(LodPolicy):
    """Rishe's distance-based region subdivision as a policy on the shared traversal (module
    docstring): per frame the region factor R, the ring-1 mesh resolution R_m and the
    ground-region estimate; per level the region / cut-off culling and the rings (`cull`),
    refinement while a tile's node spacing exceeds its ring's resolution (`refine`), and the
    coarsest stride whose cell stays within it (`stride`); same-level borders stitched.

    Args (the provider's settings, module docstring):
        hr_ratio: Rishe's HR_RATIO (larger: finer mesh); c: the speed constant C (m).
        ring1, ring2, ring3: the rings' outer edges in units of R (sorted here).
        cutoff: drop tiles beyond ring 3; max_tiles: the tile budget.
        tile_over_grid: Rishe's Tile_Size / Mesh_Grid_Size: texels of a (256 px) texture
            tile per mesh cell of our 64-cell tiles (with 1, ~2 mesh cells per pixel).
        stitch: stitch same-level borders (Rishe §3.3).
    """

    def __init__(
        self,
        hr_ratio: float = 400.0,
        c: float = 100.0,
        ring1: float = 2.0,
        ring2: float = 8.0,
        ring3: float = 20.0,
        cutoff: bool = True,
        max_tiles: int = 1500,
        tile_over_grid: float = 4.0,
        stitch: bool = True,
    ) -> None:
        super().__init__()
        self.hr_ratio, self.c, self.tile_over_grid = hr_ratio, c, tile_over_grid
        f = sorted((ring1, ring2, ring3))
        self.factors = (f[0], f[1], f[2])
        self.cutoff, self.stitch = cutoff, stitch
        self.max_tiles = max_tiles

    def begin(self, view: ViewState, terrain: TerrainStack) -> None:
        super().begin(view, terrain)
        self.lon0, self.lat0, h0 = view.eye_lonlat_h
        pitch_r, roll = rishe_pitch_roll(view)
        self.height = max(h0, 1.0)
        self.r = region_factor(self.height, pitch_r, roll, view.fovy_deg, view.aspect)
        self.r_m = mesh_resolution(
            self.height,
            view.fovy_deg,
            self.hr_ratio,
            speed_factor(view.speed_mps, view.frame_rate_hz, self.c),
            self.tile_over_grid,
        )
        self.region, self.basis = ground_region(view)
        self.overlap = RegionOverlap(self.region)
        self.nadir = np.asarray(
            lonlat_to_ecef(self.lon0, self.lat0, 0.0), dtype=np.float64
        ).reshape(3)
        self.far_ring = 4 if self.cutoff else 5  # ring 4 = beyond the cut-off distance
        self.culled_r = self.culled_c = 0
        self.rings: list[np.ndarray] = []

    def cull(self, tiles: TileCandidates) -> np.ndarray:
        """Rishe §3.1-3.2: keep the tiles whose footprint meets the ground region, within the
        cut-off ring; remembers each tile's ring."""
        view, level, basis, height = tiles.view, tiles.level, self.basis, self.height
        w, s, e, n = tiles.west, tiles.south, tiles.east, tiles.north
        lon0, lat0, nadir = self.lon0, self.lat0, self.nadir
        # Ground-plane footprint of each tile in the nadir ENU frame: the lattice points
        # (first half of pts: lowest height) and the nearest point of the lon/lat box.
        enu = (tiles.points - nadir) @ basis.T  # (N, K, 3)
        # Points far below the tangent plane (past the horizon, e.g. the far side of a big
        # tile) project back towards the nadir; they would pull D down for nothing.
        front = enu[..., 2] > -1.5 * (height + 2.0 * max(view.exaggeration, 1.0) * 9000.0)
        near_lon = np.clip((lon0 - w + 180.0) % 360.0 - 180.0 + w, w, e)
        near_lat = np.clip(lat0, s, n)
        near = (_on_ellipsoid(near_lon, near_lat) - nadir) @ basis.T
        # max(|east|, |north|) per point (np.max over the 2-long axis, without its loop)
        cheb = np.maximum(np.abs(enu[..., 0]), np.abs(enu[..., 1]))
        d_pts = np.where(front, cheb, np.inf).min(axis=1)
        d = np.minimum(d_pts, np.maximum(np.abs(near[:, 0]), np.abs(near[:, 1])))
        if level == 0:
            d[:] = np.minimum(d, 0.0)  # the two hemispheres are always in range
        ring = ring_of(d, self.r, self.factors)
        # The region test only makes sense for footprints in front of the tangent plane's
        # horizon; big tiles (curvature) and the nadir's own tile always pass.
        quad_idx = np.array([0, 2, 8, 6])  # lattice corners (NW, NE, SE, SW) at the lowest h
        quads = enu[:, quad_idx, :2]
        if view.displace is not None:
            # Displaced, the four corners no longer span the footprint (a fold bends its
            # sides): test the box around every lattice point, grown by the bend.
            quads = _bounding_quads(enu[:, : enu.shape[1] // 2, :2], tiles.bend_m)
        # (= polygons_overlap(self.region, quads) | (level < 4) | (d == 0.0), the test run
        # only where its answer matters)
        in_reg = np.ones(len(d), dtype=bool)
        if level >= 4:
            test = np.flatnonzero(d != 0.0)
            if len(test):
                in_reg[test] = self.overlap(quads.take(test, axis=0))
        near_enough = ring < self.far_ring
        self.culled_r += int(np.count_nonzero(~in_reg))
        self.culled_c += int(np.count_nonzero(in_reg & ~near_enough))
        tiles.scratch["ring"] = ring
        return in_reg & near_enough

    def refine(self, tiles: TileCandidates, error_px: np.ndarray) -> np.ndarray:
        """Rishe §3.2, Table 2: refine while the level's node spacing exceeds the ring's mesh
        resolution (and, displaced, where a fold's bend projects beyond tau at stride 1)."""
        res = ring_resolution(tiles.scratch["ring"], self.r_m)
        spacing = float(node_spacing_m(tiles.level, tiles.size))
        refine = spacing > res
        score = spacing / res
        bend_ok = None
        if tiles.view.displace is not None:
            # The fold's bend at each stride, in pixels (chunked-sse's measure): refine where
            # even stride 1 leaves more than tau, else cap the stride where it stays within.
            bend_px = tiles.bend_m_strides * tiles.px_per_m[:, None]
            bend_ok = bend_px <= self.tau_px
            refine |= ~bend_ok[:, 0]
            score = np.maximum(score, bend_px[:, 0] / self.tau_px)
        tiles.scratch.update(res=res, spacing=spacing, score=score, bend_ok=bend_ok)
        return refine

    def priority(self, tiles: TileCandidates, error_px: np.ndarray) -> np.ndarray:
        return tiles.scratch["score"]

    def stride(self, tiles: TileCandidates, error_px: np.ndarray, index: np.ndarray) -> np.ndarray:
        """The coarsest power-of-two stride whose cell is still within the ring's R_m."""
        sc = tiles.scratch
        size = tiles.size
        k = np.floor(np.log2(np.maximum(sc["res"][index] / sc["spacing"], 1.0))).astype(np.int64)
        k = np.clip(k, 0, min(N_STRIDES - 1, int(math.log2(size - 1))))
        if sc["bend_ok"] is not None:
            # ... and whose chord error across a fold projects within tau.
            ok = sc["bend_ok"][index]
            k_bend = np.where(ok.any(axis=1), N_STRIDES - 1 - np.argmax(ok[:, ::-1], 1), 0)
            k = np.minimum(k, k_bend)
        self.rings.append(sc["ring"][index])
        return k

    def frame_stats(self) -> dict[str, Any]:
        rings = np.concatenate(self.rings) if self.rings else np.empty(0, np.int64)
        return {
            "tiles_culled_region": self.culled_r,
            "tiles_culled_cutoff": self.culled_c,
            "region_R_m": self.r,
            "mesh_res_m": self.r_m,
            **{f"tiles_ring{k}": int(np.count_nonzero(rings == k)) for k in (1, 2, 3)},
        }


class DistanceRegionsProvider(PolicyProvider):
    """Rishe et al.'s distance-based region subdivision (see the module docstring)."""

    name = "distance-regions"
    label = "Distance regions (Rishe)"
    policy = RishePolicy
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
        replace(TILE_BUDGET, default=1500, max=MAX_TILES),
    )  # fmt: skip
