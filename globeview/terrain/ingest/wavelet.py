"""Dyadic wavelet approximation of grid-registered height rasters (the tile pyramid's low-pass).

The pyramid stores *grid-registered* rasters: level L+1 has (2m+1) x (2n+1) nodes, level L has
(m+1) x (n+1), and coarse node (j, i) sits exactly on fine node (2j, 2i). A coarse level is the
wavelet low-pass approximation of the finer one: separable filtering with the analysis
low-pass of a symmetric, odd-length (biorthogonal) wavelet, then keeping the even nodes.

Heights are metres (float32 in and out); the functions are agnostic of the raster's CRS, the
row/column axes are just array axes 0 and 1. NaN marks "no data".

Borders are extended by *point* reflection about the edge node (``x[-k] = 2 x[0] - x[k]``,
numpy's ``np.pad(mode="reflect", reflect_type="odd")``). This is "mirror about the edge node"
in value as well as in position; we depart from a plain even mirror (``x[-k] = x[k]``) because
the even mirror bends a linear ramp into a V at the border and gives border tiles a spurious
geometric error, while the odd mirror reproduces ramps and planes up to the raster's edge.

Windowed use (rasters larger than RAM). With ``H = kernel_halo(wavelet)`` (even), the coarse
nodes [r0, r1) x [c0, c1) are::

    padded = fine[2*r0 - H : 2*(r1 - 1) + 1 + H, 2*c0 - H : 2*(c1 - 1) + 1 + H]
    coarse_window = approximate_window(padded, H)     # == approximate_grid(fine)[r0:r1, c0:c1]

provided the halo holds real data. At the raster's true borders, build the halo with
``extend_borders(fine, H)`` (the same odd mirror ``approximate_grid`` uses) and index that
array shifted by H: the window then equals the whole-array result there too.
"""

from __future__ import annotations

import numpy as np

from globeview.errors import GlobeviewError

__all__ = [
    "WaveletError",
    "approximate_grid",
    "approximate_window",
    "extend_borders",
    "filter_decimate_grid",
    "kernel_halo",
    "lowpass_kernel",
]

# Default: bior2.2 is the CDF 5/3 (Le Gall) analysis low-pass [-1, 2, 6, 2, -1] / 8.
# - symmetric with odd length: the coarse node stays on its fine node (no half-sample shift);
# - short (5 taps): window halos are 2 samples, filtering costs 5 multiply-adds per axis, and
#   there is little ringing next to cliffs (one small negative lobe);
# - like every symmetric kernel with unit sum it reproduces linear ramps exactly, so planar
#   slopes carry no approximation error into coarse levels.
# bior4.4 (CDF 9/7) also works: smoother, 9 taps, halo 4.
DEFAULT_WAVELET = "bior2.2"

# Tap magnitudes below this are pywt's zero padding, not part of the filter.
_ZERO_TAP = 1e-12


class WaveletError(GlobeviewError, ValueError):
    """A wavelet or an array cannot be used for the approximation (explained in one line)."""


def lowpass_kernel(wavelet: str = DEFAULT_WAVELET) -> np.ndarray:
    """Return the 1-D analysis low-pass of a PyWavelets wavelet, usable on a node grid.

    The filter is ``pywt.Wavelet(wavelet).dec_lo`` with its zero padding trimmed, normalised
    to sum 1 (so heights keep their unit, metres), as float64 of odd length 2h+1.

    Raises:
        WaveletError (a ValueError): unknown or continuous wavelet, or a filter that is not
            symmetric with odd length (e.g. 'haar', 'db2'): those shift the coarse node by half
            a sample or off-centre, so coarse node j would not sit on fine node 2j.
    """
    import pywt  # here: its extension takes ~0.2 s to load, and opening a store needs none

    try:
        w = pywt.Wavelet(wavelet)
    except (ValueError, TypeError) as exc:
        raise WaveletError(
            f"unknown or continuous wavelet {wavelet!r}; use a discrete biorthogonal one "
            f"such as 'bior2.2' or 'bior4.4'"
        ) from exc
    taps = np.asarray(w.dec_lo, dtype=np.float64)
    nz = np.flatnonzero(np.abs(taps) > _ZERO_TAP)
    taps = taps[nz[0] : nz[-1] + 1]
    if taps.size % 2 == 0:
        raise WaveletError(
            f"wavelet {wavelet!r} has an even-length low-pass ({taps.size} taps): its coarse "
            f"samples fall half-way between fine nodes; use 'bior2.2' or 'bior4.4'"
        )
    if not np.allclose(taps, taps[::-1], rtol=0.0, atol=1e-12):
        raise WaveletError(
            f"wavelet {wavelet!r} has an asymmetric low-pass: its coarse samples are shifted "
            f"off the fine nodes; use 'bior2.2' or 'bior4.4'"
        )
    return taps / taps.sum()


