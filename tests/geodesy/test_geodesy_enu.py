"""Local ENU frames and the surface normal."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from globeview.geodesy import (
    WGS84,
    ecef_to_enu,
    enu_basis,
    enu_to_ecef,
    geodetic_to_ecef,
    lonlat_to_ecef,
    surface_normal,
)

_lons = st.floats(-180.0, 180.0)
_lats = st.floats(-90.0, 90.0)
_heights = st.floats(-11_000.0, 1_000_000.0)
_offsets = st.floats(-1e6, 1e6)


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(lon=_lons, lat=_lats)
def test_basis_is_orthonormal_and_right_handed(lon: float, lat: float) -> None:
    r = enu_basis(lon, lat)
    assert r.shape == (3, 3)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)
    east, north, up = r
    np.testing.assert_allclose(np.cross(east, north), up, atol=1e-14)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-14)


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(lon=_lons, lat=_lats)
def test_up_equals_surface_normal(lon: float, lat: float) -> None:
    up = enu_basis(lon, lat)[2]
    np.testing.assert_allclose(surface_normal(lonlat_to_ecef(lon, lat)), up, atol=1e-12)


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(lon=_lons, lat=_lats, h=_heights, e=_offsets, n=_offsets, u=_offsets)
def test_enu_round_trip(lon: float, lat: float, h: float, e: float, n: float, u: float) -> None:
    enu = np.array([e, n, u])
    xyz = enu_to_ecef(enu, lon, lat, h)
    np.testing.assert_allclose(ecef_to_enu(xyz, lon, lat, h), enu, atol=1e-6)


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(lon=st.floats(-179.0, 179.0), lat=st.floats(-89.0, 89.0), h=_heights)
def test_directions_mean_east_north_up(lon: float, lat: float, h: float) -> None:
    # Straight up: the point h + 100 m above the origin is 100 m up, nothing else.
    above = lonlat_to_ecef(lon, lat, h + 100.0)
    np.testing.assert_allclose(ecef_to_enu(above, lon, lat, h), [0.0, 0.0, 100.0], atol=1e-6)
    # A small step east or north at the same height shows up on that axis, with the
    # ellipsoid's curvature dropping it slightly below the tangent plane.
    step = 1e-4  # degrees
    east = ecef_to_enu(lonlat_to_ecef(lon + step, lat, h), lon, lat, h)
    north = ecef_to_enu(lonlat_to_ecef(lon, lat + step, h), lon, lat, h)
    # Round-off: one float64 ulp of an ECEF coordinate (~6.4e6 m) is ~9e-10 m, and the
    # ENU rotation of a difference carries a few of them (1.13e-9 m was seen), so "zero"
    # means within 1e-8 m (about ten ulps).
    ulps = 1e-8
    assert east[0] > 0 and abs(east[1]) < 1e-2 * east[0] and east[2] <= ulps
    assert north[1] > 0 and abs(north[0]) < ulps and north[2] <= ulps


def test_origin_maps_to_zero_and_arrays_broadcast() -> None:
    lon = np.array([0.0, 45.0, -120.0, 180.0])
    lat = np.array([0.0, 30.0, -60.0, 89.0])
    h = np.array([0.0, 100.0, -50.0, 1e5])
    origins = lonlat_to_ecef(lon, lat, h)
    np.testing.assert_allclose(ecef_to_enu(origins, lon, lat, h), 0.0, atol=1e-8)
    # One origin, many points: (5, 7, 3) in, (5, 7, 3) out.
    pts = np.random.default_rng(0).normal(size=(5, 7, 3)) * 1e3 + origins[1]
    assert ecef_to_enu(pts, 45.0, 30.0, 100.0).shape == (5, 7, 3)
    assert enu_basis(lon, lat).shape == (4, 3, 3)


def test_surface_normal_at_axes() -> None:
    pts = np.array([[WGS84.a, 0.0, 0.0], [0.0, 0.0, WGS84.b], [0.0, 0.0, -WGS84.b]])
    np.testing.assert_allclose(surface_normal(pts), [[1, 0, 0], [0, 0, 1], [0, 0, -1]])
    # Off the equator and poles the geodetic normal is not radial (points away from the axis
    # less than the radius vector does, i.e. steeper latitude).
    p = np.array(geodetic_to_ecef(0.0, 45.0, 0.0))
    n = surface_normal(p)
    assert np.degrees(np.arcsin(n[2])) == pytest.approx(45.0, abs=1e-12)
    assert np.degrees(np.arcsin(p[2] / np.linalg.norm(p))) < 45.0 - 0.1
