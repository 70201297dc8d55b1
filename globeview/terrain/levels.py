"""Geometry of one pyramid level raster and windowed node reads from it.

A level raster covers a rectangle of quadtree tiles, its *extent* (x0, y0, nx, ny): tiles
x0..x0+nx-1 (columns taken modulo 2^(L+1), so an extent may run past the antimeridian with
longitudes beyond 180) and rows y0..y0+ny-1. Nodes are grid-registered: raster pixel (r, c)
*is* the node at lon = west + c*d, lat = north - r*d (degrees, d = node spacing).

"Global node indices" number the nodes of a level over the whole globe: row gr = (90 - lat)/d
and column gc = (lon + 180)/d, *unwrapped* (gc may exceed the nodes of one turn when the
extent crosses the antimeridian; reads fold it back modulo one turn).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import rasterio
from affine import Affine
from rasterio.windows import Window

from globeview.terrain.quadtree import level_shape, node_spacing, tile_size_deg

__all__ = ["LevelGrid", "read_level_nodes"]


@dataclass(frozen=True)
class LevelGrid:
    """One level's tile extent and node raster (angles in degrees)."""

    level: int
    tile_n: int
    x0: int
    y0: int
    nx: int
    ny: int

    @property
    def tile_nodes(self) -> int:
        """Node intervals per tile side, 2^n (a tile has tile_nodes + 1 samples a side)."""
        return 1 << self.tile_n

    @property
    def ncols(self) -> int:
        """Tile columns of the whole level."""
        return level_shape(self.level)[0]

    @property
    def nrows(self) -> int:
        """Tile rows of the whole level."""
        return level_shape(self.level)[1]

    @property
    def width(self) -> int:
        return self.nx * self.tile_nodes + 1

    @property
    def height(self) -> int:
        return self.ny * self.tile_nodes + 1

    @property
    def d(self) -> float:
        """Node spacing in degrees."""
        return node_spacing(self.level, self.tile_n)

    @property
    def global_lon(self) -> bool:
        """True when the extent spans all 360 degrees of longitude."""
        return self.nx == self.ncols

    @property
    def west(self) -> float:
        return -180.0 + self.x0 * tile_size_deg(self.level)

    @property
    def north(self) -> float:
        return 90.0 - self.y0 * tile_size_deg(self.level)

    @property
    def transform(self) -> Affine:
        """GDAL geotransform: pixel edges half a node outside the nodes (pixel-is-point)."""
        d = self.d
        return Affine(d, 0.0, self.west - d / 2.0, 0.0, -d, self.north + d / 2.0)

    @property
    def file_name(self) -> str:
        """The level's GDAL VRT (mosaic of its chunk files, see `store.schema`)."""
        return f"level_{self.level:02d}.vrt"

    @property
    def gr0(self) -> int:
        """Global node row of raster row 0."""
        return self.y0 * self.tile_nodes

    @property
    def gc0(self) -> int:
        """Global (unwrapped) node column of raster column 0."""
        return self.x0 * self.tile_nodes

    def raster_rows(self, gr: np.ndarray) -> np.ndarray:
        """Raster rows of global node rows; -1 outside the raster."""
        rr = np.asarray(gr) - self.gr0
        return np.where((rr >= 0) & (rr < self.height), rr, -1)

    def raster_cols(self, gc: np.ndarray) -> np.ndarray:
        """Raster columns of (unwrapped) global node columns, folded modulo one turn; -1
        outside the raster."""
        turn = self.ncols * self.tile_nodes
        rc = (np.asarray(gc) - self.gc0) % turn
        if not self.global_lon:
            # A regional extent may also hold the node one turn further (its east edge).
            rc = np.where(rc < self.width, rc, -1)
        return rc

    def tile_slots(
        self, ty: np.ndarray, tx: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Indices (iy, ix) into (ny, nx) per-tile arrays and a mask of tiles in the extent."""
        ty = np.asarray(ty, dtype=np.int64)
        tx = np.asarray(tx, dtype=np.int64)
        iy = ty - self.y0
        ix = (tx - self.x0) % self.ncols
        inside = (iy >= 0) & (iy < self.ny) & (ix < self.nx) & (tx >= 0) & (tx < self.ncols)
        return np.where(inside, iy, 0), np.where(inside, ix, 0), inside


def _runs(pos: np.ndarray, idx: np.ndarray) -> list[tuple[int, int, int]]:
    """Split valid positions into runs where both the output position and the raster index
    advance by one: (output start, raster start, length)."""
    if pos.size == 0:
        return []
    brk = np.flatnonzero((np.diff(pos) != 1) | (np.diff(idx) != 1)) + 1
    starts = np.r_[0, brk]
    ends = np.r_[brk, pos.size]
    return [(int(pos[a]), int(idx[a]), int(b - a)) for a, b in zip(starts, ends)]


def read_level_nodes(
    ds: rasterio.DatasetReader,
    grid: LevelGrid,
    gr0: int,
    gc0: int,
    h: int,
    w: int,
    mirror: int = 0,
) -> np.ndarray:
    """Nodes [gr0, gr0+h) x [gc0, gc0+w) (global, unwrapped) of a level raster, float32.

    NaN outside the raster. With ``mirror`` > 0, up to that many nodes beyond the raster's
    true edges are filled with the odd mirror about the edge node (2*x[0] - x[k], as
    ``wavelet.extend_borders``), so a windowed wavelet approximation equals the whole-array
    one at the raster's borders. Longitudes of a global level wrap instead of mirroring.
    """
    rr = grid.raster_rows(gr0 + np.arange(h))
    rc = grid.raster_cols(gc0 + np.arange(w))
    vr = np.flatnonzero(rr >= 0)
    vc = np.flatnonzero(rc >= 0)
    if vr.size == 0 or vc.size == 0:
        return np.full((h, w), np.nan, dtype=np.float32)
    i0, i1 = int(vr[0]), int(vr[-1]) + 1
    r_a = int(rr[i0])
    # NaN only where no read writes: the rows outside [i0, i1) and the columns outside the
    # runs (a read writes every node of its ``out``), not the whole window first.
    out = np.empty((h, w), dtype=np.float32)
    out[:i0] = np.nan
    out[i1:] = np.nan
    col = 0
    for p, c, n in _runs(vc, rc[vc]):
        out[i0:i1, col:p] = np.nan
        col = p + n
        # Straight into the window (rasterio's read takes a strided ``out`` too).
        ds.read(1, window=Window(c, r_a, n, i1 - i0), out=out[i0:i1, p : p + n])
    out[i0:i1, col:] = np.nan
    if mirror:
        _mirror_axis(out, rr, grid.height, mirror, axis=0)
        if not grid.global_lon:
            _mirror_axis(out, rc, grid.width, mirror, axis=1)
    return out


def _mirror_axis(out: np.ndarray, idx: np.ndarray, size: int, k: int, axis: int) -> None:
    """Odd-mirror fill of up to k positions beyond the raster edges along one axis (in place)."""
    a = out if axis == 0 else out.T
    valid = np.flatnonzero(idx >= 0)
    first, last = int(valid[0]), int(valid[-1])
    if idx[first] == 0 and first > 0:
        m = min(k, first, last - first)
        if m > 0:
            a[first - m : first] = 2.0 * a[first] - a[first + 1 : first + m + 1][::-1]
    if idx[last] == size - 1 and last < a.shape[0] - 1:
        m = min(k, a.shape[0] - 1 - last, last - first)
        if m > 0:
            a[last + 1 : last + m + 1] = 2.0 * a[last] - a[last - m : last][::-1]