def kernel_halo(wavelet: str = DEFAULT_WAVELET) -> int:
    """Fine samples a window needs beyond each edge so windowed == whole-array results.

    The kernel's half-width h rounded up to an even number, so the window still starts on a
    fine node that carries a coarse node (even index).
    """
    h = lowpass_kernel(wavelet).size // 2
    return h + (h % 2)


def extend_borders(fine: np.ndarray, width: int) -> np.ndarray:
    """Extend a 2-D raster by ``width`` nodes on every side with the odd mirror (float32).

    ``out[-k] = 2 * fine[0] - fine[k]`` about each edge node (NaN stays NaN). This is exactly
    the border extension ``approximate_grid`` applies, so a builder that pads the raster's true
    borders with it gets window results equal to the whole-array result everywhere.
    """
    a = np.asarray(fine, dtype=np.float32)
    if a.ndim != 2 or width < 0:
        raise WaveletError(f"cannot mirror-extend a raster of shape {a.shape} by {width} nodes")
    return np.pad(a, width, mode="reflect", reflect_type="odd")


def _filter_decimate(padded: np.ndarray, taps: np.ndarray, axis: int, step: int) -> np.ndarray:
    """Filter along ``axis`` at every ``step``-th node of an array already padded by h.

    Output node i is ``sum_t taps[t] * padded[step*i + t]``: the centre tap lands on unpadded
    node step*i. One vectorised multiply-add per tap (a handful of taps), none per sample.
    """
    n_inner = padded.shape[axis] - taps.size + 1
    n_out = (n_inner - 1) // step + 1
    out_shape = list(padded.shape)
    out_shape[axis] = n_out
    acc = np.zeros(out_shape, dtype=np.float32)
    idx: list[slice] = [slice(None), slice(None)]
    for t, tap in enumerate(taps.astype(np.float32)):
        idx[axis] = slice(t, t + step * (n_out - 1) + 1, step)
        acc += tap * padded[tuple(idx)]
    return acc


def _filter_decimate_into(
    src: np.ndarray, taps32: np.ndarray, axis: int, step: int, acc: np.ndarray, tmp: np.ndarray
) -> None:
    """``_filter_decimate`` into preallocated ``acc`` (its output shape), ``tmp`` scratch.

    The same float32 operations in the same order: acc = 0, then acc += tap_t * x_t per tap.
    """
    n_out = acc.shape[axis]
    idx: list[slice] = [slice(None), slice(None)]
    acc.fill(0.0)
    for t, tap in enumerate(taps32):
        idx[axis] = slice(t, t + step * (n_out - 1) + 1, step)
        np.multiply(src[tuple(idx)], tap, out=tmp)
        acc += tmp


# Output rows per strip of ``_separable``: its float32 temporaries (a few hundred KB for a
# 2k-wide window) stay in the CPU cache; measured 2x faster than whole-array passes.
_STRIP_ROWS = 16
# Output nodes per block where the NaN-aware filter computes its convex value (rows, cols).
_NAN_BLOCK = (32, 256)


def _separable(
    padded: np.ndarray, taps: np.ndarray, step: int, rows: int = _STRIP_ROWS
) -> np.ndarray:
    """Columns (axis 1) first, then rows on the decimated result, in strips of output rows.

    A strip of output rows [r0, r1) needs the padded rows [step*r0, step*(r1-1) + T); each
    output value is computed by exactly the operations of the whole-array passes (rows of the
    column pass that two strips share are computed twice, identically), so strips change no
    bit, only the cache traffic.
    """
    taps32 = taps.astype(np.float32)
    nt = taps.size
    n_r = (padded.shape[0] - nt) // step + 1
    n_c = (padded.shape[1] - nt) // step + 1
    out = np.empty((n_r, n_c), dtype=np.float32)
    mid = np.empty(((rows - 1) * step + nt, n_c), dtype=np.float32)
    mid_tmp = np.empty_like(mid)
    out_tmp = np.empty((rows, n_c), dtype=np.float32)
    for r0 in range(0, n_r, rows):
        r1 = min(n_r, r0 + rows)
        a0, a1 = r0 * step, (r1 - 1) * step + nt
        m = mid[: a1 - a0]
        _filter_decimate_into(padded[a0:a1], taps32, 1, step, m, mid_tmp[: a1 - a0])
        _filter_decimate_into(m, taps32, 0, step, out[r0:r1], out_tmp[: r1 - r0])
    return out


