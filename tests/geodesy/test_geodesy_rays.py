"""Ray / ellipsoid intersection."""

import numpy as np
import pytest

from globeview.geodesy import (
    SPHERE,
    WGS84,
    ecef_to_lonlat,
    lonlat_to_ecef,
    ray_ellipsoid_intersection,
    ray_ellipsoid_t,
)


def _ellipsoid_residual(p: np.ndarray, a: float, b: float) -> np.ndarray:
    return (p[..., 0] ** 2 + p[..., 1] ** 2) / a**2 + p[..., 2] ** 2 / b**2 - 1.0


def test_ray_toward_centre_hits_at_surface_radius() -> None:
    rng = np.random.default_rng(5)
    n = 10_000
    lon = rng.uniform(-180, 180, n)
    lat = np.degrees(np.arcsin(rng.uniform(-1, 1, n)))
    target = lonlat_to_ecef(lon, lat, 0.0)
    # Origins far out along the geocentric direction of each surface point.
    dist = rng.uniform(1e3, 1e8, n)[:, np.newaxis]
    unit = target / np.linalg.norm(target, axis=-1, keepdims=True)
    origin = target + unit * dist
    direction = -unit * rng.uniform(0.1, 10.0, (n, 1))  # any length
    hit = ray_ellipsoid_intersection(origin, direction)
    np.testing.assert_allclose(
        np.linalg.norm(hit, axis=-1), np.linalg.norm(target, axis=-1), rtol=1e-12
    )
    assert np.max(np.abs(_ellipsoid_residual(hit, WGS84.a, WGS84.b))) <= 1e-9
    # t is in units of the direction vector: |t d| is the distance to the hit.
    t = ray_ellipsoid_t(origin, direction)
    np.testing.assert_allclose(t * np.linalg.norm(direction, axis=-1), dist[:, 0], rtol=1e-9)


def test_random_rays_hit_on_the_inflated_surface() -> None:
    rng = np.random.default_rng(6)
    n = 10_000
    origin = rng.normal(size=(n, 3)) * 2e7
    direction = rng.normal(size=(n, 3))
    h = rng.uniform(-10_000.0, 500_000.0, n)
    hit = ray_ellipsoid_intersection(origin, direction, WGS84, h)
    ok = np.all(np.isfinite(hit), axis=-1)
    assert 0 < ok.sum() < n  # some hit, some miss
    res = _ellipsoid_residual(hit[ok], WGS84.a + h[ok], WGS84.b + h[ok])
    assert np.max(np.abs(res)) <= 1e-9
    t = ray_ellipsoid_t(origin, direction, WGS84, h)
    assert np.all(t[ok] >= 0.0)
    assert np.all(np.isnan(t[~ok]))
    # Nearest hit: nothing on the segment from the origin to the hit is inside the surface
    # (checked at a few sample fractions for origins outside).
    outside = _ellipsoid_residual(origin, WGS84.a + h, WGS84.b + h) > 0
    for frac in (0.25, 0.5, 0.9, 0.999):
        mid = origin + (frac * t)[:, np.newaxis] * direction
        sel = ok & outside
        assert np.all(_ellipsoid_residual(mid[sel], WGS84.a + h[sel], WGS84.b + h[sel]) > 0)


def test_miss_and_tangent_give_nan() -> None:
    a, b = WGS84.a, WGS84.b
    # Pointing away from the Earth.
    assert np.isnan(ray_ellipsoid_t([2e7, 0.0, 0.0], [1.0, 0.0, 0.0]))
    # Passing 1 m above the north pole, and exactly grazing it.
    assert np.isnan(ray_ellipsoid_t([-1e7, 0.0, b + 1.0], [1.0, 0.0, 0.0]))
    assert np.isnan(ray_ellipsoid_t([-1e7, 0.0, b], [1.0, 0.0, 0.0]))
    # Just below the pole it does hit, near the pole.
    hit = ray_ellipsoid_intersection([-1e7, 0.0, b - 1.0], [1.0, 0.0, 0.0])
    assert ecef_to_lonlat(hit)[1] > 89.0
    # Grazing the equator on a sphere.
    assert np.isnan(ray_ellipsoid_t([SPHERE.a, -1e7, 0.0], [0.0, 1.0, 0.0], SPHERE))
    # Everything behind the origin: a ray starting beyond the Earth, pointing away from it.
    assert np.isnan(ray_ellipsoid_t([0.0, -2 * a, 0.0], [0.0, -1.0, 0.0]))
    # A ray on the far side of the inflated surface misses it.
    assert np.isnan(ray_ellipsoid_t([-1e7, 0.0, b + 50.0], [1.0, 0.0, 0.0], h=10.0))
    assert np.isfinite(ray_ellipsoid_t([-1e7, 0.0, b + 50.0], [1.0, 0.0, 0.0], h=100.0))


def test_origin_inside_returns_exit_point() -> None:
    # From the centre, along +x: the exit is at the equator, distance a.
    assert ray_ellipsoid_t([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]) == pytest.approx(WGS84.a)
    assert ray_ellipsoid_t([0.0, 0.0, 0.0], [0.0, 0.0, -2.0]) == pytest.approx(WGS84.b / 2)
    # From 1000 m below the surface, straight up: exit 1000 m later.
    below = lonlat_to_ecef(10.0, 0.0, -1000.0)
    t = ray_ellipsoid_t(below, below / np.linalg.norm(below))
    assert t == pytest.approx(1000.0, abs=1e-6)


def test_inflation_height_on_axes() -> None:
    # At the equator and the poles the inflated ellipsoid is exactly at height h.
    origin = np.array([[3e7, 0.0, 0.0], [0.0, 0.0, 3e7]])
    direction = -origin
    hit = ray_ellipsoid_intersection(origin, direction, WGS84, 2500.0)
    _, _, h = ecef_to_lonlat(hit)
    np.testing.assert_allclose(h, 2500.0, atol=1e-6)
