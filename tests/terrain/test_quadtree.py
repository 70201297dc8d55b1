"""Ellipsoidal quadtree keys: bounds <-> key round trips, hierarchy, neighbours, coverage."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from globeview.terrain.quadtree import (
    TileKey,
    ancestor_at,
    children,
    key_for_lonlat,
    linear_key,
    neighbours,
    parent,
    tile_bounds,
    tile_bounds_arrays,
    tile_center_lonlat,
    tiles_covering,
)


@pytest.mark.parametrize("level", [0, 1, 3, 7, 12, 20])
def test_centre_and_corners_round_trip(level: int) -> None:
    ncols, nrows = 2 ** (level + 1), 2**level
    rng = np.random.default_rng(level)
    x = np.r_[0, ncols - 1, rng.integers(0, ncols, 50)]
    y = np.r_[0, nrows - 1, rng.integers(0, nrows, 50)]
    lon, lat = tile_center_lonlat(level, x, y)
    kx, ky = key_for_lonlat(level, lon, lat)
    assert np.array_equal(kx, x) and np.array_equal(ky, y)
    w, s, e, n = tile_bounds_arrays(level, x, y)
    assert np.allclose(e - w, 180.0 / 2**level) and np.allclose(n - s, 180.0 / 2**level)
    # The north-west corner belongs to the tile itself (half-open towards east/south).
    kx, ky = key_for_lonlat(level, w, n)
    assert np.array_equal(kx, x) and np.array_equal(ky, y)


def test_grid_edges() -> None:
    assert tile_bounds(TileKey(0, 0, 0)) == (-180.0, -90.0, 0.0, 90.0)
    assert tile_bounds(TileKey(0, 1, 0)) == (0.0, -90.0, 180.0, 90.0)
    x, y = key_for_lonlat(3, [180.0, -180.0, 540.0 - 1e-9, 0.0], [-90.0, 90.0, 0.0, -90.0])
    assert x.tolist() == [15, 0, 15, 8]
    assert y.tolist() == [7, 0, 4, 7]


@pytest.mark.slow
@given(
    st.integers(0, 18),
    st.floats(-180, 180, allow_nan=False),
    st.floats(-90, 90, allow_nan=False),
)
def test_point_inside_its_tile(level: int, lon: float, lat: float) -> None:
    x, y = key_for_lonlat(level, lon, lat)
    w, s, e, n = tile_bounds(TileKey(level, int(x), int(y)))
    assert w <= lon <= e and s <= lat <= n


def test_parent_children_ancestor() -> None:
    key = TileKey(5, 37, 11)
    kids = children(key)
    assert [parent(k) for k in kids] == [key] * 4
    w, s, e, n = tile_bounds(key)
    nw, ne, sw, se = (tile_bounds(k) for k in kids)
    assert nw[0] == w and nw[3] == n and ne[2] == e and se[1] == s and sw[0] == w
    assert ancestor_at(TileKey(9, 37 * 16 + 5, 11 * 16 + 15), 5) == key
    with pytest.raises(ValueError, match="no parent"):
        parent(TileKey(0, 1, 0))


def test_neighbours_wrap_and_poles() -> None:
    nb = neighbours(TileKey(2, 0, 0))
    assert nb["W"] == TileKey(2, 7, 0) and nb["E"] == TileKey(2, 1, 0)
    assert nb["N"] is None and nb["S"] == TileKey(2, 0, 1)
    nb = neighbours(TileKey(2, 7, 3))
    assert nb["E"] == TileKey(2, 0, 3) and nb["S"] is None
    # Neighbours really share an edge.
    for k in (TileKey(4, 5, 6), TileKey(4, 31, 2)):
        _, _, e, n = tile_bounds(k)
        ew = tile_bounds(neighbours(k)["E"])[0]
        assert (ew - e) % 360.0 == 0.0
        assert tile_bounds(neighbours(k)["N"])[1] == n


def test_tiles_covering_plain_and_antimeridian() -> None:
    x, y = tiles_covering(3, -10.0, 10.0, 10.0, 30.0)
    assert sorted(set(x.tolist())) == [7, 8] and sorted(set(y.tolist())) == [2, 3]
    # A box ending exactly on a tile edge does not pull in the next tile.
    x, y = tiles_covering(3, 0.0, 0.0, 22.5, 22.5)
    assert x.tolist() == [8] and y.tolist() == [3]
    x, _ = tiles_covering(3, 170.0, -5.0, -170.0, 5.0)
    assert sorted(set(x.tolist())) == [0, 15]
    x, y = tiles_covering(1, -180.0, -90.0, 180.0, 90.0)
    assert len(x) == 8 and len(set(zip(x.tolist(), y.tolist()))) == 8


def test_linear_key_unique() -> None:
    keys = {
        linear_key(TileKey(lv, x, y))
        for lv in range(4)
        for x in range(2 ** (lv + 1))
        for y in range(2**lv)
    }
    assert len(keys) == sum(2 ** (2 * lv + 1) for lv in range(4))
