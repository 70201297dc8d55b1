"""Zhang et al.'s linear index key for the ellipsoidal quadtree (Geobeans3D §IV, eq. 2-3),
corrected.

Setting. A dataset of M x N posts (M rows along latitude, N columns along longitude) spans
geodetic degrees [lon_min, lon_max] x [lat_min, lat_max]. It is divided into quadrangles of
``row x col`` posts: at level 0 there are ``q_lon = int(N / col)`` quadrangles west-east and
``q_lat = int(M / row)`` south-north, each ``dlon = (lon_max - lon_min) / q_lon`` by
``dlat = (lat_max - lat_min) / q_lat`` degrees. Each quadtree level i doubles the quadrangle
size (level 0 is the finest), so level i has

    n_lon(i) = ceil(q_lon / 2^i),   n_lat(i) = ceil(q_lat / 2^i),   count(i) = n_lon(i) n_lat(i)

cells of 2^i dlon x 2^i dlat degrees (ceil: when q is not a power of two the last cell of a
row or column sticks out past lon_max / lat_max; ``bounds`` clips it to the dataset), and the
levels run i = 0 .. n_levels - 1 with n_levels = 1 + ceil(log2(max(q_lon, q_lat))) (the last
level is a single cell).

Corrected eq. (2), keys numbered level by level, row-major (south to north, west to east):

    col(i)    = min(floor((lon - lon_min) / (2^i dlon)), n_lon(i) - 1)
    row(i)    = min(floor((lat - lat_min) / (2^i dlat)), n_lat(i) - 1)
    offset(i) = sum_{j=0}^{i-1} count(j)
    key       = offset(i) + row(i) * n_lon(i) + col(i)

Departures from the printed eq. (2): its longitude term ``int(lon / (2^i dlon))`` forgets
lon_min; its latitude term is not multiplied by the number of cells per row (so keys of
different cells collide); its level offset ``sum_{j=1}^{i} q_lon q_lat 2^-j`` is neither the
number of cells of the previous levels (a level has about q_lon q_lat 4^-j cells, not 2^-j)
nor an integer for odd q. The min(...) clamp, so that points on the max edge fall into the
last cell, is ours.

Corrected eq. (3), from a key: find the level i with offset(i) <= key < offset(i+1),
t = key - offset(i), then

    lat1 = lat_min + int(t / n_lon(i)) * 2^i dlat           (printed: int(t - q_lon) dlat)
    lon1 = lon_min + (t - int(t / n_lon(i)) n_lon(i)) 2^i dlon
                                          (printed: ((t - int(t / q_lon)) q_lon) dlon)
    lat2 = min(lat1 + 2^i dlat, lat_max),   lon2 = min(lon1 + 2^i dlon, lon_max)

(the printed version also drops the 2^i level scale and uses q_lon for n_lon(i)).

Reference code, not used by the store or the renderer (issue #14 asked: wire it in or say
why not). globeview keys tiles as (level, x, y) of one global quadtree with level 0 the
coarsest (`globeview.terrain.quadtree`), because tiles of every DEM layer must line up for
the stack to compose them and for the LOD to walk them; Zhang's key numbers a per-dataset
quadtree from its finest level up, for rows of a database table, so two datasets' keys never
name the same place. The module stays as the corrected, tested reading of eq. 2-3
(tests/terrain/test_zhang_index.py) for comparing with the paper and for importing
Geobeans3D-keyed data.
"""

from __future__ import annotations

import math

import numpy as np

from globeview.errors import GlobeviewError

__all__ = ["ZhangIndex", "ZhangIndexError"]


class ZhangIndexError(GlobeviewError, ValueError):
    """Bad index parameters, a point outside the dataset or an unknown key (one line)."""


