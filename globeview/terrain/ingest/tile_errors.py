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
    "block_node_max",
    "block_node_min",
    "cell_max",
    "cell_min",
    "interp_axis",
    "lerp_rows",
    "reduce_cells",
    "round_sig_down",
    "round_sig_up",
    "segment_starts",
    "stride_deltas",
    "tile_min_max",
    "transposed_nodes",
    "upsample_nodes",
    "upsample_window",
    "upsampled_error_tiles",
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


# -- fast paths -------------------------------------------------------------------------------
#
# The functions below compute the same numbers as the gather-based ones above, bit for bit
# (tests/terrain/test_tile_errors.py pins them against those on random data with NaNs), with
# fewer passes over memory:
# - the upsampling reads the coarse rows/columns as strided slices, one phase of the fine grid
#   (fine position mod f) at a time, instead of gathering them with ``take``: each fine value
#   is still ``lo * (1 - t) + hi * t`` with the same operands and the same weights, so the
#   float result cannot change (no reassociation; a phase-0 node still uses ``hi = lo``);
# - the maxima skip ``cell_max``: a closed block of cells sees exactly the nodes of the closed
#   block, so max over its cells of (max over each cell's corners) is the max over those nodes
#   (a set identity; fmax is exact and order-free on the |differences|, which hold no -0, and
#   a block is NaN iff all its nodes are; heights may hold -0: see ``tile_min_max``);
# - the error pass works on the window transposed (each fine column is then two coarse
#   columns times scalar weights, numpy's fast vector-by-scalar loop) in strips that stay in
#   the CPU cache; long coarse intervals use single-product ``np.einsum`` outer products. Only
#   single products: a sum of two products inside one einsum may be fused into an FMA (one
#   rounding instead of two), which would change last bits.
#
# Measured per 1025^2 window of the 8192^2 benchmark DEM (benchmarks/bench_ingest_kernels.py):
# errors against 14 coarser levels 180 -> 46 ms CPU, hmin/hmax + stride deltas 41 -> 13 ms.


def _phase_weights(f: int, dtype: type) -> tuple[np.ndarray, np.ndarray]:
    """(1 - t, t) for every phase k of a factor-f grid, computed like ``interp_axis``."""
    t = np.arange(f).astype(dtype) / f
    return 1.0 - t, t


def lerp_rows(
    a: np.ndarray,
    f: int,
    off: int,
    out: np.ndarray,
    no_inf: bool = False,
    zero_sign_free: bool = False,
    scratch: np.ndarray | None = None,
) -> np.ndarray:
    """Linear interpolation along axis 0: ``out[j] = interp_axis(a, off + j, f, 0)`` rows.

    ``a`` (coarse rows, any trailing shape) is sampled at fine positions off .. off+n-1 with
    coarse row i at fine position i*f; ``out`` (n, ...) receives the values in its dtype
    (float64 or float32, as ``interp_axis``'s ``dtype``). Loops over the phases of the fine
    grid (f slices) or over the coarse intervals, whichever is fewer, so never more than about
    sqrt(n) vectorised steps. Pass transposed views to interpolate along columns.

    ``no_inf``: the caller knows ``a`` holds no +-inf (NaN is fine). Then a phase-0 node is a
    plain copy of its coarse node: for finite x, x*1 == x, x*0 is a zero with x's sign and
    x + that zero == x (also for -0); NaN stays NaN. Only inf differs (inf + inf*0 = NaN).

    ``zero_sign_free``: the caller only uses |value - something| (the sign of a zero result
    cannot matter: +-0 - y is -y for y != 0 and |+-0 - +-0| is +0). Then the outer products of
    long coarse intervals go through ``np.einsum`` (2x faster than a broadcast multiply); it
    forms the same rounded products but may turn a -0 product into +0, and x + (+-0) == x for
    x != 0, so only the sign of an all-zero sum can change.

    ``scratch``: optional buffer of ``out``'s shape and dtype for the second product (saves an
    allocation per step).
    """
    n = out.shape[0]
    if n == 0:
        return out
    dt = out.dtype.type
    w0, w1 = _phase_weights(f, dt)
    first, last = off // f, (off + n - 1) // f
    if f <= last - first + 1:
        for k in range(f):
            j0 = (k - off) % f
            if j0 >= n:
                continue
            cnt = (n - 1 - j0) // f + 1
            i0 = (off + j0) // f
            lo = a[i0 : i0 + cnt]
            o = out[j0::f]
            if k == 0 and no_inf:
                np.copyto(o, lo)
                continue
            hi = a[i0 + 1 : i0 + 1 + cnt] if k else lo
            np.multiply(lo, w0[k], out=o)
            if scratch is None:
                o += hi * w1[k]
            else:
                o += np.multiply(hi, w1[k], out=scratch[:cnt])
        return out
    outer = zero_sign_free and a.ndim == 2
    for i in range(first, last + 1):
        ja, jb = max(0, i * f - off), min(n, (i + 1) * f - off)
        ka = ja + off - i * f
        lo = a[i]
        if ka == 0:
            # Phase 0: the node sits on coarse node i (weight 0 on a duplicate, as before).
            if no_inf:
                out[ja] = lo
            else:
                np.multiply(lo, w0[0], out=out[ja])
                out[ja] += lo * w1[0]
            ja, ka = ja + 1, 1
        if jb <= ja:
            continue
        kb = ka + jb - ja
        o = out[ja:jb]
        if outer:
            np.einsum("i,j->ij", w0[ka:kb], lo, out=o, optimize=False)
            t = None if scratch is None else scratch[: jb - ja]
            o += np.einsum("i,j->ij", w1[ka:kb], a[i + 1], out=t, optimize=False)
        else:
            shape = (kb - ka,) + (1,) * (a.ndim - 1)
            np.multiply(lo, w0[ka:kb].reshape(shape), out=o)
            o += a[i + 1] * w1[ka:kb].reshape(shape)
    return out


