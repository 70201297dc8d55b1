"""Ellipsoid constants against pyproj's own ellipsoid definitions."""

import dataclasses

import pytest
from pyproj import Geod

from globeview.geodesy import GRS80, SPHERE, WGS84, Ellipsoid


@pytest.mark.parametrize(("ours", "ellps"), [(WGS84, "WGS84"), (GRS80, "GRS80")])
def test_derived_constants_match_pyproj(ours: Ellipsoid, ellps: str) -> None:
    ref = Geod(ellps=ellps)
    assert ours.a == ref.a
    assert ours.b == pytest.approx(ref.b, rel=0, abs=1e-6)
    assert ours.f == pytest.approx(ref.f, rel=1e-12)
    assert ours.e2 == pytest.approx(ref.es, rel=1e-12)
    # Second eccentricity from its definition (a² - b²) / b².
    assert ours.ep2 == pytest.approx((ref.a**2 - ref.b**2) / ref.b**2, rel=1e-10)


def test_wgs84_polar_radius_published_value() -> None:
    # NIMA TR8350.2: b = 6356752.3142 m.
    assert WGS84.b == pytest.approx(6356752.3142, abs=1e-4)


def test_sphere_is_degenerate() -> None:
    assert SPHERE.b == SPHERE.a == 6371008.8
    assert SPHERE.e2 == 0.0
    assert SPHERE.ep2 == 0.0


def test_frozen_and_validated() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        WGS84.a = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError, match="semi-major axis"):
        Ellipsoid("bad", -1.0, 0.0)
    with pytest.raises(ValueError, match="flattening"):
        Ellipsoid("bad", 1.0, 1.0)
