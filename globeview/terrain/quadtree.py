"""The ellipsoidal quadtree: a geographic tile grid on WGS84 longitude/latitude.

Like OGC WorldCRS84Quad: level L has 2^(L+1) columns and 2^L rows of square tiles, each
180/2^L degrees on a side. A tile is addressed by ``TileKey(level, x, y)``: x counts columns
eastwards from longitude -180, **y counts rows southwards from latitude +90** (row 0 touches
the north pole). All angles are degrees of WGS84 geodetic longitude/latitude.

Each tile carries (2^n + 1) x (2^n + 1) grid-registered height samples (n = ``DEFAULT_TILE_N``
unless a store says otherwise): sample (r, c) of tile (L, x, y) sits at
``lon = west + c*d``, ``lat = north - r*d`` with ``d = (180/2^L) / 2^n``; neighbouring tiles
share their edge samples (TREND's one-sample overlap).

Zhang et al. index tiles with a single linear key per level (their eq. 2-3); we keep the
(level, x, y) triple instead, which is the same address without the integer packing and lets
numpy vectorise over x and y arrays. ``linear_key`` gives the packed form if it is wanted.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "DEFAULT_TILE_N",
    "TileKey",
    "ancestor_at",
    "children",
    "key_for_lonlat",
    "level_shape",
    "linear_key",
    "neighbours",
    "node_spacing",
    "parent",
    "tile_bounds",
    "tile_bounds_arrays",
    "tile_center_lonlat",
    "tile_size_deg",
    "tiles_covering",
]

DEFAULT_TILE_N = 6  # 65 x 65 samples per tile


class TileKey(NamedTuple):
    """Address of a tile: level L >= 0, column x in [0, 2^(L+1)), row y in [0, 2^L)."""

    level: int
    x: int
    y: int


def tile_size_deg(level: int) -> float:
    """Side of a level-``level`` tile in degrees (180 / 2^level)."""
    return 180.0 / (1 << level)


def node_spacing(level: int, tile_n: int = DEFAULT_TILE_N) -> float:
    """Spacing in degrees between height samples of a level (tile side / 2^tile_n)."""
    return tile_size_deg(level) / (1 << tile_n)


def level_shape(level: int) -> tuple[int, int]:
    """(columns, rows) of tiles at ``level``: (2^(L+1), 2^L)."""
    return 1 << (level + 1), 1 << level


def _check_level(level: int) -> None:
    if level < 0 or level > 30:
        raise ValueError(f"quadtree level must be in 0..30, got {level}")


def tile_bounds_arrays(
    level: int, x: np.ndarray | int, y: np.ndarray | int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised tile bounds in degrees: (west, south, east, north) arrays (float64)."""
    _check_level(level)
    size = tile_size_deg(level)
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    west = -180.0 + xa * size
    north = 90.0 - ya * size
    return west, north - size, west + size, north


def tile_bounds(key: TileKey) -> tuple[float, float, float, float]:
    """(west, south, east, north) of one tile in degrees."""
    w, s, e, n = tile_bounds_arrays(key.level, key.x, key.y)
    return float(w), float(s), float(e), float(n)


def tile_center_lonlat(
    level: int, x: np.ndarray | int, y: np.ndarray | int
) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised tile centres (lon, lat) in degrees."""
    w, s, e, n = tile_bounds_arrays(level, x, y)
    return (w + e) / 2.0, (s + n) / 2.0


def key_for_lonlat(
    level: int, lon: np.ndarray | float, lat: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Column and row (int64 arrays) of the tiles containing (lon, lat) degrees.

    Longitudes are wrapped into [-180, 180], except that lon = 180 exactly maps to the last
    column (it is the east edge of the grid) and lat = -90 to the last row. Tiles are half-open
    towards the east and south otherwise: a point on a shared edge belongs to the tile to its
    east / south.
    """
    _check_level(level)
    ncols, nrows = level_shape(level)
    size = tile_size_deg(level)
    lon_a = np.asarray(lon, dtype=np.float64)
    lat_a = np.asarray(lat, dtype=np.float64)
    inside = (lon_a >= -180.0) & (lon_a <= 180.0)
    wrapped = np.where(inside, lon_a, (lon_a + 180.0) % 360.0 - 180.0)
    x = np.floor((wrapped + 180.0) / size).astype(np.int64)
    y = np.floor((90.0 - np.clip(lat_a, -90.0, 90.0)) / size).astype(np.int64)
    # (90 - lat) / size rounds up for a latitude a hair above a tile edge: step back so the
    # point is always inside the tile it is given.
    y = np.where(90.0 - y * size < lat_a, y - 1, y)
    x = np.where(-180.0 + x * size > wrapped, x - 1, x)
    return np.clip(x, 0, ncols - 1), np.clip(y, 0, nrows - 1)