def upsample_window(
    coarse: np.ndarray, f: int, r_off: int, c_off: int, h: int, w: int, dtype: type = np.float64
) -> np.ndarray:
    """``upsample_nodes(coarse, f, r_off + arange(h), c_off + arange(w), dtype)``, without
    gathers (rows first on the coarse columns, then columns: the same order)."""
    if f == 1:
        return coarse[r_off : r_off + h, c_off : c_off + w].astype(dtype)
    # Finite nodes interpolate to finite values: w0 + w1 == 1 and rounding is monotone, so
    # |lo*w0 + hi*w1| <= max(|lo|, |hi|) in either float type.
    no_inf = not np.isinf(coarse).any()
    tmp = lerp_rows(coarse, f, r_off, np.empty((h, coarse.shape[1]), dtype), no_inf)
    out: np.ndarray = np.empty((h, w), dtype)
    lerp_rows(tmp.T, f, c_off, out.T, no_inf)
    return out


def _block_reduce(d: np.ndarray, b: int, op: np.ufunc) -> np.ndarray:
    m, n = (d.shape[0] - 1) // b, (d.shape[1] - 1) // b
    r = op(op.reduce(d[:-1].reshape(m, b, d.shape[1]), axis=1), d[b::b])
    return op(op.reduce(r[:, :-1].reshape(m, n, b), axis=2), r[:, b::b])


def block_node_max(d: np.ndarray, b: int) -> np.ndarray:
    """(m*b+1, n*b+1) nodes -> (m, n) NaN-ignoring max over each closed b x b block of cells
    (its (b+1)^2 nodes); equals reducing ``cell_max(d)`` over the blocks."""
    return _block_reduce(d, b, np.fmax)


def block_node_min(d: np.ndarray, b: int) -> np.ndarray:
    """As ``block_node_max`` with the minimum (``cell_min`` reduced over the blocks)."""
    return _block_reduce(d, b, np.fmin)


