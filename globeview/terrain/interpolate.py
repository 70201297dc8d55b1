"""Interpolation on regular node grids, shared by the DEM reader, the store's readers and the
composition: bilinear at fractional node positions, the linear weights it uses along one
axis, and a descendant tile's nodes upsampled from an ancestor's (exactly its bilinear
surface).

Grid positions are in nodes (row 0, column 0 = the first node); NaN propagates as numpy's
arithmetic has it (a corner of weight 0 included). Pure numpy.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["bilinear", "interp_axis", "linear_weights", "upsample_subtile"]


def bilinear(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a 2-D grid at fractional (row, col) node positions."""
    nr, nc = grid.shape
    r = np.clip(rows, 0.0, nr - 1.0)
    c = np.clip(cols, 0.0, nc - 1.0)
    r0 = np.minimum(np.floor(r).astype(np.int64), nr - 2)
    c0 = np.minimum(np.floor(c).astype(np.int64), nc - 2)
    fr = r - r0
    fc = c - c0
    # Gather the corners, then widen them: not the whole grid (it may be a large raster).
    f64 = np.float64
    top = grid[r0, c0].astype(f64) * (1 - fc) + grid[r0, c0 + 1].astype(f64) * fc
    bot = grid[r0 + 1, c0].astype(f64) * (1 - fc) + grid[r0 + 1, c0 + 1].astype(f64) * fc
    return top * (1 - fr) + bot * fr


def upsample_subtile(anc: np.ndarray, f: int, dx: int, dy: int) -> np.ndarray:
    """The nodes of a descendant tile ``f`` levels below ``anc``, offset (dx, dy) tiles inside
    it, interpolated bilinearly from the ancestor's grid (exactly its bilinear surface)."""
    size = anc.shape[0]
    cells = size - 1
    scale = 2**f
    t = np.arange(size, dtype=np.float64)
    cols = (dx * cells + t) / scale
    rows = (dy * cells + t) / scale
    if not np.isnan(anc).any():
        # Bilinear is separable: two small matrix products instead of 4 gathers per node,
        # over the window of ancestor nodes the tile spans (2^-f of it; the weights outside
        # are 0, so the products are the same sums), with the weights cached per offset.
        r0, wr = _window_weights(size, f, dy)
        c0, wc = _window_weights(size, f, dx)
        sub = anc[r0 : r0 + wr.shape[1], c0 : c0 + wc.shape[1]].astype(np.float64)
        return (wr @ sub @ wc.T).astype(np.float32)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    return bilinear(anc, rr.reshape(-1), cc.reshape(-1)).reshape(size, size).astype(np.float32)


@functools.lru_cache(maxsize=2048)
def _window_weights(size: int, f: int, d: int) -> tuple[int, np.ndarray]:
    """(first node, (size, k) weights): `linear_weights` along one axis of a descendant
    ``f`` levels below a (size, size) ancestor at tile offset ``d``, cut to the k ancestor
    nodes with a non-zero column. Read-only (shared by the cache)."""
    cells = size - 1
    pos = (d * cells + np.arange(size, dtype=np.float64)) / 2**f
    m = linear_weights(pos, size)
    used = np.nonzero(m.any(axis=0))[0]
    lo, hi = int(used[0]), int(used[-1]) + 1
    w = np.ascontiguousarray(m[:, lo:hi])
    w.flags.writeable = False
    return lo, w


def linear_weights(pos: np.ndarray, n: int) -> np.ndarray:
    """(len(pos), n) matrix of linear interpolation weights at fractional node positions
    (clamped to 0..n-1), as `bilinear` uses along one axis."""
    p = np.clip(pos, 0.0, n - 1.0)
    i0 = np.minimum(np.floor(p).astype(np.int64), n - 2)
    fr = p - i0
    m = np.zeros((len(p), n))
    rows = np.arange(len(p))
    m[rows, i0] = 1.0 - fr
    m[rows, i0 + 1] += fr
    return m


def interp_axis(values: np.ndarray, pos: np.ndarray, axis: int) -> np.ndarray:
    """Linear interpolation of ``values`` along ``axis`` at fractional node positions (clamped
    to 0..n-1): the product with `linear_weights` (``linear_weights(pos, n) @ values`` for axis
    0), done by gathering each position's two neighbouring nodes. That costs O(output), where
    the dense weight matrix costs O(output x n): seconds for a layer-sized raster (issue #28).
    Float64 out; NaN in a neighbour of weight 0 does not propagate (it does in the product)."""
    n = values.shape[axis]
    p = np.clip(np.asarray(pos, dtype=np.float64), 0.0, n - 1.0)
    i0 = np.minimum(np.floor(p).astype(np.int64), n - 2)
    shape = [1] * values.ndim
    shape[axis] = len(p)
    fr = (p - i0).reshape(shape)
    lo = np.take(values, i0, axis=axis).astype(np.float64)
    hi = np.take(values, i0 + 1, axis=axis).astype(np.float64)
    return lo * (1.0 - fr) + hi * fr
