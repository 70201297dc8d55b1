"""GDAL's bilinear warp between two lon/lat grids, as two separable passes (issue #25, C1).

`Dem.read_grid_parts` samples a source onto a level's nodes with GDAL's bilinear warp
(`rasterio.warp.reproject`). Between a north-up lon/lat raster and a lon/lat node grid the
source coordinates of a node are separable (its source column depends on its longitude only,
its source row on its latitude only), so GDAL's 2-D kernel factors into a pass along the rows
and a pass along the columns over precomputed (index, weight) taps: 3-4x less CPU than the
warp on the ingest's 1025^2 windows (`benchmarks/bench_ingest_kernels.py`).

What GDAL computes (GDALWarpKernel, bilinear; rasterio 1.4 / GDAL 3.10 here): the destination
pixel whose centre falls at source pixel coordinates (X, Y) (pixel k spans [k, k + 1], its
sample at the centre) gets the weighted mean of the source pixels around it, weights
tri(dx * sx) * tri(dy * sy), tri(u) = max(0, 1 - |u|), dx and dy the distances in source
pixels from the pixel centres to (X, Y). An axis's scale s is the destination/source pixel
size ratio where that is below 1 (downsampling widens the triangle to the destination pixel),
else 1; a reciprocal within 0.05 of an integer n is snapped to 1/n, and when both scales are
at least 0.95 the 4-sample formula (s = 1) is used. Pixels off the raster or invalid (NaN)
are left out and the remaining weights renormalised (except that the general kernel leaves a
weight sum within 1e-5 of 1 undivided); a destination pixel gets no value (NaN) when its
centre is off the raster or the source pixel under it is invalid. The double result is rounded
to float32.

The one departure from plain GDAL: the scale s. GDAL takes it from each warp piece's own
source window, which is clipped at the raster's end (and GDAL cuts a destination mostly off
the raster into pieces, `warp_chunks`), so near a raster's end the kernel narrows, piece by
piece: two ingest chunks sharing a row of nodes (each chunk stores its closing row and
column) gave that row different heights, by up to 23.6 m at level 10 (52 m at level 9) on
the 512^2 benchmark DEM (benchmarks/cache/big_dem_512.tif), 1.6 m on N44W072 at level 11.
Here s comes from the grids instead (`grid_scales`: the source's pixel size over the node
spacing, constant for a source and a level), for every piece of every window: a node gets
the same height from any window (to the last bit of float32, its pixel coordinate being
formed in each window's frame; tests/terrain/test_resample.py). GDAL computes exactly this
when given the scales as its XSCALE / YSCALE warp options (documented as a fixed resampling
factor for output reproducible across processing chunks), which `Dem._warp` passes on its
general (projected) path too. The pieces still decide where GDAL gives no value and where its
approximate transformer is exact. Against plain GDAL, measured on `Dem.read_grid_parts`
windows: nodes whose window lies inside the raster are unchanged (N44W072 at level 12, an
ingest chunk over the whole tile: at most 1 ulp; ETOPO 20', Crater Lake at levels 12 and 14,
Vancouver); where a window reaches past the raster, the nodes near its end move by up to
7.5 m (N44W072, level 10, 3.3x downsampled), 10.2 m (Crater Lake, level 13) and 45 m (the
512^2 benchmark DEM's level-9 and -10 chunks): there plain GDAL's kernel was narrower than
the one the same node got from a window inside the raster.

Here: the same weights (formed as GDAL forms them), the sums in float64, the renormalisation
as num / den (num: the passes over the values, 0 where invalid; den: over the validity; the
2-D renormalisation exactly, as the weights are products), rounded once to float32. A value
differs from GDAL's (given the same XSCALE / YSCALE) only by the order of the float64 sums
before that rounding: at most 1 ulp of float32 (0.49 mm below 8 192 m, 0.98 mm up to
16 384 m) plus ~1e-15 of the window's largest |height| where a sum cancels
(tests/terrain/test_resample.py, on real data and on synthetic rasters with NaN holes and
edges, every ratio).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from affine import Affine

__all__ = [
    "AxisTaps",
    "WarpChunk",
    "axis_taps",
    "grid_scales",
    "kernel_scales",
    "resample_bilinear",
    "warp_chunks",
]

#: GDAL's tolerance on a pixel coordinate when it picks the source pixel under a node.
_PIXEL_EPS = 1e-10
#: GDAL's general kernel leaves a weight sum in [0.99999, 1.00001] undivided.
_SUM_LOW, _SUM_HIGH = 0.99999, 1.00001


def _snapped(scale: float) -> float:
    """GDAL's scale of an axis (dst/src pixel size) clamped to 1 and snapped: a reciprocal
    within 0.05 of an integer n becomes 1/n (GDALWarpKernel::PerformWarp)."""
    if scale >= 1.0:
        return 1.0
    reciprocal = 1.0 / scale
    n = int(reciprocal + 0.5)
    return 1.0 / n if abs(reciprocal - n) < 0.05 else scale


@dataclass(frozen=True)
class _AxisWindow:
    """GDALWarpOperation::ComputeSourceWindow along one axis of a destination chunk: the
    source window (off, size, pixels), the source pixels its edges span counted up to the
    raster's end (``raw``, the kernel's scale is n_dst / raw) and its padded extent (for the
    fill ratio)."""

    off: int
    size: int
    raw: float
    padded: float


def _close_to_integer(v: float) -> float:
    """GDAL rounds a source window edge within 1e-6 of an integer to it."""
    r = float(round(v))
    return r if abs(r - v) < 1e-6 else v


def _axis_window(lo: float, hi: float, n_dst: int, n_src: int) -> _AxisWindow | None:
    """The source window of destination pixels whose outer edges are at source pixel
    coordinates lo < hi, on an axis of n_src pixels; None when they miss the raster."""
    lo, hi = _close_to_integer(float(lo)), _close_to_integer(float(hi))
    if lo > n_src or hi < 0.0:
        return None
    scale = max(1e-3, n_dst / (hi - lo))
    radius = math.ceil(1.0 / scale) if scale < 0.95 else 1  # bilinear: filter radius 1
    lo_c = int(max(0.0, lo))
    hi_c = int(min(math.ceil(hi), n_src))
    raw = max(0.0, min(float(n_src - lo_c), hi - lo))
    # (Later GDAL versions take the whole axis where the window covers 90 % of it; GDAL
    # 3.10, which rasterio 1.4 ships, does not: tests/terrain/test_resample.py.)
    off = max(0, min(lo_c - radius, n_src))
    size = max(0, min(n_src - off, hi_c - off + radius))
    return _AxisWindow(off, size, raw, hi - lo + 2 * radius)


@dataclass(frozen=True)
class WarpChunk:
    """A destination rectangle GDAL warps as one piece (rows row0:row1, columns col0:col1),
    with its kernel scales (`kernel_scales`), or ``scales`` None when it has no source."""

    row0: int
    row1: int
    col0: int
    col1: int
    scales: tuple[float, float] | None


#: GDAL's default warp memory (rasterio passes none) and the bits a float32 pixel with a
#: nodata mask costs in it, source and destination alike (CollectChunkListInternal).
_WARP_MEMORY_BYTES = 64.0 * 1024 * 1024
_PIXEL_BITS = 33


def warp_chunks(
    x_edges: tuple[float, float], y_edges: tuple[float, float], shape: tuple[int, int],
    src_shape: tuple[int, int],
) -> list[WarpChunk]:  # fmt: skip
    """The pieces GDAL cuts a warp into (GDALWarpOperation::CollectChunkListInternal), for a
    destination of ``shape`` (rows, cols) whose column edge k lies at source pixel coordinate
    x_edges[0] + k * x_edges[1] (rows likewise), on a source raster of ``src_shape``.

    GDAL halves a destination (the longer side) while its source window would exceed the
    warp memory, or while less than half of the source window it would need (padded by the
    kernel) is on the raster and the destination is over 100 pixels on a side. Each piece
    then gets its own scale from its own source window, clipped at the raster's end: where
    a piece reaches past the raster, its kernel is narrower (`WarpChunk.scales`: plain
    GDAL's). `resample_bilinear` keeps the pieces (where there is no value, where the
    approximate transformer is exact) but not their scales (the module docstring says why).
    """
    out: list[WarpChunk] = []
    h, w = src_shape

    def collect(r0: int, nr: int, c0: int, nc: int) -> None:
        xw = _axis_window(x_edges[0] + c0 * x_edges[1], x_edges[0] + (c0 + nc) * x_edges[1], nc, w)
        yw = _axis_window(y_edges[0] + r0 * y_edges[1], y_edges[0] + (r0 + nr) * y_edges[1], nr, h)
        if xw is None or yw is None:
            out.append(WarpChunk(r0, r0 + nr, c0, c0 + nc, None))
            return
        fill = xw.size * yw.size / max(1.0, xw.padded * yw.padded)
        memory = _PIXEL_BITS * (xw.size * yw.size + nr * nc) / 8.0
        if (memory > _WARP_MEMORY_BYTES and (nc > 2 or nr > 2)) or (
            0.0 < fill < 0.5 and (nc > 100 or nr > 100)
        ):
            if nc > nr:
                collect(r0, nr, c0, nc // 2)
                collect(r0, nr, c0 + nc // 2, nc - nc // 2)
            else:
                collect(r0, nr // 2, c0, nc)
                collect(r0 + nr // 2, nr - nr // 2, c0, nc)
            return
        if xw.size == 0 or yw.size == 0:
            out.append(WarpChunk(r0, r0 + nr, c0, c0 + nc, None))
            return
        sx = nc / xw.raw if xw.raw > 0.0 else math.inf
        sy = nr / yw.raw if yw.raw > 0.0 else math.inf
        out.append(WarpChunk(r0, r0 + nr, c0, c0 + nc, kernel_scales(sx, sy)))

    collect(0, shape[0], 0, shape[1])
    return out


def kernel_scales(scale_x: float, scale_y: float) -> tuple[float, float]:
    """GDAL's kernel scales (sx, sy) from the axes' destination/source pixel size ratios
    (`window_scale`): 1 on an axis that is not downsampled, and on both when both are at
    least 0.95 (the 4-sample formula)."""
    sx, sy = _snapped(scale_x), _snapped(scale_y)
    if sx >= 0.95 and sy >= 0.95:
        return 1.0, 1.0
    return sx, sy


@dataclass(frozen=True)
class AxisTaps:
    """The taps of one axis: node i takes source pixels ``index[i]`` with weights
    ``weight[i]`` (float64, 0 for pixels off the raster; not normalised); ``centre[i]`` is
    the source pixel under the node (clamped into the raster) and ``inside[i]`` whether GDAL
    samples the node at all (its centre on the raster)."""

    index: np.ndarray
    weight: np.ndarray
    centre: np.ndarray
    inside: np.ndarray


def axis_taps(x: np.ndarray, n_src: int, scale: float) -> AxisTaps:
    """Taps of the nodes at source pixel coordinates ``x`` (float64, pixel k spans
    [k, k + 1]) on an axis of ``n_src`` pixels, with the kernel scale ``scale``.

    GDAL weighs pixel iSrc + k, iSrc = floor(x - 0.5), by tri((k - delta) * scale) with
    delta = x - 0.5 - iSrc, for k within the kernel's radius 1 / scale; only the ceil(2 /
    scale) pixels nearest x can have a weight, so those are the taps (the same weights,
    formed the same way).
    """
    radius = 1.0 / scale
    count = math.ceil(2.0 * radius)
    i_src = np.floor(x - 0.5)
    delta = (x - 0.5) - i_src
    first = np.floor(x - 0.5 - radius) + 1.0  # the first pixel whose centre is within radius
    k = (first - i_src)[:, None] + np.arange(count)  # offsets from iSrc, small integers
    weight = np.maximum(0.0, 1.0 - np.abs(k - delta[:, None]) * scale)
    index = (i_src[:, None] + k).astype(np.int64)
    off = (index < 0) | (index >= n_src)
    weight[off] = 0.0
    np.clip(index, 0, n_src - 1, out=index)
    # GDAL: no value for a node left of the raster or past its end (with a 1e-10 pixel
    # tolerance); the pixel under it is trunc(x + 1e-10), the last one for x at the end.
    inside = (x >= 0.0) & (x + _PIXEL_EPS <= n_src)
    centre = np.clip(np.floor(x + _PIXEL_EPS), 0, n_src - 1).astype(np.int64)
    return AxisTaps(index, weight, centre, inside)


def _rows_pass(a: np.ndarray, taps: AxisTaps) -> np.ndarray:
    """out[i] = sum_t weight[i, t] * a[index[i, t]] (float64): whole source rows, gathered
    contiguously and scaled by one weight each."""
    out = np.multiply(a[taps.index[:, 0]], taps.weight[:, :1], dtype=np.float64)
    scratch = np.empty_like(out)
    for t in range(1, taps.index.shape[1]):
        out += np.multiply(a[taps.index[:, t]], taps.weight[:, t : t + 1], out=scratch)
    return out


def _columns_pass(a: np.ndarray, taps: AxisTaps) -> np.ndarray:
    """out[:, j] = sum_t weight[j, t] * a[:, index[j, t]] (float64)."""
    out = np.multiply(np.take(a, taps.index[:, 0], axis=1), taps.weight[:, 0])
    scratch = np.empty_like(out)
    for t in range(1, taps.index.shape[1]):
        np.take(a, taps.index[:, t], axis=1, out=scratch)
        scratch *= taps.weight[:, t]
        out += scratch
    return out


@dataclass(frozen=True)
class _DstToSrc:
    """Destination pixel -> source pixel coordinates of two north-up grids as GDAL's
    transformer forms them (GDALGenImgProjTransform without reprojection): the destination
    pixel to lon/lat by its geotransform, then to source pixels by the source's inverse
    geotransform (GDALInvGeoTransform: x = -c / a + lon * (1 / a)); so the same roundings."""

    src: Affine
    dst: Affine

    def rows(self, r0: int, r1: int) -> np.ndarray:
        """y of the centres of destination rows r0..r1-1 (a row's points share their y)."""
        lat = self.dst.f + (np.arange(r0, r1) + 0.5) * self.dst.e
        return -self.src.f / self.src.e + lat * (1.0 / self.src.e)

    def exact_columns(self, px: np.ndarray) -> np.ndarray:
        lon = self.dst.c + px * self.dst.a
        return -self.src.c / self.src.a + lon * (1.0 / self.src.a)

    def columns(self, c0: int, c1: int) -> np.ndarray:
        """x of the centres of destination columns c0..c1-1 of one warp piece, as GDAL's
        approximate transformer gives a scanline of it (rasterio's default, 0.125 pixel):
        exact at its first and last point, linear between (more than 5 points)."""
        px = np.arange(c0, c1) + 0.5
        if px.size <= 5:
            return self.exact_columns(px)
        first, last = self.exact_columns(px[[0, -1]])
        slope = (last - first) / (px[-1] - px[0])
        return first + slope * (px - px[0])

    def edges(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """((x of edge 0, x step), (y of edge 0, y step)) of the destination pixel edges."""
        x0 = float(self.exact_columns(np.array([0.0]))[0])
        y0 = -self.src.f / self.src.e + self.dst.f * (1.0 / self.src.e)
        return (x0, self.dst.a / self.src.a), (y0, self.dst.e / self.src.e)


def grid_scales(pixel: tuple[float, float], spacing: tuple[float, float]) -> tuple[float, float]:
    """The kernel scales (sx, sy) of a warp from the grids alone: the source's pixel size
    ``pixel`` over the destination's ``spacing`` (x, y; the same units, e.g. degrees), through
    GDAL's clamp, snap and 4-sample rule (`kernel_scales`). Constant for a source and a level,
    whatever the window: what GDAL's XSCALE / YSCALE warp options take."""
    return kernel_scales(abs(pixel[0] / spacing[0]), abs(pixel[1] / spacing[1]))


def resample_bilinear(
    arr: np.ndarray,
    src_transform: Affine,
    dst_transform: Affine,
    shape: tuple[int, int],
    scales: tuple[float, float] | None = None,
) -> np.ndarray:
    """GDAL's bilinear warp of ``arr`` (float32 heights, NaN = no data; pixel-is-area cells of
    ``src_transform``) onto the destination pixels of ``dst_transform`` (``shape`` = (rows,
    cols)), both north-up grids in the same lon/lat frame (degrees), with the kernel scales
    ``scales`` (default: `grid_scales` of the two transforms) for every pixel, as GDAL's warp
    given them as XSCALE / YSCALE: float32, NaN where GDAL gives no value. See the module
    docstring for the rule and how close to GDAL it is."""
    for t in (src_transform, dst_transform):
        if t.b != 0.0 or t.d != 0.0 or not (t.a > 0.0 and t.e < 0.0):
            raise ValueError(f"resample_bilinear needs north-up grids, not {tuple(t)[:6]}")
    if scales is None:
        scales = grid_scales((src_transform.a, src_transform.e), (dst_transform.a, dst_transform.e))
    to_src = _DstToSrc(src_transform, dst_transform)
    # GDAL's pieces still decide which pixels get no value (a piece without source) and
    # where its approximate transformer is exact; the kernel is the same in all of them.
    chunks = warp_chunks(*to_src.edges(), shape, arr.shape)
    valid = ~np.isnan(arr)
    result = np.full(shape, np.nan, dtype=np.float32)
    for c in chunks:
        if c.scales is not None:
            y, x = to_src.rows(c.row0, c.row1), to_src.columns(c.col0, c.col1)
            result[c.row0 : c.row1, c.col0 : c.col1] = _warp_block(arr, valid, y, x, scales)
    return result


def _warp_block(
    arr: np.ndarray,
    valid: np.ndarray,
    y: np.ndarray,
    x: np.ndarray,
    scales: tuple[float, float],
) -> np.ndarray:
    """One GDAL warp chunk: the destination pixels at source pixel coordinates y (rows) x x
    (columns) with the kernel scales (sx, sy); float32, NaN where GDAL gives no value."""
    sx, sy = scales
    h, w = arr.shape
    rt, ct = axis_taps(y, h, sy), axis_taps(x, w, sx)
    # Only the source columns the chunk's taps reach (a chunk may be a slice of the window).
    c_lo, c_hi = int(ct.index.min()), int(ct.index.max()) + 1
    ct = AxisTaps(ct.index - c_lo, ct.weight, ct.centre, ct.inside)
    a, ok = arr[:, c_lo:c_hi], valid[:, c_lo:c_hi]
    # GDAL's general kernel (not the 4-sample formula) divides by the sum of the weights only
    # where it is off 1 by more than 1e-5 (GWKResample); the 4-sample formula always does.
    keeps_sum = not (sx == 1.0 and sy == 1.0)
    rows_used = np.unique(rt.index)
    all_valid = bool(ok[rows_used].all())
    if all_valid:
        # No pixel to leave out: the weights of each axis normalised once (their products
        # are the 2-D weights normalised).
        out = _columns_pass(_rows_pass(a, _normalised(rt)), _normalised(ct))
        if keeps_sum:
            _undivide_near_one(out, rt.weight.sum(axis=1), ct.weight.sum(axis=1))
    else:
        num = _columns_pass(_rows_pass(np.where(ok, a, np.float32(0.0)), rt), ct)
        den = _columns_pass(_rows_pass(ok.astype(np.float32), rt), ct)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = num / den
        if keeps_sum:
            near_one = (den >= _SUM_LOW) & (den <= _SUM_HIGH)
            out[near_one] = num[near_one]
    block = out.astype(np.float32)
    sampled = rt.inside[:, None] & ct.inside[None, :]
    if not all_valid:
        sampled &= valid[np.ix_(rt.centre, ct.centre)]
    block[~sampled] = np.nan
    return block


def _undivide_near_one(out: np.ndarray, row_sums: np.ndarray, col_sums: np.ndarray) -> None:
    """Where the 2-D weight sum row_sums[i] * col_sums[j] is within GDAL's 1e-5 of 1, give
    ``out`` (normalised values) GDAL's undivided sum, in place. Rare (nodes whose taps are
    cut by the raster's end): the rows that have such a column are found by bisection."""
    order = np.sort(col_sums)
    with np.errstate(divide="ignore"):
        lo = np.searchsorted(order, _SUM_LOW / row_sums, side="left")
        hi = np.searchsorted(order, _SUM_HIGH / row_sums, side="right")
    for i in np.flatnonzero(hi > lo):
        total = row_sums[i] * col_sums
        near_one = (total >= _SUM_LOW) & (total <= _SUM_HIGH)
        out[i, near_one] *= total[near_one]


def _normalised(taps: AxisTaps) -> AxisTaps:
    total = taps.weight.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        weight = np.where(total > 0.0, taps.weight / total, 0.0)
    return AxisTaps(taps.index, weight, taps.centre, taps.inside)
