"""Tile bounding volumes, view-frustum culling and horizon (ellipsoid-occlusion) culling.

Everything is vectorised over arrays of tiles. A tile's bounding volume is a set of sample
points (a k x k lon/lat lattice over the tile at its lowest and highest height) plus a margin
that covers how far the curved surface can bulge between lattice points (the chord sag).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from globeview.geodesy import WGS84, lonlat_to_ecef
from globeview.lod.view_state import ViewState
from globeview.terrain.compose.metadata import TileMetadata
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.quadtree import tile_bounds_arrays

#: Lattice points per tile side for bounding volumes.
LATTICE = 3


def norm3(v: np.ndarray) -> np.ndarray:
    """np.linalg.norm(v, axis=-1) for vectors of 3 components (the last axis): the same
    operations in the same order (x² + y², then + z²: numpy reduces a 3-long axis that way),
    so the same floats, ~4x faster (a reduce over a 3-long axis pays a loop per vector)."""
    w = v * v
    return np.sqrt(w[..., 0] + w[..., 1] + w[..., 2])


def chord_sag(angle_deg: np.ndarray | float, radius: float = WGS84.a) -> np.ndarray:
    """How far (m) a straight chord spanning ``angle_deg`` of arc dips below the sphere."""
    half = np.radians(np.asarray(angle_deg, dtype=np.float64)) / 2.0
    return radius * (1.0 - np.cos(np.minimum(half, math.pi / 2)))


def tile_bounding_points(
    west: np.ndarray,
    south: np.ndarray,
    east: np.ndarray,
    north: np.ndarray,
    hmin: np.ndarray,
    hmax: np.ndarray,
    exaggeration: float = 1.0,
    displace=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Bounding points of N tiles and the margin (m) that makes them conservative.

    Returns points (N, 2 * LATTICE**2, 3) in ECEF and margin (N,). Heights are multiplied by
    the vertical exaggeration, as the renderer does; ``displace`` (a ViewState's CPU
    displacement, (M, 3) -> (M, 3) ECEF) moves the points where the vertex shader will draw
    them.
    """
    n = len(west)
    t = np.linspace(0.0, 1.0, LATTICE)
    lon = west[:, None] + (east - west)[:, None] * t[None, :]
    lat = north[:, None] + (south - north)[:, None] * t[None, :]
    lon_g = np.broadcast_to(lon[:, None, :], (n, LATTICE, LATTICE))
    lat_g = np.broadcast_to(lat[:, :, None], (n, LATTICE, LATTICE))
    lo = hmin * exaggeration
    hi = hmax * exaggeration
    shape = lon_g.shape
    h = np.stack(
        [np.broadcast_to(lo[:, None, None], shape), np.broadcast_to(hi[:, None, None], shape)],
        axis=1,
    )
    pts = lonlat_to_ecef(
        np.broadcast_to(lon_g[:, None], h.shape), np.broadcast_to(lat_g[:, None], h.shape), h
    )
    spacing = np.maximum(east - west, north - south) / (LATTICE - 1)
    margin = chord_sag(spacing) + 1.0
    pts = pts.reshape(n, -1, 3)
    if displace is not None and n:
        pts = np.asarray(displace(pts.reshape(-1, 3)), dtype=np.float64).reshape(pts.shape)
    return pts, margin


