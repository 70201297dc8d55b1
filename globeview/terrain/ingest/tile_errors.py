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

import functools
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = [
    "PRUNE_BLOCK",
    "ErrorWindow",
    "block_node_max",
    "block_node_min",
    "cell_max",
    "cell_min",
    "data_blocks",
    "error_window",
    "interp_axis",
    "lerp_rows",
    "pruned_error_tiles",
    "reduce_cells",
    "round_sig_down",
    "round_sig_up",
    "segment_starts",
    "stride_deltas",
    "tile_min_max",
    "tile_stats",
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


#: Fine columns per strip of the stride-delta passes (`stride_deltas`, float32). Strips
#: change no value (each node is computed by the same operations whatever the strip,
#: tests/terrain/test_tile_errors.py); wider strips mean fewer numpy calls a window for
#: temporaries of 2 MB (a 1025-node window). Thread CPU a 1025^2 window of the 8192^2
#: benchmark DEM (4 windows, 11 interleaved rounds, load 10): 64 -> 512 columns 30.2 ->
#: 27.1 ms (median), 23.8 -> 20.1 ms (min). The float64 error passes keep 64: 256 gave no
#: clear gain there (27.5 vs 28.6 ms median, 22.8 vs 21.6 ms min).
STRIDE_STRIP = 512
ERROR_STRIP = 64


def _phase_weights(f: int, dtype: type) -> tuple[np.ndarray, np.ndarray]:
    """(1 - t, t) for every phase k of a factor-f grid, computed like ``interp_axis``
    (remembered per factor and dtype: read-only arrays, shared by every call)."""
    return _phase_weights_cached(f, np.dtype(dtype).str)


@functools.lru_cache(maxsize=64)
def _phase_weights_cached(f: int, dtype: str) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(f).astype(np.dtype(dtype).type) / f
    w0, w1 = 1.0 - t, t
    w0.flags.writeable = False
    w1.flags.writeable = False
    return w0, w1


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
    arr: np.ndarray, s_n: int, strides: tuple[int, ...], strip: int = STRIDE_STRIP
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


def data_blocks(arr: np.ndarray, b: int) -> tuple[slice, slice] | None:
    """The closed b x b cell blocks of a node window (``arr``: (m*b+1, n*b+1) or its first
    rows / columns, e.g. without the closing ones) that hold a finite node: (rows, cols),
    slices of block indices (a box: every block outside it holds only NaN), or None when
    no node is finite. Closed blocks share their edge nodes, so a finite node on a block
    edge puts both blocks in.

    The ingest's per-tile passes (heights, stride deltas, errors) give an all-NaN block
    NaN (0 for stride deltas) whatever they compute, so they run on the box alone: a chunk
    at a DEM's edge, or a coarse level's chunk around a small DEM, is mostly NaN (of the
    8192^2 benchmark's 94 chunk windows, 46 % of the nodes are finite).
    """
    finite = np.isfinite(arr)
    rows = np.flatnonzero(finite.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(finite.any(axis=0))
    return _block_span(rows, b, arr.shape[0]), _block_span(cols, b, arr.shape[1])


def _block_span(nodes: np.ndarray, b: int, size: int) -> slice:
    """Blocks of b cells (ceil((size - 1) / b) of them along an axis of ``size`` nodes)
    whose closed node range [k*b, (k+1)*b] meets node indices ``nodes`` (sorted, non-empty):
    from the block that closes on the first to the one that opens on the last."""
    n = max(1, -(-(size - 1) // b))
    return slice(max(0, (int(nodes[0]) - 1) // b), min(n, int(nodes[-1]) // b + 1))


def tile_stats(
    arr: np.ndarray, s_n: int, strides: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(hmin, hmax, stride deltas) of a closed, tile-aligned float32 node window: exactly
    `tile_min_max` and `stride_deltas` of the whole window, computed on the box of tiles
    that hold data (`data_blocks`); the others are NaN, NaN and 0 as those give them."""
    kty, ktx = (arr.shape[0] - 1) // s_n, (arr.shape[1] - 1) // s_n
    hmin = np.full((kty, ktx), np.nan, dtype=arr.dtype)
    hmax = hmin.copy()
    delta = np.zeros((kty, ktx, len(strides)), dtype=np.float64)
    box = data_blocks(arr, s_n)
    if box is None:
        return hmin, hmax, delta
    ty, tx = box
    sub = arr[ty.start * s_n : ty.stop * s_n + 1, tx.start * s_n : tx.stop * s_n + 1]
    lo, hi = tile_min_max(sub, s_n)
    hmin[ty, tx], hmax[ty, tx] = lo, hi
    delta[ty, tx] = stride_deltas(sub, s_n, strides)
    return hmin, hmax, delta


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
    strip_cols: int = ERROR_STRIP,
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


# -- branch and bound (issue #25, C2) ---------------------------------------------------------
#
# A coarse level's error pass spends most of its time on blocks of the window that cannot hold
# their tile's maximum. For a block of B x B fine cells lying inside one coarse cell (B divides
# f and the offsets), the upsampled surface P is bilinear on the block, so its extremes are at
# the block's four corners; with the fine nodes' min and max over the block (fmin, fmax, one
# pass per window, shared by every coarser level),
#
#     max over the block of |P - fine| <= max(Pmax - fmin, fmax - Pmin) =: bound.
#
# A tile's error is at least the |P - fine| at any of its nodes: the block corners give a
# lower bound LB per tile for the price of (h/B) x (w/B) nodes. A block whose bound is below
# its tile's LB cannot hold the tile's maximum and is skipped; the others get the exact pass
# (the same floats as the full pass, node for node), and the tile's value is the max of
# theirs and LB. The result is the full pass's, bit for bit:
# - LB is a value of the full pass (its nodes are the full pass's nodes, computed the same
#   way), so the max is never above the full pass's;
# - the block holding the full pass's maximum V is never skipped: V <= bound + margin <= LB
#   would make V the maximum too (and then LB = V is the answer anyway).
# The margin covers the float rounding between the bilinear surface and its computed values
# (two lerps and a difference, each within a few ulps of the window's largest |height| M):
# 64 eps M, 6e-11 m at 9 km in float64, far below any error that decides a skip.
# Where the block's cell has NaN coarse nodes, P is finite only on the block's edges between
# finite corners, so the finite corners still bound it; blocks with no finite P or no finite
# fine node are skipped outright (they add nothing to a max that ignores NaN). That is most of
# the window for the levels much coarser than the data (a 1-degree DEM's level-0 tile).
#
# Measured in the 8192^2 benchmark DEM's ingest (its 54 error windows, thread CPU of the
# full and the pruned pass on the same inputs, load 3): f = 2-16 unchanged (most blocks
# survive: f = 16 keeps 17-44 % of them, where the gathered pass costs more than the strip
# pass), f = 32 0.21 -> 0.08 s, f = 64 .. 16384 0.18 -> 0.03-0.06 s each; all levels
# 2.9 -> 1.5 s.

#: Side (fine cells) of the blocks the pruned pass bounds and skips: their bookkeeping is
#: 1/64 of the nodes, and from f = 8 on a block lies inside one coarse cell.
PRUNE_BLOCK = 8
#: Factors f from which the pass is pruned (below, too many blocks survive, see above).
PRUNE_MIN_F = 32
#: Above this share of surviving blocks the full strip pass is cheaper than the gathered one
#: (a gathered node costs about 5x a strip-pass node: 81 nodes a block for 64 cells, and
#: gathers instead of strided slices).
PRUNE_MAX_SURVIVAL = 0.15
#: Blocks per batch of the gathered exact pass (bounds its temporaries to a few MB).
_GATHER_BATCH = 2048


@dataclass(frozen=True)
class ErrorWindow:
    """A fine node window made ready for the errors of every coarser level against it.

    fine: the (h, w) nodes as given (float32 heights, metres; row 0 north); fine_t: the same
    transposed and C-contiguous in the pass's dtype (`transposed_nodes` for float64);
    bmin, bmax: NaN-ignoring min and max of the nodes of each closed PRUNE_BLOCK-cell block
    ((h-1)/B, (w-1)/B), None where the window is not whole blocks (no pruning then);
    scale: the largest |node| (inf if any is), for the rounding margin.
    """

    fine: np.ndarray
    fine_t: np.ndarray
    bmin: np.ndarray | None
    bmax: np.ndarray | None
    scale: float


def error_window(fine: np.ndarray, dtype: type = np.float64) -> ErrorWindow:
    """Make the `ErrorWindow` of a fine node window (once per window)."""
    fine = np.asarray(fine)
    fine_t: np.ndarray = np.ascontiguousarray(fine.T, dtype=dtype)
    b = PRUNE_BLOCK
    bmin = bmax = None
    if (fine.shape[0] - 1) % b == 0 and (fine.shape[1] - 1) % b == 0 and fine.size > 1:
        bmin, bmax = block_node_min(fine, b), block_node_max(fine, b)
    with np.errstate(invalid="ignore"):
        scale = float(np.nanmax(np.abs(fine))) if np.isfinite(fine).any() else 0.0
    return ErrorWindow(fine, fine_t, bmin, bmax, scale)


def pruned_error_tiles(
    coarse: np.ndarray,
    win: ErrorWindow,
    f: int,
    r_off: int,
    c_off: int,
    cell_r0: int,
    cell_c0: int,
    tile_span: int,
    block: int,
    owned: np.ndarray | None = None,
    strip_cols: int = ERROR_STRIP,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`upsampled_error_tiles(coarse, win.fine_t, ...)`, the same floats, with the blocks that
    cannot hold their tile's maximum skipped (branch and bound, see above). Falls back to the
    full pass where pruning does not apply (f < PRUNE_MIN_F, blocks not aligned with the
    coarse cells, infinite values) or does not pay (too many blocks survive)."""
    w, h = win.fine_t.shape
    b, pb = block, PRUNE_BLOCK
    m, n = (h - 1) // b, (w - 1) // b
    if m * b != h - 1 or n * b != w - 1 or cell_r0 % b or cell_c0 % b or tile_span % b:
        raise ValueError("window, origin and tile span must be whole blocks")

    def full() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return upsampled_error_tiles(
            coarse, win.fine_t, f, r_off, c_off, cell_r0, cell_c0, tile_span, block, owned,
            strip_cols,
        )  # fmt: skip

    aligned = f % pb == 0 and b % pb == 0 and r_off % pb == 0 and c_off % pb == 0
    if f < PRUNE_MIN_F or not aligned or win.bmin is None or win.bmax is None:
        return full()
    dt = win.fine_t.dtype.type
    with np.errstate(invalid="ignore"):
        c_scale = float(np.nanmax(np.abs(coarse))) if np.isfinite(coarse).any() else 0.0
    scale = max(win.scale, c_scale)
    if not np.isfinite(scale):
        return full()
    mb, nb = (h - 1) // pb, (w - 1) // pb
    rows_b = (cell_r0 + np.arange(mb) * pb) // tile_span  # tile row of each block row
    cols_b = (cell_c0 + np.arange(nb) * pb) // tile_span
    owned_b = None if owned is None else np.repeat(np.repeat(owned, b // pb, 0), b // pb, 1)
    skip, lower = _skippable_blocks(
        coarse, win, f, r_off, c_off, rows_b, cols_b, owned_b, 64 * np.finfo(dt).eps * scale
    )
    survivors = skip.size - np.count_nonzero(skip)
    if survivors > PRUNE_MAX_SURVIVAL * skip.size:
        return full()
    rv, cv = segment_starts(rows_b)[1], segment_starts(cols_b)[1]
    if survivors == 0:
        return rv, cv, lower
    bi, bj = np.nonzero(~skip)
    blocks = np.full((mb, nb), np.nan, dtype=dt)
    blocks[bi, bj] = _gathered_block_max(coarse, win.fine, f, r_off, c_off, bi, bj, dt)
    return rv, cv, np.fmax(reduce_cells(blocks, rows_b, cols_b)[2], lower)


def _skippable_blocks(
    coarse: np.ndarray,
    win: ErrorWindow,
    f: int,
    r_off: int,
    c_off: int,
    rows_b: np.ndarray,
    cols_b: np.ndarray,
    owned_b: np.ndarray | None,
    margin: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(skip, lower): which PRUNE_BLOCK blocks need no exact pass (bound + margin below their
    tile's lower bound, all-NaN fine nodes, or not owned), and the per-tile lower bound (the
    max of |P - fine| at the owned blocks' corners, as `reduce_cells` over rows_b, cols_b)."""
    pb = PRUNE_BLOCK
    h, w = win.fine.shape
    dt = win.fine_t.dtype.type
    # P at the block corners: the gather upsampling, bit for bit the strip pass's values
    # (tests/terrain/test_tile_errors.py pins upsample_window to upsample_nodes).
    p = upsample_nodes(coarse, f, r_off + np.arange(0, h, pb), c_off + np.arange(0, w, pb), dt)
    d = np.abs(p - win.fine[::pb, ::pb])
    # NaN-ignoring: where a coarse node of the block's cell is NaN, P is NaN inside the cell
    # and finite only along the cell's edges between two finite coarse nodes, i.e. along the
    # block's edges between two finite block corners, linear between them (or at a finite
    # corner alone). So the finite corners bound every finite P, and a block with four NaN
    # corners has no finite P at all.
    p_min, p_max = np.fmin(p[:-1], p[1:]), np.fmax(p[:-1], p[1:])
    p_min, p_max = np.fmin(p_min[:, :-1], p_min[:, 1:]), np.fmax(p_max[:, :-1], p_max[:, 1:])
    assert win.bmin is not None and win.bmax is not None
    with np.errstate(invalid="ignore"):
        bound = np.maximum(p_max - win.bmin, win.bmax - p_min)
    bound += margin
    at_corner = np.fmax(d[:-1], d[1:])
    at_corner = np.fmax(at_corner[:, :-1], at_corner[:, 1:])
    if owned_b is not None:
        at_corner[~owned_b] = np.nan
    _, _, lower = reduce_cells(at_corner, rows_b, cols_b)
    lower_b = lower[rows_b - rows_b[0]][:, cols_b - cols_b[0]]
    with np.errstate(invalid="ignore"):
        skip = bound < lower_b
    skip |= np.isnan(win.bmin) | np.isnan(p_min)  # no finite fine node, or no finite P
    if owned_b is not None:
        skip |= ~owned_b
    return skip, lower


def _gathered_block_max(
    coarse: np.ndarray,
    fine: np.ndarray,
    f: int,
    r_off: int,
    c_off: int,
    bi: np.ndarray,
    bj: np.ndarray,
    dt: type,
) -> np.ndarray:
    """Max |P - fine| over the nodes of closed PRUNE_BLOCK blocks (bi, bj), NaN-ignoring, in
    dtype ``dt``, with each node's P as the strip pass computes it, so the values are the
    full pass's, node for node.

    The strip pass interpolates rows first (lo * w0 + hi * w1 with the phase's weights, hi =
    lo at phase 0: a copy of lo when no value is infinite), then columns the same way. A block
    lies in one coarse cell (i, j) (B divides f and the offsets), its nodes at phases 0 .. f
    of it; where the cell's four nodes are finite, phase f's copy of the next node equals
    lo * 0 + hi * 1 and phase 0's copy lo * 1 + hi * 0 (up to the sign of a zero, which
    |P - fine| cannot see), so one formula with the weights of phases 0 .. f serves every
    node. Blocks of other cells take each node's own indices (rare: cells at data edges).
    """
    pb = PRUNE_BLOCK
    t = np.arange(f + 1).astype(dt) / f  # as _phase_weights, plus phase f (t = 1)
    w0, w1 = 1.0 - t, t
    c: np.ndarray = coarse.astype(dt)
    blocks = sliding_window_view(fine, (pb + 1, pb + 1))[::pb, ::pb]  # (mb, nb, B+1, B+1) view
    a_r, a_c = r_off + bi * pb, c_off + bj * pb  # the blocks' first node, fine positions
    i, j = a_r // f, a_c // f
    c00, c10, c01, c11 = c[i, j], c[i + 1, j], c[i, j + 1], c[i + 1, j + 1]
    finite = np.isfinite(c00) & np.isfinite(c10) & np.isfinite(c01) & np.isfinite(c11)
    out: np.ndarray = np.empty(bi.size, dtype=dt)
    k = np.arange(pb + 1)
    for s in range(0, bi.size, _GATHER_BATCH):
        sl = slice(s, s + _GATHER_BATCH)
        pr = (a_r[sl] % f)[:, None] + k  # phases 0 .. f of the block's rows in its cell
        pc = (a_c[sl] % f)[:, None] + k
        ok = finite[sl]
        t0 = c00[sl, None] * w0[pr]
        t0 += c10[sl, None] * w1[pr]
        t1 = c01[sl, None] * w0[pr]
        t1 += c11[sl, None] * w1[pr]
        p = t0[:, :, None] * w0[pc][:, None, :]
        p += t1[:, :, None] * w1[pc][:, None, :]
        if not ok.all():
            bad = np.flatnonzero(~ok)
            p[bad] = _node_values(c, f, w0, w1, a_r[sl][bad], a_c[sl][bad])
        p -= blocks[bi[sl], bj[sl]]
        np.abs(p, out=p)
        out[sl] = np.fmax.reduce(np.fmax.reduce(p, axis=2), axis=1)
    return out


def _node_values(
    c: np.ndarray, f: int, w0: np.ndarray, w1: np.ndarray, a_r: np.ndarray, a_c: np.ndarray
) -> np.ndarray:
    """P at the (B+1)^2 nodes of blocks whose first node is at fine positions (a_r, a_c), each
    node with its own coarse indices and phase (hi = lo at phase 0), as the strip pass."""
    k = np.arange(PRUNE_BLOCK + 1)
    qr, qc = a_r[:, None] + k, a_c[:, None] + k
    i0, kr = (qr // f)[:, :, None], (qr % f)[:, :, None]
    j0, kc = (qc // f)[:, None, :], (qc % f)[:, None, :]
    i1, j1 = i0 + (kr > 0), j0 + (kc > 0)
    t0 = c[i0, j0] * w0[kr]
    t0 += c[i1, j0] * w1[kr]
    t1 = c[i0, j1] * w0[kr]
    t1 += c[i1, j1] * w1[kr]
    p = t0 * w0[kc]
    p += t1 * w1[kc]
    return p


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
    change = np.empty(group.shape[0], dtype=bool)
    change[:1] = True
    np.not_equal(group[1:], group[:-1], out=change[1:])
    starts = np.flatnonzero(change)
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
