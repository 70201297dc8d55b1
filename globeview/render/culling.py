"""Tile bounding volumes, view-frustum culling and horizon (ellipsoid-occlusion) culling.

Everything is vectorised over arrays of tiles. A tile's bounding volume is a set of sample
points (a k x k lon/lat lattice over the tile at its lowest and highest height) plus a margin
that covers how far the curved surface can bulge between lattice points (the chord sag).
"""

from __future__ import annotations

import math

import numpy as np

from globeview.geodesy import WGS84, lonlat_to_ecef
from globeview.render.view_state import ViewState

#: Lattice points per tile side for bounding volumes.
LATTICE = 3


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
    dist = np.einsum("nkj,pj->npk", rel, planes[:, :3]) + d_eye[None, :, None]
    outside = np.all(dist < -margin[:, None, None], axis=2)
    return ~np.any(outside, axis=1)


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
    lon0, lat0, h0 = view.eye_lonlat_h
    r = WGS84.b
    if h0 <= 0.0:
        return np.ones(len(west), dtype=bool)
    cap = math.acos(r / (r + h0))
    peak = np.maximum(np.asarray(hmax, dtype=np.float64) * exaggeration, 0.0)
    cap_total = cap + np.arccos(r / (r + peak))
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
    p0 = math.radians(lat0)
    dw = np.radians((lon0 - west + 180.0) % 360.0 - 180.0)  # offset east of the west edge
    de = np.radians((lon0 - east + 180.0) % 360.0 - 180.0)
    span = np.radians(east - west)
    inside = (dw >= 0.0) & (dw <= span) | (span >= 2 * math.pi - 1e-12)
    s_r, n_r = np.radians(south), np.radians(north)

    def to_meridian(dlon: np.ndarray) -> np.ndarray:
        lat_star = np.arctan2(math.tan(p0) if abs(p0) < math.pi / 2 else 1e12, np.cos(dlon))
        lat_c = np.clip(lat_star, s_r, n_r)
        return _central_angle(p0, lat_c, dlon)

    same_meridian = np.abs(p0 - np.clip(p0, s_r, n_r))
    other = np.minimum(to_meridian(dw), to_meridian(de))
    return np.where(inside, same_meridian, other)


def _central_angle(lat1: float, lat2: np.ndarray, dlon: np.ndarray) -> np.ndarray:
    c = math.sin(lat1) * np.sin(lat2) + math.cos(lat1) * np.cos(lat2) * np.cos(dlon)
    return np.arccos(np.clip(c, -1.0, 1.0))


def bounding_distance(view: ViewState, points: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """A lower bound (m, >= 1) of the distance from the eye to each tile's surface.

    Uses the bounding sphere of the tile's points (centre = their mean)."""
    centre = points.mean(axis=1)
    radius = np.max(np.linalg.norm(points - centre[:, None, :], axis=2), axis=1) + margin
    d = np.linalg.norm(centre - view.eye, axis=1) - radius
    return np.maximum(d, 1.0)


def displacement_chord_error_m(displace, points: np.ndarray) -> np.ndarray:
    """How far a displacement bends straight edges: for tiles' bounding lattices ``points``
    (N, K, 3) ECEF laid out as (2 heights x L x L) like `culling.tile_bounding_points`, the
    largest distance (m) between the displaced midpoint of two neighbouring lattice points
    and the midpoint of their displaced ends, per tile (N,). Zero for an affine
    displacement. A triangle edge spanning the same length deviates about this much from
    the displaced surface (linearly less for shorter edges, at a fold's kink), so an LOD
    provider can add it to the tile's geometric error to refine where the fold would open
    gaps between neighbouring tiles drawn at different strides."""
    pts = np.asarray(points, dtype=np.float64)
    n, k, _ = pts.shape
    side = round(math.sqrt(k // 2))
    grid = pts.reshape(n, 2, side, side, 3)[:, 0]  # the lower surface suffices
    a = np.concatenate([grid[:, :, :-1].reshape(n, -1, 3), grid[:, :-1, :].reshape(n, -1, 3)], 1)
    b = np.concatenate([grid[:, :, 1:].reshape(n, -1, 3), grid[:, 1:, :].reshape(n, -1, 3)], 1)
    mid = 0.5 * (a + b)
    da, db, dm = (np.asarray(displace(v.reshape(-1, 3))).reshape(v.shape) for v in (a, b, mid))
    return np.max(np.linalg.norm(dm - 0.5 * (da + db), axis=-1), axis=1)