def filter_decimate_grid(fine: np.ndarray, taps: np.ndarray, step: int) -> np.ndarray:
    """NaN-aware separable filtering of a node grid with a symmetric kernel, keeping every
    ``step``-th node: (step*m+1, step*n+1) -> (m+1, n+1), float32.

    The engine behind ``approximate_grid`` (step 2) and ``mband.mband_approximate_grid``
    (step M). ``taps`` must be symmetric, odd-length and sum to 1; sides must be
    ``1 (mod step)``. See ``approximate_grid`` for borders and the NaN rule.
    """
    a = np.asarray(fine, dtype=np.float32)
    if a.ndim != 2:
        raise WaveletError(f"expected a 2-D height raster, got {a.ndim} dimension(s)")
    if a.shape[0] % step != 1 % step or a.shape[1] % step != 1 % step or min(a.shape) < 1:
        raise WaveletError(
            f"a grid-registered level needs sides of {step}*m+1 nodes"
            f"{' (odd sides)' if step == 2 else ''}, got {a.shape[0]} x {a.shape[1]}"
        )
    h = taps.size // 2
    # np.pad reflects repeatedly when a side is shorter than h and keeps 1-node sides constant.
    padded = np.pad(a, h, mode="reflect", reflect_type="odd")
    return _filter_padded(padded, a[::step, ::step], taps, step)


def _filter_padded(
    padded: np.ndarray, centres: np.ndarray, taps: np.ndarray, step: int
) -> np.ndarray:
    """``filter_decimate_grid`` on an array already padded by the kernel's half-width:
    output node i is centred on ``padded[step*i + h]``, whose value is ``centres[i]``.

    Every output node depends only on its own support and centre (the NaN rule included),
    so a window cut from a larger padded array gives those nodes' whole-array values. So
    only the box of output nodes with a valid centre is filtered (a NaN centre gives NaN):
    a coarse level's window around a small DEM is mostly NaN.
    """
    box = _valid_box(centres)
    if box is None:
        return np.full(centres.shape, np.nan, dtype=np.float32)
    (b_r0, b_r1), (b_c0, b_c1) = box
    if b_r1 - b_r0 < centres.shape[0] or b_c1 - b_c0 < centres.shape[1]:
        boxed = np.full(centres.shape, np.nan, dtype=np.float32)
        rows = slice(b_r0 * step, (b_r1 - 1) * step + taps.size)
        cols = slice(b_c0 * step, (b_c1 - 1) * step + taps.size)
        inner = centres[b_r0:b_r1, b_c0:b_c1]
        boxed[b_r0:b_r1, b_c0:b_c1] = _filter_padded(padded[rows, cols], inner, taps, step)
        return boxed
    invalid = np.isnan(padded)
    if not invalid.any():
        return _separable(padded, taps, step)

    values = np.where(invalid, np.float32(0.0), padded)
    out = _separable(values, taps, step)  # the exact low-pass, kept where no NaN is touched
    touched = _touches(invalid, taps.size, step)
    # The convex (renormalised, non-negative taps) value only where the support touches NaN,
    # computed per block of output nodes that holds such a node and a valid centre (a NaN
    # centre ends NaN anyway): same operations per node as filtering the whole array, so the
    # same floats, but a NaN border costs its own blocks instead of two more whole passes.
    positive = np.clip(taps, 0.0, None)
    centre_nan = np.isnan(centres)
    nt = taps.size
    br, bc = _NAN_BLOCK
    for r0 in range(0, out.shape[0], br):
        r1 = min(out.shape[0], r0 + br)
        t_rows = touched[r0:r1]
        if not t_rows.any():
            continue
        for c0 in range(0, out.shape[1], bc):
            c1 = min(out.shape[1], c0 + bc)
            t = t_rows[:, c0:c1] & ~centre_nan[r0:r1, c0:c1]
            if not t.any():
                continue
            rows = slice(r0 * step, (r1 - 1) * step + nt)
            cols = slice(c0 * step, (c1 - 1) * step + nt)
            num = _separable(values[rows, cols], positive, step)
            den = _separable((~invalid[rows, cols]).astype(np.float32), positive, step)
            convex = np.divide(num, den, out=np.full_like(num, np.nan), where=den > 0)
            out[r0:r1, c0:c1][t] = convex[t]
    out[centre_nan] = np.nan
    return out


