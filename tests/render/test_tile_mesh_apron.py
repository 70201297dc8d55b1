"""Edge normals from the neighbours' data (issue #16, item 5): with the stack's apron, two
adjacent tiles compute the same normal at every node of their shared edge."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.render.renderer import tile_bounds_tuple
from globeview.render.tile_mesh import build_tile_mesh
from globeview.terrain.quadtree import key_for_lonlat


@pytest.fixture(scope="module")
def stack(globeview_terrain):
    """The embedded terrain: the run's one stack (`globeview_terrain`, tests/conftest.py), not
    one of the module's own (each stack measures its layers' blend masks again: up to ~7 CPU-s)."""
    return globeview_terrain


def _pair(level: int, lon: float, lat: float):
    kx, ky = key_for_lonlat(level, np.array([lon]), np.array([lat]))
    x, y = int(np.ravel(kx)[0]), int(np.ravel(ky)[0])
    return (level, x, y), (level, x + 1, y)


def _normals(stack, key, apron: bool) -> np.ndarray:
    a = stack.heights_apron(key) if apron else None
    return build_tile_mesh(tile_bounds_tuple(key), stack.heights(key), 10.0, apron=a).normals


# White Mountains (SRTM N44W072): rough terrain at a level finer than the base.
@pytest.mark.slow
@pytest.mark.parametrize("level", [9, 11])
def test_shared_edge_normals_agree_with_apron(stack, level):
    west, east = _pair(level, -71.3, 44.25)
    assert np.ptp(stack.heights(west)) > 50.0  # rough: the test means something here
    nw, ne = _normals(stack, west, True), _normals(stack, east, True)
    np.testing.assert_allclose(nw[:, -1], ne[:, 0], atol=2e-6)
    # Without the apron each side averages only its own triangles: visibly different.
    bw, be = _normals(stack, west, False), _normals(stack, east, False)
    assert np.max(np.abs(bw[:, -1] - be[:, 0])) > 1e-2


def test_apron_interior_is_the_tile_and_ring_is_the_neighbours(stack):
    west, east = _pair(10, -71.3, 44.25)
    a = stack.heights_apron(west)
    h, he = stack.heights(west), stack.heights(east)
    size = h.shape[0]
    assert a.shape == (size + 2, size + 2)
    np.testing.assert_array_equal(a[1:-1, 1:-1], h)
    np.testing.assert_array_equal(a[1:-1, -1], he[:, 1])


def test_apron_wraps_the_antimeridian_and_extrapolates_at_the_poles(stack):
    level = 3
    ncols, nrows = 2 << level, 1 << level
    size = stack.tile_size
    east_end = (level, ncols - 1, 0)  # touches lon +180 and the north pole
    a = stack.heights_apron(east_end)
    first = stack.heights((level, 0, 0))
    np.testing.assert_array_equal(a[1:-1, -1], first[:, 1])
    np.testing.assert_allclose(a[0], 2.0 * a[1] - a[2], atol=1e-3)
    south = stack.heights_apron((level, 0, nrows - 1))
    np.testing.assert_allclose(south[-1], 2.0 * south[-2] - south[-3], atol=1e-3)
    assert np.isfinite(a).all() and a.shape == (size + 2, size + 2)