def parent(key: TileKey) -> TileKey:
    """The level-(L-1) tile containing ``key``. Raises ValueError at level 0."""
    if key.level == 0:
        raise ValueError("a level-0 tile has no parent")
    return TileKey(key.level - 1, key.x >> 1, key.y >> 1)


def ancestor_at(key: TileKey, level: int) -> TileKey:
    """The tile at ``level`` (<= key.level) containing ``key``."""
    if level < 0 or level > key.level:
        raise ValueError(f"ancestor level {level} must be in 0..{key.level}")
    shift = key.level - level
    return TileKey(level, key.x >> shift, key.y >> shift)


def children(key: TileKey) -> tuple[TileKey, TileKey, TileKey, TileKey]:
    """The four level-(L+1) tiles of ``key`` in the order NW, NE, SW, SE."""
    lv, x, y = key.level + 1, key.x * 2, key.y * 2
    return (
        TileKey(lv, x, y),
        TileKey(lv, x + 1, y),
        TileKey(lv, x, y + 1),
        TileKey(lv, x + 1, y + 1),
    )


def neighbours(key: TileKey) -> dict[str, TileKey | None]:
    """Edge neighbours at the same level: keys "N", "E", "S", "W".

    East/west wrap across the antimeridian. The pole rows have no tile beyond the pole: "N" of
    row 0 and "S" of the last row are None (the renderer closes the poles with fans).
    """
    ncols, nrows = level_shape(key.level)
    return {
        "N": TileKey(key.level, key.x, key.y - 1) if key.y > 0 else None,
        "E": TileKey(key.level, (key.x + 1) % ncols, key.y),
        "S": TileKey(key.level, key.x, key.y + 1) if key.y < nrows - 1 else None,
        "W": TileKey(key.level, (key.x - 1) % ncols, key.y),
    }


def _index_range(lo: float, hi: float, origin: float, size: float, count: int) -> tuple[int, int]:
    """First and last tile index whose interior meets [lo, hi] (a point picks its own tile)."""
    first = int(np.floor((lo - origin) / size))
    last = int(np.ceil((hi - origin) / size)) - 1
    last = max(last, first)
    return min(max(first, 0), count - 1), min(max(last, 0), count - 1)


def tiles_covering(
    level: int, west: float, south: float, east: float, north: float
) -> tuple[np.ndarray, np.ndarray]:
    """Columns and rows (int64 arrays, row-major order) of the tiles meeting a lon/lat box.

    A tile is included when its interior meets the box (a box edge lying on a tile edge does
    not pull in the tile beyond). ``west > east`` means the box crosses the antimeridian; a box
    with ``east - west >= 360`` covers every column.
    """
    _check_level(level)
    ncols, nrows = level_shape(level)
    size = tile_size_deg(level)
    y0, y1 = _index_range(90.0 - north, 90.0 - south, 0.0, size, nrows)
    if east - west >= 360.0:
        xs = np.arange(ncols, dtype=np.int64)
    else:
        w = (west + 180.0) % 360.0 - 180.0
        e = w + ((east - west) % 360.0 if east != west else 0.0)
        if east - west == 360.0:
            e = w + 360.0
        # Work on the unwrapped interval [w, e] (e may exceed 180), then fold columns.
        first = int(np.floor((w + 180.0) / size))
        last = max(int(np.ceil((e + 180.0) / size)) - 1, first)
        xs = np.arange(first, last + 1, dtype=np.int64) % ncols
        xs = xs[:ncols]  # an interval shorter than 360 never repeats a column
    ys = np.arange(y0, y1 + 1, dtype=np.int64)
    xx, yy = np.meshgrid(xs, ys)
    return xx.ravel(), yy.ravel()


def linear_key(key: TileKey) -> int:
    """A single integer per tile, unique across levels (Zhang et al.'s packed index idea).

    Levels 0..L-1 hold sum 2^(2l+1) = (2/3)(4^L - 1) tiles; the key is that offset plus the
    row-major index y * 2^(L+1) + x within the level.
    """
    offset = (2 * ((1 << (2 * key.level)) - 1)) // 3
    return offset + key.y * (1 << (key.level + 1)) + key.x
