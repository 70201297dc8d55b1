"""Geodetic <-> ECEF: round trips, degenerate points and agreement with PROJ."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Transformer

from globeview.geodesy import (
    GRS80,
    SPHERE,
    WGS84,
    Ellipsoid,
    ecef_foot_points,
    ecef_to_geodetic,
    ecef_to_lonlat,
    geodetic_to_ecef,
    lonlat_to_ecef,
)


def _lon_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest absolute difference between longitudes in degrees (wrap-aware)."""
    return np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0)


def _random_geodetic(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniform on the sphere of directions, plus poles, equator, antimeridian, extremes."""
    rng = np.random.default_rng(seed)
    lon = rng.uniform(-180.0, 180.0, n)
    lat = np.degrees(np.arcsin(rng.uniform(-1.0, 1.0, n)))
    h = rng.uniform(-11_000.0, 1_000_000.0, n)
    k = n // 20
    lat[:k] = 90.0
    lat[k : 2 * k] = -90.0
    lat[2 * k : 3 * k] = 0.0
    lat[3 * k : 4 * k] = rng.choice([89.9999999, -89.9999999, 1e-12, -1e-12], k)
    lon[4 * k : 5 * k] = rng.choice([180.0, -180.0, 179.9999999, -179.9999999], k)
    h[5 * k : 6 * k] = rng.choice([-11_000.0, 0.0, 1_000_000.0], k)
    return lon, lat, h


@pytest.mark.parametrize("ellipsoid", [WGS84, GRS80, SPHERE])
def test_round_trip_100k_points(ellipsoid: Ellipsoid) -> None:
    lon, lat, h = _random_geodetic(100_000, seed=1)
    xyz = lonlat_to_ecef(lon, lat, h, ellipsoid)
    lon2, lat2, h2 = ecef_to_lonlat(xyz, ellipsoid)
    # Angles and heights come back exactly (longitude is arbitrary on the polar axis).
    off_axis = np.abs(lat) < 90.0
    assert np.max(_lon_diff(lon2, lon)[off_axis]) <= 1e-9
    assert np.max(np.abs(lat2 - lat)) <= 1e-9
    assert np.max(np.abs(h2 - h)) <= 1e-6
    # And so does the position.
    back = lonlat_to_ecef(lon2, lat2, h2, ellipsoid)
    assert np.max(np.linalg.norm(back - xyz, axis=-1)) <= 1e-6
    # Longitudes land in (-180, 180].
    assert np.all((lon2 > -180.0) & (lon2 <= 180.0))


def test_ecef_round_trip_in_space_and_inside_the_earth() -> None:
    # Start from ECEF: points from the centre of the Earth out to geostationary distance.
    rng = np.random.default_rng(2)
    n = 50_000
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    radii = np.concatenate([rng.uniform(0.0, 50_000.0, n // 2), rng.uniform(0, 4.3e7, n // 2)])
    xyz = directions * radii[:, np.newaxis]
    xyz[:100, 2] = 0.0  # equatorial plane, partly inside the evolute
    xyz[100:200, :2] = 0.0  # polar axis
    lon, lat, h = ecef_to_lonlat(xyz)
    assert np.all(np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h))
    back = lonlat_to_ecef(lon, lat, h)
    # Near the centre h is close to -N, so N + h cancels: allow 10 µm there.
    assert np.max(np.linalg.norm(back - xyz, axis=-1)) <= 1e-5


def test_known_points() -> None:
    a, b = WGS84.a, WGS84.b
    x, y, z = geodetic_to_ecef([0.0, 90.0, 0.0, 180.0], [0.0, 0.0, 90.0, 0.0], 0.0)
    np.testing.assert_allclose(x, [a, 0.0, 0.0, -a], atol=1e-9)
    np.testing.assert_allclose(y, [0.0, a, 0.0, 0.0], atol=1e-8)
    np.testing.assert_allclose(z, [0.0, 0.0, b, 0.0], atol=1e-9)
    lon, lat, h = ecef_to_geodetic(-a - 5.0, 0.0, 0.0)
    assert lon == 180.0  # atan2 gives ±180; the convention is +180
    assert lat == pytest.approx(0.0, abs=1e-12)
    assert h == pytest.approx(5.0, abs=1e-8)  # a few ulps of 6.4e6 m


@pytest.mark.parametrize("ellipsoid", [WGS84, SPHERE])
def test_centre_of_the_earth(ellipsoid: Ellipsoid) -> None:
    lon, lat, h = ecef_to_geodetic(0.0, 0.0, 0.0, ellipsoid)
    # Nearest surface points are the poles, at distance b.
    assert abs(lat) == pytest.approx(90.0, abs=1e-12)
    assert h == pytest.approx(-ellipsoid.b, abs=1e-6)
    np.testing.assert_allclose(lonlat_to_ecef(lon, lat, h, ellipsoid), 0.0, atol=1e-6)


def test_equatorial_plane_inside_the_evolute() -> None:
    # A point 1 km from the centre on the equatorial plane: its nearest surface point is
    # near a pole; the geodetic height must equal minus the distance to that point.
    lon, lat, h = ecef_to_geodetic(1000.0, 0.0, 0.0)
    foot = lonlat_to_ecef(lon, lat, 0.0)
    assert -h == pytest.approx(np.linalg.norm(foot - [1000.0, 0.0, 0.0]), abs=1e-6)
    np.testing.assert_allclose(lonlat_to_ecef(lon, lat, h), [1000.0, 0.0, 0.0], atol=1e-6)


@pytest.mark.parametrize("z", [-1e8, -7e6, -WGS84.b, -1e4, 1.0, 1e4, WGS84.b, 7e6, 1e8])
def test_polar_axis(z: float) -> None:
    lon, lat, h = ecef_to_geodetic(0.0, 0.0, z)
    assert lat == pytest.approx(np.sign(z) * 90.0, abs=1e-12)
    assert h == pytest.approx(abs(z) - WGS84.b, abs=1e-6)
    assert lon == 0.0


def test_agrees_with_proj_epsg4979_to_4978() -> None:
    lon, lat, h = _random_geodetic(20_000, seed=3)
    fwd = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    ref = np.stack(fwd.transform(lon, lat, h), axis=-1)
    ours = lonlat_to_ecef(lon, lat, h)
    assert np.max(np.linalg.norm(ours - ref, axis=-1)) <= 1e-3
    # PROJ's inverse is iterative and loses accuracy with height (~8 mm at 1000 km, where
    # ours round-trips to nm), so compare the inverse only near the surface.
    near = np.abs(h) <= 12_000.0
    lon, lat, ref = lon[near], lat[near], ref[near]
    inv = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    rlon, rlat, rh = inv.transform(ref[:, 0], ref[:, 1], ref[:, 2])
    olon, olat, oh = ecef_to_lonlat(ref)
    assert np.max(np.abs(oh - rh)) <= 1e-3
    assert np.max(np.abs(olat - rlat)) <= 1e-8  # ~1 mm of arc
    assert np.max(_lon_diff(olon, rlon)[np.abs(lat) < 90.0]) <= 1e-8


def test_broadcasting_and_scalars() -> None:
    xyz = lonlat_to_ecef(np.zeros((4, 1)), np.linspace(-60, 60, 5), 0.0)
    assert xyz.shape == (4, 5, 3)
    assert xyz.dtype == np.float64
    lon, lat, h = ecef_to_lonlat(xyz)
    assert lon.shape == lat.shape == h.shape == (4, 5)
    assert np.ndim(ecef_to_geodetic(1e7, 0.0, 0.0)[0]) == 0
    with pytest.raises(ValueError, match="shape"):
        ecef_to_lonlat(np.zeros((3, 2)))


_lons = st.floats(-180.0, 180.0)
_lats = st.floats(-90.0, 90.0)
_heights = st.floats(-11_000.0, 2_000_000.0)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(lon=_lons, lat=_lats, h=_heights)
def test_property_round_trip(lon: float, lat: float, h: float) -> None:
    x, y, z = geodetic_to_ecef(lon, lat, h)
    lon2, lat2, h2 = ecef_to_geodetic(x, y, z)
    assert abs(lat2 - lat) <= 1e-9
    assert abs(h2 - h) <= 1e-6
    if abs(lat) < 90.0 - 1e-9:
        # On or near the axis longitude is ill-conditioned; compare positions instead.
        assert np.hypot(x, y) < 1e-3 or _lon_diff(lon2, lon) <= 1e-9
    back = np.array(geodetic_to_ecef(lon2, lat2, h2))
    assert np.linalg.norm(back - np.array([x, y, z])) <= 1e-6


#: ECEF points (metres) no position on Earth has: infinite, NaN.
NON_FINITE_ECEF = [
    (np.inf, 0.0, 0.0),
    (-np.inf, 0.0, 0.0),
    (0.0, 0.0, np.inf),
    (0.0, 0.0, -np.inf),
    (np.inf, np.inf, np.inf),
    (np.inf, -np.inf, 1.0),
    (np.nan, 0.0, 0.0),
    (1e7, np.nan, 0.0),
    (0.0, 0.0, np.nan),
]


def test_non_finite_ecef_gives_nan_where_proj_gives_no_point() -> None:
    pts = np.array(NON_FINITE_ECEF)
    inv = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    _, _, rh = inv.transform(pts[:, 0], pts[:, 1], pts[:, 2])
    assert not np.isfinite(rh).any()  # PROJ: no height (inf or NaN)
    lon, lat, h = ecef_to_lonlat(pts)
    # Not a point 6 335 km below the equator (what the closed form made of x = inf).
    assert np.isnan(lon).all() and np.isnan(lat).all() and np.isnan(h).all()
    assert np.isnan(ecef_to_geodetic(np.inf, 0.0, 0.0)[2])


def test_foot_points_of_non_finite_ecef_are_nan() -> None:
    foot, h = ecef_foot_points(np.array(NON_FINITE_ECEF))
    assert np.isnan(foot).all() and np.isnan(h).all()
    # Mixed with good points, the good ones keep their feet.
    good = lonlat_to_ecef(10.0, 45.0, 1000.0)
    foot, h = ecef_foot_points(np.stack([good, [np.inf, 0.0, 0.0]]))
    np.testing.assert_allclose(foot[0], lonlat_to_ecef(10.0, 45.0, 0.0), atol=1e-6)
    assert h[0] == pytest.approx(1000.0, abs=1e-6) and np.isnan(h[1]) and np.isnan(foot[1]).all()


@pytest.mark.parametrize("r", [1e20, 1e30, 1e59, 1e100, 1e154, 1e200, 1e300])
def test_huge_ecef_is_the_far_field_point_not_an_overflow(r: float) -> None:
    # Far out the normal through the point passes (to double precision) through the centre:
    # the geodetic latitude is the geocentric one and h is the distance less the foot's
    # radius. The closed form's powers overflowed from ~1e58 m on (NaN, or inf - inf).
    d = np.array([[1.0, 0.0, 1.0], [-3.0, 4.0, -12.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = d * r
    lon, lat, h = ecef_to_lonlat(pts)
    want_lat = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])))
    np.testing.assert_allclose(lat, want_lat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(lon, np.degrees(np.arctan2(d[:, 1], d[:, 0])), atol=1e-12)
    np.testing.assert_allclose(h, r, rtol=1e-12)
    # Where PROJ answers, ours agrees with it.
    inv = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    _, rlat, rh = inv.transform(pts[:, 0], pts[:, 1], pts[:, 2])
    ok = np.isfinite(rh)
    np.testing.assert_allclose(lat[ok], rlat[ok], atol=1e-12)
    np.testing.assert_allclose(h[ok], rh[ok], rtol=1e-12)
    # The feet are on the ellipsoid, under the point (not the point less h times a normal,
    # which loses everything below the point's own rounding: 16 km at 1e20 m).
    foot, hf = ecef_foot_points(pts)
    np.testing.assert_allclose(foot, lonlat_to_ecef(lon, lat, 0.0), rtol=0, atol=1e-6)
    np.testing.assert_allclose(hf, h, rtol=1e-12)


def test_ecef_beyond_the_float_range_of_h_gives_inf_height() -> None:
    # |P| overflows float64 although each coordinate is finite: h is inf, the angles exact.
    lon, lat, h = ecef_to_geodetic(1.5e308, 1.5e308, 1.5e308)
    assert lon == pytest.approx(45.0) and lat == pytest.approx(np.degrees(np.arctan(0.5**0.5)))
    assert h == np.inf


@pytest.mark.parametrize("lat", [90.0000001, 91.0, 180.0, -90.5, -270.0, np.inf, -np.inf, np.nan])
def test_latitudes_beyond_the_poles_give_nan(lat: float) -> None:
    # 91 degrees is no latitude: not the point at 89 degrees on the far meridian.
    xyz = lonlat_to_ecef(np.array([0.0, 10.0]), np.array([lat, 45.0]), 100.0)
    assert np.isnan(xyz[0]).all()
    np.testing.assert_allclose(xyz[1], lonlat_to_ecef(10.0, 45.0, 100.0), atol=0)
    assert np.isnan(geodetic_to_ecef(0.0, lat, 0.0)).all()
    # The poles themselves are latitudes.
    assert np.isfinite(lonlat_to_ecef(0.0, [90.0, -90.0])).all()
