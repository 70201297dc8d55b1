"""Grid arithmetic for tile statistics: bilinear upsampling on nested node grids and per-tile
maxima over cells.

Why node-based maxima are exact: a coarse tile drawn as a bilinear surface and the fine data
drawn as a bilinear surface on a nested (finer) node grid differ by a function that is bilinear
inside every fine cell, so its absolute maximum over a cell sits at one of the cell's four
corner nodes. The max over a tile is therefore the max over the fine nodes of the tile, and we
get it by (1) upsampling the coarse nodes to the fine nodes with fixed linear weights per axis,
(2) taking |difference| at the nodes, (3) reducing each cell to the max of its corners, (4)
reducing the cells of each tile. Step (3) makes every closed tile (edges shared with its
neighbours) see all of its nodes while the cells partition the plane.

Arrays are (rows, cols) = (south-going, east-going) node grids; heights in metres. NaN is "no
data" and is ignored by the maxima (np.fmax), i.e. comparisons use valid nodes only.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "cell_max",
    "cell_min",
    "interp_axis",
    "reduce_cells",
    "round_sig_down",
    "round_sig_up",
    "segment_starts",
    "upsample_nodes",
]


def interp_axis(
    a: np.ndarray, q: np.ndarray, f: int, axis: int, dtype: type = np.float64
) -> np.ndarray:
    """Linear interpolation of ``a`` along ``axis`` at fine positions ``q`` (int array).

    Coarse node i sits at fine position i*f, so fine position q lies between coarse nodes
    q // f and q // f + 1 with weight t = (q % f) / f on the second. Where t == 0 the second
    index is the first one (weight 0 on a duplicate), so a NaN neighbour never leaks into a
    node that coincides with a valid coarse node.
    """
    i = q // f
    t = (q % f).astype(dtype) / f
    i1 = np.where(t > 0, i + 1, i)
    shape = [1, 1]
    shape[axis] = -1
    t = t.reshape(shape)
    lo: np.ndarray = np.take(a, i, axis=axis).astype(dtype, copy=False)
    hi: np.ndarray = np.take(a, i1, axis=axis).astype(dtype, copy=False)
    lo *= 1.0 - t
    hi *= t
    lo += hi
    return lo


def upsample_nodes(
    coarse: np.ndarray, f: int, rows: np.ndarray, cols: np.ndarray, dtype: type = np.float64
) -> np.ndarray:
    """Bilinear values of a coarse node grid at fine nodes (rows x cols), separable.

    ``rows``/``cols`` are fine positions relative to coarse node (0, 0) (coarse node (j, i) is
    fine node (j*f, i*f)). Rows are interpolated first on the few coarse columns, then columns
    on the full fine grid.
    """
    if f == 1:
        return coarse[np.ix_(rows, cols)].astype(dtype)
    tmp = interp_axis(coarse, rows, f, 0, dtype)
    return interp_axis(tmp, cols, f, 1, dtype)


def cell_max(d: np.ndarray) -> np.ndarray:
    """(h, w) node values -> (h-1, w-1) max over each cell's four corners, NaN-ignoring."""
    a = np.fmax(d[:, :-1], d[:, 1:])
    return np.fmax(a[:-1], a[1:])


def cell_min(d: np.ndarray) -> np.ndarray:
    """(h, w) node values -> (h-1, w-1) min over each cell's four corners, NaN-ignoring."""
    a = np.fmin(d[:, :-1], d[:, 1:])
    return np.fmin(a[:-1], a[1:])


def segment_starts(group: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start offsets of runs of equal values in a non-decreasing int array, and their values."""
    starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
    return starts, group[starts]


def reduce_cells(
    cells: np.ndarray, row_group: np.ndarray, col_group: np.ndarray, op: np.ufunc = np.fmax
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reduce cells into tiles: ``row_group``/``col_group`` give each cell row/col its tile
    index (non-decreasing). Returns (tile rows, tile cols, reduced (ntr, ntc))."""
    rs, rv = segment_starts(row_group)
    cs, cv = segment_starts(col_group)
    # Columns first (contiguous rows), then rows on the narrow result; a single segment is a
    # plain reduction, much faster than reduceat.
    a = op.reduce(cells, axis=1, keepdims=True) if cs.size == 1 else op.reduceat(cells, cs, axis=1)
    a = op.reduce(a, axis=0, keepdims=True) if rs.size == 1 else op.reduceat(a, rs, axis=0)
    return rv, cv, a


def round_sig_up(v: np.ndarray, digits: int = 6) -> np.ndarray:
    """Round towards +inf to ``digits`` significant digits (short JSON, still an upper bound).

    A relative margin of a few 1e-7 absorbs the float rounding of the decimal result.
    """
    return _round_sig(v * (1.0 + 4e-7 * np.sign(v)), digits, np.ceil)


def round_sig_down(v: np.ndarray, digits: int = 6) -> np.ndarray:
    """Round towards -inf to ``digits`` significant digits (for lower bounds such as hmin)."""
    return _round_sig(v * (1.0 - 4e-7 * np.sign(v)), digits, np.floor)


def _round_sig(v: np.ndarray, digits: int, fn: np.ufunc) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        mag = np.floor(np.log10(np.abs(v)))
        mag = np.where(np.isfinite(mag), mag, 0.0)
        scale = 10.0 ** (digits - 1 - mag)
        out = fn(v * scale) / scale
    return np.where(np.isfinite(v), out, v)
