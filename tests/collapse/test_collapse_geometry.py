"""The collapse mapping on the ellipsoid (numpy only): identity at r = 1, A and B brought to
r d apart, cross-axis offsets and heights kept, continuity, the exact inverse, for short and
long pairs in every orientation and across the antimeridian."""

from __future__ import annotations

import math

import numpy as np
import pytest

from globeview.geodesy import ecef_to_lonlat, geodesic_direct, geodesic_inverse, lonlat_to_ecef
from globeview.plugins.builtin.collapse.geometry import CollapseFrame

# (centre lon, centre lat, azimuth of A->B in degrees)
ORIENTATIONS = {
    "east-west": (10.0, 45.0, 90.0),
    "north-south": (10.0, 45.0, 0.0),
    "oblique": (-122.5, 46.0, 33.0),
    "antimeridian": (180.0, -20.0, 75.0),
    "antimeridian-ns": (-179.99, 60.0, 170.0),
}
DISTANCES_M = (1.0e3, 3.0e5, 5.0e6)


def pair(name: str, dist_m: float) -> tuple[float, float, float, float]:
    """A and B (lon, lat degrees) dist_m apart along a geodesic through a centre point."""
    lon, lat, az = ORIENTATIONS[name]
    la, pa, _ = geodesic_direct(lon, lat, az + 180.0, dist_m / 2)
    lb, pb, _ = geodesic_direct(lon, lat, az, dist_m / 2)
    return float(la), float(pa), float(lb), float(pb)


