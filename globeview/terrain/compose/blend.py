"""Seamless layers: the weight with which a DEM layer feathers into the layers below it.

A regional DEM over the global base would stand as a cliff along its edge (30 m data against
the 20' base: a wall of tens to hundreds of metres). `TerrainStack` composes a layer over those
below as ``B = L + w (U - L)`` with ``w = BlendMask.sample(lon, lat)`` in [0, 1]: 0 on the edge
of the layer's data, 1 one border band inside it. The weight depends on position only (degrees
of longitude and latitude, never on a tile or level), so tiles of every level describe one
surface and the LOD's errors can bound the difference between them.

`weight_change_bound` is the Lipschitz bound of w that those errors use (see
`TerrainStack._blend_error`).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from globeview.terrain.compose.mask_cache import (
    load_interp_errors,
    load_weights,
    mask_key,
    save_interp_errors,
    save_weights,
)
from globeview.terrain.interpolate import bilinear, interp_axis, linear_weights
from globeview.terrain.quadtree import node_spacing, tile_bounds_arrays
from globeview.terrain.store.coverage import coverage_level
from globeview.terrain.store.tile_store import TileStore

#: Width of a layer's border band as a fraction of its footprint's shorter side. The band is a
#: property of the layer (position-only weights). A twentieth of the footprint leaves the
#: central 90 % of each axis untouched (a wider band also smoothed away the detail the LOD
#: refines on) and still spreads the step between, e.g., 30 m data and the 20' base (hundreds
#: of metres) over ~50-70 of the regional data's own nodes at its finest levels.
BLEND_FRACTION = 0.05

#: The band spans at least this many of the layer's finest nodes ...
BLEND_MIN_NODES = 16

#: ... and at most this fraction of the footprint's shorter side.
BLEND_MAX_FRACTION = 0.15

# The coverage is read at `globeview.terrain.store.coverage.coverage_level` (`MASK_NODES`
# nodes across the footprint's shorter side).

#: Slope bound of smoothstep(t) = t^2 (3 - 2 t) on [0, 1] (at t = 1/2).
SMOOTHSTEP_SLOPE = 1.5


def blend_band(bounds: tuple[float, float, float, float], finest_spacing: float = 0.0) -> float:
    """Border band width (degrees) of a layer with footprint (west, south, east, north) and
    node spacing ``finest_spacing`` (degrees) at its finest level: `BLEND_FRACTION` of the
    footprint's shorter side, but at least `BLEND_MIN_NODES` of its own nodes (a coarse layer's
    band would otherwise be a few nodes wide: a ramp as steep as the cliff it replaces, and
    as costly to draw) and at most `BLEND_MAX_FRACTION` of the shorter side."""
    west, south, east, north = bounds
    short = min((east - west) % 360.0 or 360.0, north - south)
    band = max(BLEND_FRACTION * short, BLEND_MIN_NODES * finest_spacing)
    return min(band, BLEND_MAX_FRACTION * short)


def weight_change_bound(cell_deg: np.ndarray | float, band_deg: float) -> np.ndarray:
    """Bound on |w(corner) - w(p)| for a point p and the corners of a drawn cell of side
    ``cell_deg`` (degrees, the same along both axes on the quadtree) holding it.

    Derivation: c (a box mean over half-side ``band``) changes by at most delta / (2 band) per
    delta degrees along an axis, so 2c - 1 by delta / band, and smoothstep's slope is <= 1.5;
    a corner is at most one cell side away along each axis: |dw| <= 1.5 * 2 cell / band.
    """
    return np.minimum(1.0, SMOOTHSTEP_SLOPE * 2.0 * np.asarray(cell_deg) / band_deg)


class BlendMask:
    """A layer's blend weight w(lon, lat) in [0, 1] over the layers below, on a fixed raster.

    w = smoothstep(clip(2 c - 1, 0, 1)), c = the fraction of the layer's data coverage in a
    square of half-side ``band`` around the point (an integral-image box mean of the layer's
    nodata mask, read once at level ``level``). On a straight data edge c = 1/2, so w = 0 there
    and reaches 1 one band inside; it follows nodata holes and rotated footprints (projected
    sources leave nodata wedges inside their lon/lat box) as well as the box edge. A footprint
    all the way round has no edge at +-180, one reaching a pole none there. Sampled bilinearly,
    it keeps the Lipschitz bound of `weight_change_bound`.
    """

    def __init__(self, st: TileStore) -> None:
        tile_n = int(np.log2(st.tile_size - 1))
        self.band = blend_band(st.bounds, node_spacing(st.max_level, tile_n))
        self.level = coverage_level(st.bounds, tile_n, st.max_level)
        lv = self.level
        grid = st.level_grid(lv)
        cells = st.tile_size - 1
        self.step = (180.0 / 2**lv) / cells
        w0, _, _, n0 = (float(v) for v in tile_bounds_arrays(lv, grid.x0, grid.y0))
        self.west, self.north = w0, n0
        #: The name the mask is kept under in the user's cache (`mask_cache`), None: not kept.
        self.cache_key = mask_key(st)
        # _box_mean's raster is one node larger than the coverage's along each axis.
        shape = (grid.ny * cells + 2, grid.nx * cells + 2)
        kept = None if self.cache_key is None else load_weights(self.cache_key, shape)
        if kept is None:
            self.w = self._weights(st, lv)
            # Integral image of "w < 1" raster nodes: does a lon/lat box meet the band?
            part = np.pad((self.w < 1.0).astype(np.int64), ((1, 0), (1, 0)))
            self._partial = part.cumsum(0).cumsum(1)
            if self.cache_key is not None:
                save_weights(self.cache_key, self.w, self._partial)
        else:
            self.w, self._partial = kept
        #: `interpolation_error` by cell size in raster steps (it depends on w only).
        self.interp_errors: dict[int, float] = (
            {} if self.cache_key is None else load_interp_errors(self.cache_key)
        )

    def _weights(self, st: TileStore, lv: int) -> np.ndarray:
        """The weight raster (float32) built from the store's coverage at level ``lv``: once
        per layer, never per frame (the top shard's coverage; a store built before it: a few
        dozen tiles of the level read), and once per store and terrain code in the user's
        cache."""
        r = max(1, round(self.band / self.step))
        c = _box_mean(st.coverage(lv).astype(np.float64), r, st.bounds)
        t = np.clip(2.0 * c - 1.0, 0.0, 1.0)
        return (t * t * (3.0 - 2.0 * t)).astype(np.float32)

    def _east_of_west(self, lon: np.ndarray) -> np.ndarray:
        """Degrees east of the raster's west edge, the longitude taken within 180 degrees of
        the raster's middle: a layer crossing the antimeridian has its raster run on past
        +180 (the level grid wraps too), and a place just west of the raster comes out
        negative (not 359.x: a tile starting there and reaching into the raster must)."""
        half = 0.5 * (self.w.shape[1] - 1) * self.step
        return np.mod(lon - self.west - half + 180.0, 360.0) - 180.0 + half

    def sample(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """w at points (degrees; outside the raster: 0)."""
        ny, nx = self.w.shape
        cols = self._east_of_west(np.asarray(lon, dtype=np.float64)) / self.step
        rows = (self.north - np.asarray(lat, dtype=np.float64)) / self.step
        inside = (cols >= 0) & (cols <= nx - 1) & (rows >= 0) & (rows <= ny - 1)
        return np.where(inside, bilinear(self.w, rows, cols), 0.0)

    def sample_grid(
        self, west: float, south: float, east: float, north: float, size: int
    ) -> np.ndarray:
        """(size, size) w at a tile's nodes (bounds in degrees, row 0 north): `sample` on a
        regular grid, done as two small matrix products over the raster rows and columns
        the tile spans (bilinear is separable)."""
        ny, nx = self.w.shape
        start = float(self._east_of_west(np.array(west)))
        cols = (start + np.linspace(0.0, east - west, size)) / self.step
        rows = (self.north - np.linspace(north, south, size)) / self.step
        c0 = int(np.clip(np.floor(cols.min()), 0, nx - 2))
        c1 = int(np.clip(np.ceil(cols.max()), c0 + 1, nx - 1))
        r0 = int(np.clip(np.floor(rows.min()), 0, ny - 2))
        r1 = int(np.clip(np.ceil(rows.max()), r0 + 1, ny - 1))
        if (r1 - r0 + 1) * (c1 - c0 + 1) > size * size:
            # A coarse tile over much of the raster: gathering 4 corners a node is cheaper.
            lon, lat = np.meshgrid(np.linspace(west, east, size), np.linspace(north, south, size))
            return self.sample(lon.ravel(), lat.ravel()).reshape(size, size)
        sub = self.w[r0 : r1 + 1, c0 : c1 + 1].astype(np.float64)
        wr = linear_weights(rows - r0, sub.shape[0])
        out = wr @ sub @ linear_weights(cols - c0, sub.shape[1]).T
        inside_c = (cols >= 0) & (cols <= nx - 1)
        inside_r = (rows >= 0) & (rows <= ny - 1)
        return np.where(inside_r[:, None] & inside_c[None, :], out, 0.0)

    def touches_band(
        self, tw: np.ndarray, ts: np.ndarray, te: np.ndarray, tn: np.ndarray
    ) -> np.ndarray:
        """Whether tiles (bounds arrays, degrees) may hold nodes with w < 1: conservatively,
        any raster node with w < 1 within one raster step of them."""
        ny, nx = self.w.shape
        start = self._east_of_west(np.asarray(tw, dtype=np.float64))
        end = start + (np.asarray(te, dtype=np.float64) - tw)
        c0 = np.clip(np.floor(start / self.step).astype(np.int64) - 1, 0, nx)
        c1 = np.clip(np.ceil(end / self.step).astype(np.int64) + 2, 0, nx)
        r0 = np.clip(np.floor((self.north - tn) / self.step).astype(np.int64) - 1, 0, ny)
        r1 = np.clip(np.ceil((self.north - ts) / self.step).astype(np.int64) + 2, 0, ny)
        p = self._partial
        n = p[r1, c1] - p[r0, c1] - p[r1, c0] + p[r0, c0]
        # Outside the raster w = 0, but such tiles hold no data of this layer: nothing to blend.
        return n > 0

    def touches_band_one(self, tw: float, ts: float, te: float, tn: float) -> bool:
        """`touches_band` for one tile, in Python floats: the tile compose path asks it per
        layer of every tile, where numpy's per-call overhead on 1-element arrays was ~35 us
        (issue #17). The same arithmetic, so the same answer."""
        ny, nx = self.w.shape
        half = 0.5 * (nx - 1) * self.step
        # _east_of_west: np.mod takes the sign of the divisor, as Python's % does.
        start = (tw - self.west - half + 180.0) % 360.0 - 180.0 + half
        end = start + (te - tw)
        c0 = min(max(math.floor(start / self.step) - 1, 0), nx)
        c1 = min(max(math.ceil(end / self.step) + 2, 0), nx)
        r0 = min(max(math.floor((self.north - tn) / self.step) - 1, 0), ny)
        r1 = min(max(math.ceil((self.north - ts) / self.step) + 2, 0), ny)
        p = self._partial
        return bool(p[r1, c1] - p[r0, c1] - p[r1, c0] + p[r0, c0] > 0)


def _box_mean(data: np.ndarray, r: int, bounds: tuple[float, float, float, float]) -> np.ndarray:
    """Mean of ``data`` over the (2r+1)^2 box centred on each node. Beyond the raster there is
    no data, except that a footprint all the way round continues across +-180 (wrap) and one
    reaching a pole has no edge there (the pole row repeats)."""
    west, south, east, north = bounds
    if east - west >= 360.0 - 1e-9 and data.shape[1] > 1:
        ring = data[:, :-1]  # the last column repeats the first (-180 = +180)
        reps = -(-(r + 1) // ring.shape[1])
        tiled = np.concatenate([ring] * (2 * reps + 1), axis=1)
        c0 = reps * ring.shape[1] - (r + 1)
        data = tiled[:, c0 : c0 + data.shape[1] + 2 * (r + 1)]
    else:
        data = np.pad(data, ((0, 0), (r + 1, r + 1)))
    top: Literal["edge", "constant"] = "edge" if north >= 90.0 - 1e-9 else "constant"
    bottom: Literal["edge", "constant"] = "edge" if south <= -90.0 + 1e-9 else "constant"
    data = np.pad(data, ((r + 1, 0), (0, 0)), mode=top)
    data = np.pad(data, ((0, r + 1), (0, 0)), mode=bottom)
    ii = data.cumsum(0).cumsum(1)
    k = 2 * r + 1
    box = ii[k:, k:] - ii[:-k, k:] - ii[k:, :-k] + ii[:-k, :-k]
    return box / (k * k)


def interpolation_error(mask: BlendMask, cell_deg: float) -> float:
    """max |interp(w) - w| over the layer, w interpolated bilinearly between the corners of
    quadtree-aligned cells of side ``cell_deg`` (a power-of-two multiple or fraction of the
    raster step).

    w is bilinear on its raster, so a cell inside one raster cell reproduces it exactly (0);
    for larger cells the difference of the two piecewise-bilinear surfaces peaks at raster
    nodes, where it is measured (once per cell size, cached on the mask).
    """
    m = round(cell_deg / mask.step)
    if m <= 1:
        return 0.0
    cache = mask.interp_errors
    hit = cache.get(m)
    if hit is not None:
        return hit
    w = mask.w.astype(np.float64)
    ny, nx = w.shape
    # Raster node (0, 0) lies on a tile corner of the mask's level; cells of m raster steps
    # start at multiples of m steps counted from -180 / +90 degrees.
    c0 = round((mask.west + 180.0) / mask.step) % m
    r0 = round((90.0 - mask.north) / mask.step) % m
    n_cols = -(-(c0 + nx - 1) // m) + 1
    n_rows = -(-(r0 + ny - 1) // m) + 1
    lon = mask.west + (np.arange(n_cols) * m - c0) * mask.step
    lat = mask.north - (np.arange(n_rows) * m - r0) * mask.step
    lo, la = np.meshgrid(lon, lat)
    corners = mask.sample(lo.ravel(), la.ravel()).reshape(n_rows, n_cols)
    if corners.shape[0] < 2 or corners.shape[1] < 2:
        corners = np.pad(corners, ((0, corners.shape[0] < 2), (0, corners.shape[1] < 2)))
    rows = (r0 + np.arange(ny)) / m
    cols = (c0 + np.arange(nx)) / m
    # Bilinear is separable: interpolate along rows, then columns (two gathers a node; the
    # dense weight matrices' product cost seconds on a global layer's raster).
    interp = interp_axis(interp_axis(corners, rows, 0), cols, 1)
    hit = float(np.abs(interp - w).max())
    cache[m] = hit
    if mask.cache_key is not None:
        save_interp_errors(mask.cache_key, dict(cache))
    return hit
