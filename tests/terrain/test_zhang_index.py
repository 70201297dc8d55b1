"""Tests for Zhang's corrected quadtree index key (globeview.terrain.zhang_index)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from globeview.errors import GlobeviewError
from globeview.terrain.zhang_index import ZhangIndex

# (lon_min, lat_min, lon_max, lat_max, rows_posts, cols_posts, row, col)
GRIDS = [
    (-180.0, -90.0, 180.0, 90.0, 1025, 2049, 64, 64),  # q = 16 x 32, powers of two
    (100.0, 20.0, 110.0, 30.0, 700, 500, 100, 100),  # q_lat = 7, q_lon = 5
    (-75.5, 40.25, -70.0, 45.75, 1201, 1201, 120, 240),  # q_lat = 10, q_lon = 5
    (5.0, 45.0, 11.0, 48.0, 300, 3000, 100, 100),  # q = 3 x 30, far from square
    (0.0, 0.0, 1.0, 1.0, 50, 50, 50, 50),  # a single quadrangle
]


def _index(grid: tuple) -> ZhangIndex:
    return ZhangIndex(*grid)


@pytest.mark.parametrize("grid", GRIDS)
def test_level_counts_follow_ceil_halving(grid: tuple) -> None:
    idx = _index(grid)
    q_lat, q_lon = grid[4] // grid[6], grid[5] // grid[7]
    assert idx.level_shape(0) == (q_lat, q_lon)
    for level in range(idx.n_levels):
        n_lat, n_lon = idx.level_shape(level)
        # Independent formulation: repeated ceil-halving of the previous level's count.
        exp_lat, exp_lon = q_lat, q_lon
        for _ in range(level):
            exp_lat, exp_lon = (exp_lat + 1) // 2, (exp_lon + 1) // 2
        assert (n_lat, n_lon) == (exp_lat, exp_lon)
    assert idx.level_shape(idx.n_levels - 1) == (1, 1)
    if idx.n_levels > 1:
        assert idx.level_shape(idx.n_levels - 2) != (1, 1)


@pytest.mark.parametrize("grid", GRIDS)
def test_every_cell_round_trips_and_keys_are_contiguous(grid: tuple) -> None:
    idx = _index(grid)
    lon_min, lat_min, lon_max, lat_max = grid[:4]
    seen: list[np.ndarray] = []
    expected_offset = 0
    for level in range(idx.n_levels):
        keys = idx.keys_at_level(level)
        n_lat, n_lon = idx.level_shape(level)
        assert keys[0] == expected_offset == idx.offset(level)
        np.testing.assert_array_equal(keys, np.arange(expected_offset, expected_offset + keys.size))
        assert keys.size == n_lat * n_lon
        lvl, lon1, lat1, lon2, lat2 = idx.bounds(keys)
        assert np.all(lvl == level)
        assert np.all((lon_min <= lon1) & (lon1 < lon2) & (lon2 <= lon_max))
        assert np.all((lat_min <= lat1) & (lat1 < lat2) & (lat2 <= lat_max))
        # key -> bounds -> key through the cell centre.
        back = idx.key(level, (lon1 + lon2) / 2, (lat1 + lat2) / 2)
        np.testing.assert_array_equal(back, keys)
        # The cells tile the dataset: areas (in degree^2) sum to the whole.
        area = np.sum((lon2 - lon1) * (lat2 - lat1))
        assert area == pytest.approx((lon_max - lon_min) * (lat_max - lat_min), rel=1e-12)
        seen.append(keys)
        expected_offset += keys.size
    all_keys = np.concatenate(seen)
    assert np.unique(all_keys).size == all_keys.size == idx.n_keys


@pytest.mark.parametrize("grid", GRIDS)
def test_scalar_key_and_bounds(grid: tuple) -> None:
    idx = _index(grid)
    lon = grid[0] + 0.37 * (grid[2] - grid[0])
    lat = grid[1] + 0.81 * (grid[3] - grid[1])
    for level in range(idx.n_levels):
        k = idx.key(level, lon, lat)
        assert isinstance(k, int)
        lvl, lon1, lat1, lon2, lat2 = idx.bounds(k)
        assert lvl == level
        assert lon1 <= lon <= lon2 and lat1 <= lat <= lat2


@pytest.mark.parametrize("grid", GRIDS)
def test_max_edge_maps_into_last_cell(grid: tuple) -> None:
    idx = _index(grid)
    for level in range(idx.n_levels):
        n_lat, n_lon = idx.level_shape(level)
        last = idx.offset(level) + n_lat * n_lon - 1
        assert idx.key(level, grid[2], grid[3]) == last
        assert idx.key(level, grid[0], grid[1]) == idx.offset(level)


def test_nested_cells_contain_their_children() -> None:
    idx = _index(GRIDS[1])
    rng = np.random.default_rng(0)
    lon = rng.uniform(100.0, 110.0, 500)
    lat = rng.uniform(20.0, 30.0, 500)
    for level in range(1, idx.n_levels):
        _, plon1, plat1, plon2, plat2 = idx.bounds(idx.key(level, lon, lat))
        _, clon1, clat1, clon2, clat2 = idx.bounds(idx.key(level - 1, lon, lat))
        assert np.all((plon1 <= clon1) & (clon2 <= plon2 + 1e-12))
        assert np.all((plat1 <= clat1) & (clat2 <= plat2 + 1e-12))


def _paper_literal_key(idx: ZhangIndex, level: int, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Zhang eq. (2) exactly as printed (with its typos), for the demonstration below."""
    s = 2.0**level
    offset = sum(idx.q_lon * idx.q_lat * 2.0**-j for j in range(1, level + 1))
    return np.floor(lon / (s * idx.dlon)) + np.floor((lat - idx.lat_min) / (s * idx.dlat)) + offset


def test_printed_formula_fails_the_round_trip() -> None:
    idx = _index(GRIDS[1])
    keys = idx.keys_at_level(0)
    _, lon1, lat1, lon2, lat2 = idx.bounds(keys)
    literal = _paper_literal_key(idx, 0, (lon1 + lon2) / 2, (lat1 + lat2) / 2)
    # The printed formula neither returns the keys nor even tells the cells apart.
    assert not np.array_equal(literal, keys)
    assert np.unique(literal).size < keys.size


def test_bad_input_gives_one_line_errors() -> None:
    idx = _index(GRIDS[1])
    with pytest.raises(GlobeviewError, match="outside the dataset"):
        idx.key(0, np.array([105.0, 111.0]), np.array([25.0, 25.0]))
    with pytest.raises(ValueError, match="outside the dataset"):
        idx.key(0, 105.0, float("nan"))
    with pytest.raises(GlobeviewError, match="level"):
        idx.key(idx.n_levels, 105.0, 25.0)
    with pytest.raises(GlobeviewError, match="key outside"):
        idx.bounds(idx.n_keys)
    with pytest.raises(GlobeviewError, match="larger than the dataset"):
        ZhangIndex(0, 0, 1, 1, 50, 50, 100, 10)
    with pytest.raises(GlobeviewError, match="empty dataset bounds"):
        ZhangIndex(1, 0, 1, 1, 50, 50, 10, 10)


def test_n_levels_matches_log2() -> None:
    for q in [1, 2, 3, 4, 5, 8, 9, 30]:
        idx = ZhangIndex(0.0, 0.0, 1.0, 1.0, 10, 10 * q, 10, 10)
        assert idx.n_levels == 1 + math.ceil(math.log2(q))