def _ceil_div(a: np.ndarray | int, b: np.ndarray | int) -> np.ndarray | int:
    return -(-a // b)


class ZhangIndex:
    """Quadtree index keys over a geographic dataset (degrees), per Zhang eq. (2)-(3) corrected.

    Args:
        lon_min, lat_min, lon_max, lat_max: dataset bounds in geodetic degrees.
        rows_posts, cols_posts: the dataset's posts M (latitude rows) and N (longitude columns).
        row, col: posts per level-0 quadrangle along latitude and longitude.
    """

    def __init__(
        self,
        lon_min: float,
        lat_min: float,
        lon_max: float,
        lat_max: float,
        rows_posts: int,
        cols_posts: int,
        row: int,
        col: int,
    ) -> None:
        if not (lon_max > lon_min and lat_max > lat_min):
            raise ZhangIndexError(
                f"empty dataset bounds: lon {lon_min}..{lon_max}, lat {lat_min}..{lat_max}"
            )
        if min(rows_posts, cols_posts, row, col) < 1:
            raise ZhangIndexError("post counts and quadrangle sizes must be positive integers")
        self.lon_min, self.lat_min = float(lon_min), float(lat_min)
        self.lon_max, self.lat_max = float(lon_max), float(lat_max)
        self.q_lon = int(cols_posts // col)
        self.q_lat = int(rows_posts // row)
        if self.q_lon < 1 or self.q_lat < 1:
            raise ZhangIndexError(
                f"a quadrangle of {row} x {col} posts is larger than the dataset "
                f"({rows_posts} x {cols_posts} posts)"
            )
        self.dlon = (self.lon_max - self.lon_min) / self.q_lon
        self.dlat = (self.lat_max - self.lat_min) / self.q_lat
        self.n_levels = 1 + math.ceil(math.log2(max(self.q_lon, self.q_lat)))
        i = np.arange(self.n_levels)
        self._n_lon = np.asarray(_ceil_div(self.q_lon, 2**i)).astype(np.int64)
        self._n_lat = np.asarray(_ceil_div(self.q_lat, 2**i)).astype(np.int64)
        counts = self._n_lon * self._n_lat
        # offsets[i] = cells in levels 0..i-1; offsets[n_levels] = total key count.
        self._offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    def _check_level(self, level: int) -> int:
        if not 0 <= int(level) < self.n_levels:
            raise ZhangIndexError(f"level {level} outside 0..{self.n_levels - 1}")
        return int(level)

    def level_shape(self, level: int) -> tuple[int, int]:
        """Cells at ``level`` as (n_lat, n_lon): rows south-north, columns west-east."""
        level = self._check_level(level)
        return int(self._n_lat[level]), int(self._n_lon[level])

    def offset(self, level: int) -> int:
        """First key of ``level``: the number of cells in all finer levels before it."""
        return int(self._offsets[self._check_level(level)])

    @property
    def n_keys(self) -> int:
        """Total number of keys over all levels."""
        return int(self._offsets[-1])

    def keys_at_level(self, level: int) -> np.ndarray:
        """All keys of ``level``: the contiguous range [offset(i), offset(i) + count(i))."""
        level = self._check_level(level)
        return np.arange(self._offsets[level], self._offsets[level + 1], dtype=np.int64)

    def key(self, level: int, lon: float | np.ndarray, lat: float | np.ndarray) -> int | np.ndarray:
        """Key of the level-``level`` cell holding (lon, lat) degrees; vectorised.

        Returns an int for scalar input, an int64 array otherwise. Points on the max edges
        fall into the last cell.

        Raises:
            ZhangIndexError: a level out of range or a point outside the dataset bounds.
        """
        level = self._check_level(level)
        lon_a = np.asarray(lon, dtype=np.float64)
        lat_a = np.asarray(lat, dtype=np.float64)
        outside = (
            ~(lon_a >= self.lon_min)
            | ~(lon_a <= self.lon_max)
            | ~(lat_a >= self.lat_min)
            | ~(lat_a <= self.lat_max)
        )
        if np.any(outside):
            bad = np.broadcast_arrays(lon_a, lat_a)
            j = np.flatnonzero(np.broadcast_to(outside, bad[0].shape))[0]
            raise ZhangIndexError(
                f"point (lon {bad[0].flat[j]}, lat {bad[1].flat[j]}) is outside the dataset "
                f"bounds lon {self.lon_min}..{self.lon_max}, lat {self.lat_min}..{self.lat_max}"
            )
        scale = float(2**level)
        n_lon, n_lat = self._n_lon[level], self._n_lat[level]
        # Departure from printed eq. (2): subtract lon_min; clamp the max edge into the grid.
        col = np.minimum(np.floor((lon_a - self.lon_min) / (scale * self.dlon)), n_lon - 1)
        row = np.minimum(np.floor((lat_a - self.lat_min) / (scale * self.dlat)), n_lat - 1)
        # Departure: the row term is scaled by cells per row, and the offset counts the cells
        # of levels 0..i-1 instead of sum_j q_lon q_lat 2^-j.
        keys = self._offsets[level] + row.astype(np.int64) * n_lon + col.astype(np.int64)
        return int(keys) if keys.ndim == 0 else keys

    def bounds(
        self, key: int | np.ndarray
    ) -> tuple[int, float, float, float, float] | tuple[np.ndarray, ...]:
        """Corrected eq. (3): ``(level, lon1, lat1, lon2, lat2)`` of a key, degrees.

        Vectorised: for an array of keys each item of the tuple is an array. The last cell
        of a row/column at a level with non-power-of-two q is clipped to the dataset.

        Raises:
            ZhangIndexError: a key outside [0, n_keys).
        """
        k = np.asarray(key, dtype=np.int64)
        if np.any((k < 0) | (k >= self.n_keys)):
            raise ZhangIndexError(f"index key outside 0..{self.n_keys - 1}")
        level = np.searchsorted(self._offsets, k, side="right") - 1
        t = k - self._offsets[level]
        n_lon = self._n_lon[level]
        scale = 2.0**level
        # Departure from printed eq. (3): int(t / n_lon) (not int(t - q_lon)) and
        # t - int(t / n_lon) * n_lon (not (t - int(t / q_lon)) * q_lon), both scaled by 2^i.
        row = t // n_lon
        col = t - row * n_lon
        lat1 = self.lat_min + row * scale * self.dlat
        lon1 = self.lon_min + col * scale * self.dlon
        lat2 = np.minimum(lat1 + scale * self.dlat, self.lat_max)
        lon2 = np.minimum(lon1 + scale * self.dlon, self.lon_max)
        if k.ndim == 0:
            return int(level), float(lon1), float(lat1), float(lon2), float(lat2)
        return level, lon1, lat1, lon2, lat2