def axis_coords(frame: CollapseFrame, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Independent oracle of the along/cross-axis coordinates (m): from the great-circle
    plane through A and B rebuilt here (not the frame's vectors): along = R_M * angle of the
    point's in-plane projection measured from the plane's midpoint direction; cross = R_M *
    elevation angle above the plane."""
    a = lonlat_to_ecef(frame.lon_a, frame.lat_a, 0.0)
    b = lonlat_to_ecef(frame.lon_b, frame.lat_b, 0.0)
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    n = np.cross(a, b)
    n /= np.linalg.norm(n)
    mid = (a + b) / np.linalg.norm(a + b)
    lon, lat, _ = ecef_to_lonlat(pts)
    u = lonlat_to_ecef(lon, lat, 0.0)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    inplane = u - (u @ n)[:, None] * n
    cosang = inplane @ mid / np.linalg.norm(inplane, axis=-1)
    sinang = np.cross(mid, inplane) @ n / np.linalg.norm(inplane, axis=-1)
    return frame.r_m * np.arctan2(sinang, cosang), frame.r_m * np.arcsin(u @ n)


def cloud(frame: CollapseFrame, rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """Random points (ECEF) around the zone: along-axis within 3 zone lengths, cross-axis
    within one zone length (at least 2 km), heights -400..8000 m."""
    d = max(frame.d_m, 2e3)
    psi = rng.uniform(-3, 3, n) * frame.psi0
    c = rng.uniform(-1, 1, n) * d / frame.r_m
    dirs = np.cos(c)[:, None] * (np.cos(psi)[:, None] * frame.m + np.sin(psi)[:, None] * frame.t)
    dirs += np.sin(c)[:, None] * frame.n
    lon, lat, _ = ecef_to_lonlat(dirs * 6.4e6)
    return lonlat_to_ecef(lon, lat, rng.uniform(-400, 8000, n))


CASES = [(name, d) for name in ORIENTATIONS for d in DISTANCES_M]


@pytest.mark.parametrize(("name", "dist"), CASES)
def test_ratio_one_is_the_identity(name: str, dist: float) -> None:
    frame = CollapseFrame.from_lonlat(*pair(name, dist), 1.0)
    pts = cloud(frame, np.random.default_rng(1))
    assert np.array_equal(frame.forward(pts), pts)
    assert np.array_equal(frame.inverse(pts), pts)


@pytest.mark.parametrize(("name", "dist"), CASES)
@pytest.mark.parametrize("ratio", [0.2, 0.5])
def test_a_and_b_come_r_d_apart_keeping_cross_offsets_and_heights(
    name: str, dist: float, ratio: float
) -> None:
    frame = CollapseFrame.from_lonlat(*pair(name, dist), ratio)
    assert frame.d_m == pytest.approx(dist, rel=4e-3)  # angle * R_M vs geodesic length
    ab = lonlat_to_ecef(
        np.array([frame.lon_a, frame.lon_b]), np.array([frame.lat_a, frame.lat_b]), [1500.0, 30.0]
    )
    s0, _ = axis_coords(frame, ab)
    s1, c1 = axis_coords(frame, frame.forward(ab))
    assert s0[1] - s0[0] == pytest.approx(frame.d_m, abs=1e-3)
    assert abs((s1[1] - s1[0]) - ratio * frame.d_m) <= 1.0
    assert np.all(np.abs(c1) <= 1.0)
    # Every point: cross-axis offset and ellipsoidal height unchanged (<= 1 m).
    pts = cloud(frame, np.random.default_rng(2))
    out = frame.forward(pts)
    s_in, c_in = axis_coords(frame, pts)
    s_out, c_out = axis_coords(frame, out)
    assert np.max(np.abs(c_out - c_in)) <= 1.0
    assert np.max(np.abs(ecef_to_lonlat(out)[2] - ecef_to_lonlat(pts)[2])) <= 1.0
    # Along the axis: scaled by r inside the zone, shifted by (1 - r) d / 2 outside.
    half = frame.d_m / 2
    want = np.where(np.abs(s_in) <= half, ratio * s_in, s_in - np.sign(s_in) * (1 - ratio) * half)
    assert np.max(np.abs(s_out - want)) <= 1.0


@pytest.mark.parametrize(("name", "dist"), CASES)
def test_true_distances_scale_by_r(name: str, dist: float) -> None:
    """A metric independent of the frame: the geodesic A'B' is r times AB, to within the
    ellipsoid's flattening (the axis coordinate is R_M x angle, not the ellipse's arc)."""
    frame = CollapseFrame.from_lonlat(*pair(name, dist), 0.25)
    ab = lonlat_to_ecef(
        np.array([frame.lon_a, frame.lon_b]), np.array([frame.lat_a, frame.lat_b]), 0.0
    )
    lon, lat, _ = ecef_to_lonlat(frame.forward(ab))
    _, _, d_after = geodesic_inverse(lon[0], lat[0], lon[1], lat[1])
    assert float(d_after) == pytest.approx(0.25 * dist, rel=4e-3)


@pytest.mark.parametrize(("name", "dist"), CASES)
def test_outside_the_zone_moves_rigidly(name: str, dist: float) -> None:
    """Two points beyond B, 10 km apart: their distance survives the move, up to the
    ellipsoid's change of curvature between where they were and where they land (a rotation
    about an axis other than the pole is not rigid on the ellipsoid): e^2 * shift / R."""
    frame = CollapseFrame.from_lonlat(*pair(name, dist), 0.2)
    lon, lat, _ = ORIENTATIONS[name]
    az = ORIENTATIONS[name][2]
    far = frame.d_m / 2 + 5e3
    l1, p1, _ = geodesic_direct(lon, lat, az, far)
    l2, p2, _ = geodesic_direct(l1, p1, az + 60.0, 10e3)
    pts = lonlat_to_ecef(np.array([l1, l2], dtype=float), np.array([p1, p2], dtype=float), 0.0)
    out = frame.forward(pts)
    lo, la, _ = ecef_to_lonlat(out)
    _, _, d0 = geodesic_inverse(float(l1), float(p1), float(l2), float(p2))
    _, _, d1 = geodesic_inverse(lo[0], la[0], lo[1], la[1])
    shift = 0.8 * frame.d_m / 2
    assert abs(float(d1) - float(d0)) <= float(d0) * 0.0067 * shift / frame.r_m + 1e-3
    chord = 2.0 * frame.r_m * math.sin(shift / (2.0 * frame.r_m))
    assert np.linalg.norm(out[0] - pts[0]) == pytest.approx(chord, rel=4e-3)


@pytest.mark.parametrize(("name", "dist"), CASES)
def test_continuous_at_the_zone_edges_and_on_the_far_side(name: str, dist: float) -> None:
    frame = CollapseFrame.from_lonlat(*pair(name, dist), 0.2)
    eps = 1e-9
    knots = [frame.psi0, frame.psi_k, math.pi - 1e-7]
    for k in knots:
        for sgn in (-1.0, 1.0):
            psi = sgn * np.array([k * (1 - eps), k * (1 + eps)])
            if abs(psi[1]) > math.pi:
                psi[1] = -psi[1]  # across the antipodal half-meridian
            dirs = np.cos(psi)[:, None] * frame.m + np.sin(psi)[:, None] * frame.t
            dirs += 0.01 * frame.n
            lon, lat, _ = ecef_to_lonlat(dirs * 6.4e6)
            pts = lonlat_to_ecef(lon, lat, 250.0)
            gap_before = np.linalg.norm(pts[1] - pts[0])
            out = frame.forward(pts)
            # Lipschitz: the far-side taper stretches by less than 2; a tear is metres.
            assert np.linalg.norm(out[1] - out[0]) <= 2.0 * gap_before + 1e-3
    # The mapping of the along-axis angle is strictly increasing (one-to-one).
    psi = np.linspace(-math.pi, math.pi, 20001)
    mapped = psi + frame.rotation_angle(psi)
    assert np.all(np.diff(mapped) > 0)
    assert mapped[0] == pytest.approx(-math.pi) and mapped[-1] == pytest.approx(math.pi)


@pytest.mark.parametrize(("name", "dist"), CASES)
def test_inverse_round_trip_within_a_millimetre(name: str, dist: float) -> None:
    frame = CollapseFrame.from_lonlat(*pair(name, dist), 0.2)
    rng = np.random.default_rng(3)
    pts = cloud(frame, rng)
    # ... and points anywhere on the globe (the far-side taper included).
    lon, lat = rng.uniform(-180, 180, 300), np.degrees(np.arcsin(rng.uniform(-1, 1, 300)))
    pts = np.concatenate([pts, lonlat_to_ecef(lon, lat, rng.uniform(-5e3, 9e3, 300))])
    assert np.max(np.linalg.norm(frame.inverse(frame.forward(pts)) - pts, axis=1)) <= 1e-3
    assert np.max(np.linalg.norm(frame.forward(frame.inverse(pts)) - pts, axis=1)) <= 1e-3


def test_frame_rejects_bad_input_and_degenerates_to_identity() -> None:
    with pytest.raises(ValueError, match="ratio"):
        CollapseFrame.from_lonlat(0, 0, 1, 0, 0.0)
    with pytest.raises(ValueError, match="apart"):
        CollapseFrame.from_lonlat(0, 0, 179.5, 0.1, 0.5)
    same = CollapseFrame.from_lonlat(5.0, 5.0, 5.0, 5.0, 0.2)
    pts = lonlat_to_ecef(np.array([5.0, 6.0]), np.array([5.0, 4.0]), 100.0)
    assert same.psi0 == 0.0 and np.array_equal(same.forward(pts), pts)
