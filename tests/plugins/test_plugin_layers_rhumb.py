"""Rhumb-line densification (`densify_rhumb`): constant bearing, parallels stay parallels,
the antimeridian crossed the short way."""

from __future__ import annotations

import numpy as np
from pyproj import Transformer

from globeview.terrain.vectors import Polylines, densify, densify_rhumb


def _one(lon: list[float], lat: list[float]) -> Polylines:
    return Polylines(np.array(lon, float), np.array(lat, float), np.array([0, len(lon)]))


def test_a_parallel_stays_on_its_latitude() -> None:
    d = densify_rhumb(_one([-60.0, 60.0], [45.0, 45.0]), 50_000.0)
    assert len(d.lon) > 100
    assert np.all(d.lat == 45.0)
    # The geodesic between the same points bulges poleward by degrees: the test can fail.
    g = densify(_one([-60.0, 60.0], [45.0, 45.0]), 50_000.0)
    assert g.lat.max() > 55.0


def test_a_slanted_rhumb_is_straight_in_ellipsoidal_mercator() -> None:
    """Constant bearing == a straight line in World Mercator (EPSG:3395, on the ellipsoid)."""
    d = densify_rhumb(_one([0.0, 40.0], [-30.0, 50.0]), 20_000.0)
    x, y = Transformer.from_crs(4326, 3395, always_xy=True).transform(d.lon, d.lat)
    t = (x - x[0]) / (x[-1] - x[0])
    off = y - (y[0] + t * (y[-1] - y[0]))
    assert np.abs(off).max() < 0.01  # metres in Mercator: straight to float precision
    assert len(d.lon) > 300 and d.lon[-1] == 40.0 and abs(d.lat[-1] - 50.0) < 1e-9
    # A geodesic between the same points is far from straight there.
    g = densify(_one([0.0, 40.0], [-30.0, 50.0]), 20_000.0)
    gx, gy = Transformer.from_crs(4326, 3395, always_xy=True).transform(g.lon, g.lat)
    gt = (gx - gx[0]) / (gx[-1] - gx[0])
    assert np.abs(gy - (gy[0] + gt * (gy[-1] - gy[0]))).max() > 100_000.0


def test_antimeridian_short_way_and_continuous() -> None:
    d = densify_rhumb(_one([170.0, -170.0, -160.0], [10.0, 10.0, 10.0]), 50_000.0)
    assert np.all(np.diff(d.lon) > 0)  # eastwards through 180, no jump of 360
    assert d.lon[-1] == 200.0 and np.all(d.lat == 10.0)