def frustum_visible(view: ViewState, points: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """False for tiles whose every bounding point lies outside one frustum plane (by more
    than the margin). ``points`` (N, K, 3) ECEF; returns (N,) bool."""
    planes = view.frustum_planes
    # Work relative to the eye: keeps the products small and exact enough in float64.
    rel = points - view.eye
    d_eye = planes[:, :3] @ view.eye + planes[:, 3]
    # Every point outside a plane <=> the farthest-inside point is outside it; adding d_eye
    # after the max gives the same float as before it (rounding is monotonic).
    dist = np.einsum("nkj,pj->npk", rel, planes[:, :3]).max(axis=2) + d_eye
    outside = dist < -margin[:, None]
    return ~outside.any(axis=1)


def horizon_cap(view: ViewState) -> float | None:
    """The central angle (radians) a viewer at the eye's height sees ground out to over the
    semi-minor-axis sphere, acos(b / (b + h)); None when the eye is at or below the
    ellipsoid (nothing is hidden). The camera-dependent half of `horizon_visible`."""
    h0 = view.eye_lonlat_h[2]
    if h0 <= 0.0:
        return None
    r = WGS84.b
    return math.acos(r / (r + h0))


def horizon_peak_angle(hmax: np.ndarray, exaggeration: float = 1.0) -> np.ndarray:
    """How much further (central angle, radians) a peak of height ``hmax`` (times the
    exaggeration) shows over the horizon, acos(b / (b + H)): the camera-independent half of
    `horizon_visible`, which a caller may cache per tile."""
    r = WGS84.b
    peak = np.maximum(np.asarray(hmax, dtype=np.float64) * exaggeration, 0.0)
    return np.arccos(r / (r + peak))


def horizon_visible(
    view: ViewState,
    west: np.ndarray,
    south: np.ndarray,
    east: np.ndarray,
    north: np.ndarray,
    hmax: np.ndarray,
    exaggeration: float = 1.0,
) -> np.ndarray:
    """False for tiles hidden behind the horizon (ellipsoid occlusion), vectorised.

    From height h a viewer sees the ground out to the central angle acos(R / (R + h)); a peak
    of height H beyond that shows over the horizon up to acos(R / (R + H)) further. A tile is
    hidden when the central angle from the camera's nadir to the nearest point of its lon/lat
    box exceeds the sum. Using the semi-minor axis b for R makes both angles as large as
    anywhere on the ellipsoid, so the test never hides a visible tile. (Testing a few sample
    points of a tile, Cesium-style, fails for big tiles whose interior holds the nadir.)
    """
    cap = horizon_cap(view)
    if cap is None:
        return np.ones(len(west), dtype=bool)
    lon0, lat0, _ = view.eye_lonlat_h
    cap_total = cap + horizon_peak_angle(hmax, exaggeration)
    return box_angular_distance(lon0, lat0, west, south, east, north) <= cap_total


def box_angular_distance(
    lon0: float,
    lat0: float,
    west: np.ndarray,
    south: np.ndarray,
    east: np.ndarray,
    north: np.ndarray,
) -> np.ndarray:
    """Central angle (radians) from (lon0, lat0) to the nearest point of each lon/lat box.

    Inside the box's longitudes the nearest point is on the same meridian; otherwise it lies
    on the nearer bounding meridian at latitude atan(tan(lat0) / cos(dlon)), clamped to the
    box (the foot of the perpendicular great circle)."""
    west = np.asarray(west, dtype=np.float64)
    east = np.asarray(east, dtype=np.float64)
    return box_angular_distance_pre(
        lon0,
        lat0,
        np.stack([west, east]),
        np.radians(east - west),
        np.radians(south),
        np.radians(north),
    )


def box_angular_distance_pre(
    lon0: float,
    lat0: float,
    west_east: np.ndarray,
    span: np.ndarray,
    south_rad: np.ndarray,
    north_rad: np.ndarray,
) -> np.ndarray:
    """`box_angular_distance` from the boxes' camera-independent parts, precomputed (and
    cacheable per tile): ``west_east`` (2, N) the west and east edges (degrees), ``span``
    radians(east - west), and the south / north edges in radians.

    Both bounding meridians are handled in one (2, N) pass; clamps are written as
    minimum(maximum()) (what np.clip computes, with less call overhead)."""
    p0 = math.radians(lat0)
    # Offsets east of the west (row 0) and of the east edge (row 1), radians.
    d = np.radians((lon0 - west_east + 180.0) % 360.0 - 180.0)
    dw = d[0]
    inside = (dw >= 0.0) & (dw <= span) | (span >= 2 * math.pi - 1e-12)
    # Nearest point on each bounding meridian: the foot of the perpendicular great circle.
    cos_d = np.cos(d)
    lat_star = np.arctan2(math.tan(p0) if abs(p0) < math.pi / 2 else 1e12, cos_d)
    lat_c = np.minimum(np.maximum(lat_star, south_rad), north_rad)
    c = math.sin(p0) * np.sin(lat_c) + math.cos(p0) * np.cos(lat_c) * cos_d
    ang = np.arccos(np.minimum(np.maximum(c, -1.0), 1.0))
    other = np.minimum(ang[0], ang[1])
    same_meridian = np.abs(p0 - np.minimum(np.maximum(p0, south_rad), north_rad))
    return np.where(inside, same_meridian, other)


def bounding_distance(view: ViewState, points: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """A lower bound (m, >= 1) of the distance from the eye to each tile's surface.

    Uses the bounding sphere of the tile's points (centre = their mean)."""
    centre = points.mean(axis=1)
    radius = np.max(norm3(points - centre[:, None, :]), axis=1) + margin
    d = norm3(centre - view.eye) - radius
    return np.maximum(d, 1.0)


def _lattice_edges(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (E,) into a bounding lattice (K = 2 x L x L points, `tile_bounding_points`)
    of the two ends of every edge between neighbouring points of its lower surface."""
    k = points.shape[1]
    side = round(math.sqrt(k // 2))
    idx = np.arange(side * side).reshape(side, side)
    ia = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    ib = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    return ia, ib


def displacement_chord_error_m(
    displace, points: np.ndarray, displaced: np.ndarray | None = None
) -> np.ndarray:
    """How far a displacement bends straight edges: for tiles' bounding lattices ``points``
    (N, K, 3) ECEF laid out as (2 heights x L x L) like `culling.tile_bounding_points`, the
    largest distance (m) between the displaced midpoint of two neighbouring lattice points
    and the midpoint of their displaced ends, per tile (N,). Zero for an affine
    displacement. A triangle edge spanning the same length deviates about this much from
    the displaced surface (linearly less for shorter edges, at a fold's kink), so an LOD
    provider can add it to the tile's geometric error to refine where the fold would open
    gaps between neighbouring tiles drawn at different strides.

    ``displaced`` (N, K, 3), when the caller already has ``displace(points)``, is reused for
    the edges' ends: only the midpoints are displaced then."""
    pts = np.asarray(points, dtype=np.float64)
    n = pts.shape[0]
    if n == 0:
        return np.zeros(0)
    ia, ib = _lattice_edges(pts)
    a, b = pts[:, ia], pts[:, ib]
    mid = 0.5 * (a + b)
    if displaced is None:
        da, db, dm = (np.asarray(displace(v.reshape(-1, 3))).reshape(v.shape) for v in (a, b, mid))
    else:
        disp = np.asarray(displaced, dtype=np.float64)
        da, db = disp[:, ia], disp[:, ib]
        dm = np.asarray(displace(mid.reshape(-1, 3)), dtype=np.float64).reshape(mid.shape)
    return np.max(norm3(dm - 0.5 * (da + db)), axis=1)


def displacement_bend_m(
    view: ViewState, points: np.ndarray, displaced: np.ndarray | None = None
) -> np.ndarray:
    """The bend (m) of ``view.displace`` over tiles' bounding lattices ``points`` (N, K, 3),
    per tile (N,): what an LOD provider adds to a tile's geometric error (scaled by stride).

    Uses the active tool's cheap conservative bound (``view.displacement_bend``, e.g. the
    collapse's, nonzero in practice only for tiles a fold line crosses) when it has one, else
    the exact `displacement_chord_error_m`. ``displaced`` = ``view.displace(points)`` when
    the caller already has it (saves displacing the lattice again). Zeros without a
    displacement."""
    pts = np.asarray(points, dtype=np.float64)
    if view.displace is None or len(pts) == 0:
        return np.zeros(len(pts))
    if view.displacement_bend is not None:
        return np.asarray(view.displacement_bend(pts, displaced), dtype=np.float64)
    return displacement_chord_error_m(view.displace, pts, displaced)


@dataclass
class LevelCandidates:
    """One level's candidate tiles with their bounds (degrees), metadata, bounding lattice
    before (``pts_true``) and after (``pts``) the view's displacement, margins (m), and the
    frustum / horizon visibility masks."""

    west: np.ndarray
    south: np.ndarray
    east: np.ndarray
    north: np.ndarray
    meta: TileMetadata
    pts_true: np.ndarray
    pts: np.ndarray
    margin: np.ndarray
    in_frustum: np.ndarray
    above_horizon: np.ndarray


def cull_level(
    view: ViewState, terrain: TerrainStack, level: int, x: np.ndarray, y: np.ndarray
) -> LevelCandidates:
    """The per-level step LOD providers share: tile bounds, metadata, bounding lattice (moved
    by ``view.displace``), and frustum and horizon culling, for tiles (level, x, y)."""
    exag = view.exaggeration
    w, s, e, n = tile_bounds_arrays(level, x, y)
    meta = terrain.metadata(level, x, y)
    pts_true, margin = tile_bounding_points(w, s, e, n, meta.hmin, meta.hmax, exag)
    pts = pts_true
    if view.displace is not None:
        pts = np.asarray(view.displace(pts.reshape(-1, 3)), dtype=np.float64).reshape(pts.shape)
    return LevelCandidates(
        w,
        s,
        e,
        n,
        meta,
        pts_true,
        pts,
        margin,
        frustum_visible(view, pts, margin),
        horizon_visible(view, w, s, e, n, meta.hmax, exag),
    )