def tile_min_max(arr: np.ndarray, s_n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-tile (min, max) of a closed, tile-aligned node window (tiles of s_n cells), bit for
    bit ``cell_min``/``cell_max`` reduced per tile (ingest's hmin/hmax).

    The extremum of a set of floats is one value whatever the order, except that fmin/fmax
    may return either zero of a {+0, -0} pair. So where a tile's extremum is a zero and the
    window holds a -0 (rare: levels are sums that start at +0), the reference order is used.
    """
    lo, hi = block_node_min(arr, s_n), block_node_max(arr, s_n)
    if ((lo == 0.0) | (hi == 0.0)).any() and np.signbit(arr[arr == 0.0]).any():
        kty, ktx = lo.shape

        def per_tile(cells: np.ndarray, op: np.ufunc) -> np.ndarray:
            return op.reduce(op.reduce(cells.reshape(kty, s_n, ktx, s_n), axis=3), axis=1)

        lo, hi = per_tile(cell_min(arr), np.fmin), per_tile(cell_max(arr), np.fmax)
    return lo, hi


def stride_deltas(
    arr: np.ndarray, s_n: int, strides: tuple[int, ...], strip: int = 64
) -> np.ndarray:
    """Running max over strides of per-tile max |S_s - S_1| (see ingest's ``_tile_stats``).

    ``arr``: a closed, tile-aligned float32 node window (tiles of s_n cells). Returns
    (kty, ktx, len(strides)) float64: entry i is the max over strides[:i+1] that are <= s_n of
    the tile's max |bilinear of every s-th node - the node|, NaN-free (0 where no data); a
    stride coarser than the tile repeats the previous entry. Computed in float32 like the
    original loop (upsample_nodes(..., np.float32), cell_max, per-tile fmax).
    """
    kty, ktx = (arr.shape[0] - 1) // s_n, (arr.shape[1] - 1) // s_n
    out = np.zeros((kty, ktx, len(strides)), dtype=np.float64)
    delta = np.zeros((kty, ktx), dtype=np.float64)
    a = np.asarray(arr, dtype=np.float32)
    arr_t = np.ascontiguousarray(a.T)
    for i, s in enumerate(strides):
        if s <= s_n:
            blocks = _abs_diff_block_max(a[::s, ::s], arr_t, s, 0, 0, s_n, strip)
            delta = np.maximum(delta, np.nan_to_num(blocks, nan=0.0))
        out[:, :, i] = delta
    return out


def transposed_nodes(fine: np.ndarray) -> np.ndarray:
    """A fine node window as ``upsampled_error_tiles`` takes it: transposed, C-contiguous
    float64 (exact: float32 -> float64 is lossless). Make it once per window and pass it for
    every coarser level."""
    return np.ascontiguousarray(np.asarray(fine).T, dtype=np.float64)


def _abs_diff_block_max(
    coarse: np.ndarray, fine_t: np.ndarray, f: int, r_off: int, c_off: int, b: int, strip: int
) -> np.ndarray:
    """(m, n) max over closed b x b cell blocks of |upsample(coarse) - fine| at the nodes, in
    ``fine_t``'s dtype (the upsampling's dtype); ``fine_t`` is the (w, h) transposed window."""
    w, h = fine_t.shape
    m, n = (h - 1) // b, (w - 1) // b
    dt = fine_t.dtype
    # Rows first on the few coarse columns (as upsample_nodes), once for the window; then
    # stored transposed: tmp_t[i] is coarse column i interpolated at the h fine rows.
    c = coarse.astype(dt)
    no_inf = not np.isinf(c).any()
    tmp = lerp_rows(c, f, r_off, np.empty((h, coarse.shape[1]), dt), no_inf)
    tmp_t = np.ascontiguousarray(tmp.T)
    per = max(1, strip // b)  # block columns per strip
    cols = np.empty((n, h), dtype=dt)  # per block column: max over its node columns
    buf = np.empty((per * b + 1, h), dtype=dt)
    scratch = np.empty_like(buf)
    for p0 in range(0, n, per):
        p1 = min(n, p0 + per)
        a0, a1 = p0 * b, p1 * b + 1
        up = lerp_rows(tmp_t, f, c_off + a0, buf[: a1 - a0], no_inf, True, scratch)
        np.subtract(up, fine_t[a0:a1], out=up)
        np.abs(up, out=up)
        k = p1 - p0
        np.fmax(np.fmax.reduce(up[:-1].reshape(k, b, h), axis=1), up[b::b], out=cols[p0:p1])
    blocks_t = np.fmax(np.fmax.reduce(cols[:, :-1].reshape(n, m, b), axis=2), cols[:, b::b])
    return blocks_t.T


def upsampled_error_tiles(
    coarse: np.ndarray,
    fine_t: np.ndarray,
    f: int,
    r_off: int,
    c_off: int,
    cell_r0: int,
    cell_c0: int,
    tile_span: int,
    block: int,
    owned: np.ndarray | None = None,
    strip_cols: int = 64,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per coarse tile, max |bilinear(coarse) - fine| over the fine window's cells (metres).

    The fast equal (bit for bit) of::

        up = upsample_nodes(coarse, f, r_off + arange(h), c_off + arange(w))   # float64
        cells = cell_max(abs(up - fine.astype(float64)))
        cells[~owned_cells] = nan                       # owned: per block of block^2 cells
        reduce_cells(cells, (cell_r0 + arange(h-1)) // tile_span,
                     (cell_c0 + arange(w-1)) // tile_span)

    ``fine_t``: the (h, w) fine nodes as ``transposed_nodes(fine)`` (w, h), with h-1, w-1
    multiples of ``block``; ``cell_r0``/``cell_c0``: global cell indices of the window's first
    cell, multiples of ``block`` like ``tile_span`` (tiles are whole blocks); ``owned``:
    ((h-1)//block, (w-1)//block) bool, False for blocks judged elsewhere, or None. Returns
    (tile rows, tile cols, (ntr, ntc) float64 maxima, NaN where no owned node has data), as
    ``reduce_cells``.

    Why transposed: the column pass (the big one, every fine node) computes each fine column
    as two coarse-grid columns times scalar weights; with columns stored as contiguous rows
    that is numpy's fast vector-times-scalar loop, where the untransposed layout needs a
    strided write or a broadcast along the contiguous axis (2-4x slower). The window is
    processed in strips of about ``strip_cols`` fine columns so the float64 temporaries stay
    in the CPU cache.
    """
    w, h = fine_t.shape
    b = block
    m, n = (h - 1) // b, (w - 1) // b
    if m * b != h - 1 or n * b != w - 1 or cell_r0 % b or cell_c0 % b or tile_span % b:
        raise ValueError("window, origin and tile span must be whole blocks")
    blocks = _abs_diff_block_max(coarse, fine_t, f, r_off, c_off, b, strip_cols)
    if owned is not None:
        blocks = np.where(owned, blocks, np.nan)
    return reduce_cells(
        blocks, (cell_r0 + np.arange(m) * b) // tile_span, (cell_c0 + np.arange(n) * b) // tile_span
    )


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
