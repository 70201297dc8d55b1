"""distance-regions' per-frame fast paths give exactly the answers of the plain functions:
the separating-axis test with the region's axes computed once (`RegionOverlap`) and the
ellipsoid points without `lonlat_to_ecef`'s broadcasting (`_on_ellipsoid`)."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.app.testing import make_view
from globeview.geodesy import lonlat_to_ecef
from globeview.plugins.builtin.regions.provider import (
    RegionOverlap,
    _on_ellipsoid,
    ground_region,
    polygons_overlap,
)


@pytest.mark.parametrize("seed", range(6))
def test_region_overlap_equals_polygons_overlap(seed: int) -> None:
    rng = np.random.default_rng(seed)
    view = make_view(
        rng.uniform(-180, 180),
        rng.uniform(-80, 80),
        float(10 ** rng.uniform(3, 6)),
        rng.uniform(0, 360),
        rng.uniform(-90, -5),
    )
    region, _ = ground_region(view)
    scale = float(np.abs(region).max())
    # Quads around the region: convex (rotated rectangles), some inside, some across its
    # edges, some far away, and some exactly touching one of its corners.
    n = 2000
    centre = rng.normal(0.0, 1.5 * scale, (n, 2))
    half = rng.uniform(0.001, 0.3, (n, 2)) * scale
    ang = rng.uniform(0, np.pi, n)
    rot = np.stack([np.cos(ang), -np.sin(ang), np.sin(ang), np.cos(ang)], 1).reshape(n, 2, 2)
    box = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    quads = centre[:, None, :] + np.einsum("nij,nkj->nki", rot, box[None] * half[:, None, :])
    quads[:10] += region[0] - quads[:10, 2][:, None, :]  # a corner on the region's corner
    want = polygons_overlap(region, quads)
    assert 0 < want.sum() < n  # both answers occur
    assert np.array_equal(RegionOverlap(region)(quads), want)


def test_points_on_the_ellipsoid_are_lonlat_to_ecef_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    lon = np.concatenate([rng.uniform(-180, 180, 1000), [-180.0, 0.0, 180.0, 90.0]])
    lat = np.concatenate([rng.uniform(-90, 90, 1000), [-90.0, 0.0, 90.0, 45.0]])
    want = np.asarray(lonlat_to_ecef(lon, lat, 0.0)).reshape(-1, 3)
    assert np.array_equal(_on_ellipsoid(lon, lat), want)