def _valid_box(centres: np.ndarray) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """((r0, r1), (c0, c1)): the smallest box of nodes holding every non-NaN one, None if
    all are NaN."""
    valid = ~np.isnan(centres)
    rows = np.flatnonzero(valid.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(valid.any(axis=0))
    return (int(rows[0]), int(rows[-1]) + 1), (int(cols[0]), int(cols[-1]) + 1)


def _touches(invalid: np.ndarray, nt: int, step: int) -> np.ndarray:
    """Output nodes whose nt x nt support (as ``_separable``) holds an invalid sample.

    Boolean dilation, separable like the filter: equal to ``_separable(invalid, ones) > 0.5``
    (a sum of at most nt^2 zeros and ones is exact in float32 and >= 1 iff any is one).
    """
    n_r = (invalid.shape[0] - nt) // step + 1
    n_c = (invalid.shape[1] - nt) // step + 1
    cols = np.zeros((invalid.shape[0], n_c), dtype=bool)
    for t in range(nt):
        cols |= invalid[:, t : t + step * (n_c - 1) + 1 : step]
    out = np.zeros((n_r, n_c), dtype=bool)
    for t in range(nt):
        out |= cols[t : t + step * (n_r - 1) + 1 : step]
    return out


def approximate_grid(fine: np.ndarray, wavelet: str = DEFAULT_WAVELET) -> np.ndarray:
    """Wavelet low-pass approximation of a grid-registered raster: (2m+1, 2n+1) -> (m+1, n+1).

    Separable filtering along columns and rows with ``lowpass_kernel(wavelet)``, keeping the
    even nodes: coarse node (j, i) is the filtered value at fine node (2j, 2i). Borders use the
    odd mirror about the edge node (see ``extend_borders``). Heights in metres, float32.

    NaN-aware ("no data"): a coarse node is NaN iff its own fine node is NaN. A node whose
    filter support touches NaN is the normalised convolution (weights renormalised over the
    valid samples) with the kernel's non-negative taps only: a convex weighted mean of valid
    neighbours, so it stays within their range and the denominator is at least the centre
    weight. We drop the negative lobes there because renormalising a kernel with negative
    taps over a partial support can make the denominator tiny or negative and the result
    explode. Nodes whose support is all valid get the exact wavelet low-pass.

    Raises:
        WaveletError (a ValueError): not 2-D, a side of even length or < 1, or a bad wavelet.
    """
    return filter_decimate_grid(fine, lowpass_kernel(wavelet), 2)


def approximate_window(
    fine_padded: np.ndarray, halo: int, wavelet: str = DEFAULT_WAVELET
) -> np.ndarray:
    """Approximate a window of fine nodes that carries ``halo`` extra nodes on every side.

    ``fine_padded = fine[2*r0 - halo : 2*(r1-1) + 1 + halo, 2*c0 - halo : 2*(c1-1) + 1 + halo]``
    (real data, or ``extend_borders`` output at the raster's true borders) gives coarse nodes
    [r0, r1) x [c0, c1), equal to ``approximate_grid(fine)[r0:r1, c0:c1]``.

    Raises:
        WaveletError: ``halo`` odd or smaller than ``kernel_halo(wavelet)``, or a window with
            no interior node.
    """
    need = kernel_halo(wavelet)
    if halo % 2 or halo < need:
        raise WaveletError(
            f"window halo must be even and at least {need} fine nodes for {wavelet!r}, got {halo}"
        )
    a = np.asarray(fine_padded, dtype=np.float32)
    if a.ndim != 2 or min(a.shape) < 2 * halo + 1:
        raise WaveletError(f"window of shape {a.shape} is too small for a halo of {halo} nodes")
    if a.shape[0] % 2 != 1 or a.shape[1] % 2 != 1:
        raise WaveletError(
            f"a grid-registered level needs sides of 2*m+1 nodes (odd sides), "
            f"got {a.shape[0]} x {a.shape[1]}"
        )
    # The interior coarse nodes read only the window's own nodes (halo >= the kernel's half
    # width h), so filter them straight from the window: the mirror padding approximate_grid
    # would add and the halo/2 border nodes it would compute and drop never reach them. The
    # same operations per kept node, without the padded copy of the window.
    taps = lowpass_kernel(wavelet)
    d = halo - taps.size // 2
    core = a[d : a.shape[0] - d, d : a.shape[1] - d]
    return _filter_padded(
        core, a[halo : a.shape[0] - halo : 2, halo : a.shape[1] - halo : 2], taps, 2
    )
