"""Geodesics: direct/inverse consistency, symmetry, densification."""

import numpy as np
import pytest

from globeview.geodesy import (
    SPHERE,
    geodesic_direct,
    geodesic_inverse,
    geodesic_points,
)


def _random_pairs(n: int, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    lon1, lon2 = rng.uniform(-180, 180, (2, n))
    lat1, lat2 = np.degrees(np.arcsin(rng.uniform(-1, 1, (2, n))))
    return lon1, lat1, lon2, lat2


def _ang_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0)


def test_inverse_then_direct_returns_to_point_2() -> None:
    lon1, lat1, lon2, lat2 = _random_pairs(5000, seed=7)
    az12, az21, dist = geodesic_inverse(lon1, lat1, lon2, lat2)
    lon_b, lat_b, back = geodesic_direct(lon1, lat1, az12, dist)
    assert np.max(np.abs(lat_b - lat2)) <= 1e-9
    assert np.max(_ang_diff(lon_b, lon2)) <= 1e-9
    assert np.max(_ang_diff(back, az21)) <= 1e-7


def test_symmetry() -> None:
    lon1, lat1, lon2, lat2 = _random_pairs(5000, seed=8)
    az12, az21, d12 = geodesic_inverse(lon1, lat1, lon2, lat2)
    ba12, ba21, d21 = geodesic_inverse(lon2, lat2, lon1, lat1)
    np.testing.assert_allclose(d12, d21, rtol=1e-12, atol=1e-6)
    # Azimuths swap roles; compare away from (near-)antipodal pairs where they are unstable.
    regular = d12 < 1.9e7
    assert np.max(_ang_diff(az12, ba21)[regular]) <= 1e-7
    assert np.max(_ang_diff(az21, ba12)[regular]) <= 1e-7


def test_known_distances() -> None:
    # WGS84 quarter meridian (equator to pole), a published constant: 10 001 965.729 m.
    _, _, d = geodesic_inverse(0.0, 0.0, 0.0, 90.0)
    assert d == pytest.approx(10_001_965.729, abs=1e-3)
    # On the sphere one degree of the equator is R * pi / 180, heading due east.
    az12, az21, d = geodesic_inverse(0.0, 0.0, 1.0, 0.0, SPHERE)
    assert d == pytest.approx(SPHERE.a * np.pi / 180.0, rel=1e-12)
    assert az12 == pytest.approx(90.0)
    assert az21 == pytest.approx(-90.0)


def test_broadcasting() -> None:
    lon2 = np.linspace(-10, 10, 6).reshape(2, 3)
    az12, az21, d = geodesic_inverse(0.0, 0.0, lon2, 5.0)
    assert az12.shape == az21.shape == d.shape == (2, 3)
    lon, lat, back = geodesic_direct(0.0, 0.0, np.array([0.0, 90.0]), 1000.0)
    assert lon.shape == (2,)
    assert lat[0] > 0 and lon[1] > 0
    # Heading north the way back points south; heading east it points (roughly) west.
    assert abs(abs(back[0]) - 180.0) < 1e-9 and back[1] == pytest.approx(-90.0, abs=1e-3)


@pytest.mark.parametrize(
    ("p1", "p2", "spacing"),
    [
        ((0.0, 0.0), (1.0, 0.0), 50_000.0),
        ((-170.0, 60.0), (170.0, 65.0), 1_000.0),
        ((10.0, -89.0), (-170.0, 89.0), 100_000.0),
    ],
)
def test_points_densify_one_geodesic(p1: tuple, p2: tuple, spacing: float) -> None:
    lons, lats = geodesic_points(*p1, *p2, spacing)
    assert lons.ndim == 1 and lons.shape == lats.shape and lons.size >= 2
    assert (lons[0], lats[0]) == pytest.approx(p1)
    assert lats[-1] == pytest.approx(p2[1], abs=1e-9)
    assert _ang_diff(lons[-1], p2[0]) <= 1e-9
    _, _, seg = geodesic_inverse(lons[:-1], lats[:-1], lons[1:], lats[1:])
    assert np.max(seg) <= spacing * (1 + 1e-9)
    np.testing.assert_allclose(seg, seg[0], rtol=1e-6)  # equally spaced
    # The pieces add up to the whole: the points lie on the one geodesic.
    _, _, total = geodesic_inverse(*p1, *p2)
    assert np.sum(seg) == pytest.approx(total, rel=1e-9)
    # and the point count is minimal for the spacing.
    assert lons.size == max(int(np.ceil(total / spacing)) + 1, 2)


def test_points_degenerate_and_invalid() -> None:
    lons, lats = geodesic_points(5.0, 5.0, 5.0, 5.0, 10.0)
    np.testing.assert_allclose(lons, [5.0, 5.0])
    np.testing.assert_allclose(lats, [5.0, 5.0])
    with pytest.raises(ValueError, match="spacing"):
        geodesic_points(0.0, 0.0, 1.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="spacing"):
        geodesic_points(0.0, 0.0, 1.0, 1.0, float("nan"))


@pytest.mark.parametrize(
    "pair",
    [(0.0, -45.0, -180.0, -45.0), (10.0, -45.0, -170.0, -45.0), (0.0, -90.0, -180.0, 0.0)],
)
def test_azimuths_are_in_the_documented_range(pair: tuple) -> None:
    # Due south is 180, not -180: the docstring's range is (-180, 180].
    az12, az21, _ = geodesic_inverse(*pair)
    assert az12 == 180.0 and az21 == 180.0
    lon1, lat1, lon2, lat2 = _random_pairs(2000, seed=9)
    lon2[:500] = lon1[:500] + 180.0  # meridional pairs: azimuths of exactly +-180
    lat1[:250], lat2[250:500] = -45.0, -45.0
    for az in geodesic_inverse(lon1, lat1, lon2, lat2)[:2]:
        assert np.all((az > -180.0) & (az <= 180.0))
    _, _, back = geodesic_direct(lon1, lat1, 0.0, 1000.0)
    assert np.all((back > -180.0) & (back <= 180.0))


@pytest.mark.parametrize(
    ("call", "words"),
    [
        (lambda: geodesic_inverse(0.0, 91.0, 0.0, 0.0), "latitude of point 1 .* -90..90"),
        (lambda: geodesic_inverse(0.0, 0.0, 0.0, -90.0000001), "latitude of point 2"),
        (lambda: geodesic_inverse([0.0, 1.0], [0.0, np.nan], 0.0, 0.0), "not nan"),
        (lambda: geodesic_inverse(np.inf, 0.0, 0.0, 0.0), "longitude of point 1 .* not inf"),
        (lambda: geodesic_direct(0.0, 95.0, 0.0, 1.0), "latitude .* not 95"),
        (lambda: geodesic_direct(0.0, 0.0, np.nan, 1.0), "azimuth"),
        (lambda: geodesic_direct(0.0, 0.0, 0.0, np.inf), "distance"),
        (lambda: geodesic_points(0.0, 0.0, 0.0, 100.0, 1e3), "latitude of point 2"),
        (lambda: geodesic_points(np.nan, 0.0, 0.0, 1.0, 1e3), "longitude of point 1"),
    ],
)
def test_bad_latitudes_and_non_finite_inputs_raise(call, words: str) -> None:
    # PROJ's answer to these is NaN without a word; the caller learns which value was bad.
    with pytest.raises(ValueError, match=words):
        call()
