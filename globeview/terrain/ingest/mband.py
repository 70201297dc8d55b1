"""M-band wavelet transforms of height rasters (Zhang et al., Geobeans3D, §V, eq. 4-5).

PyWavelets has no M-band transforms, so the filter bank is built here in numpy. An M-band
filter bank has one scaling (low-pass) filter ``c`` and M-1 wavelet filters ``d^s``
(s = 1..M-1); with decimation by M along each axis, one 2-D level splits an array into M^2
sub-bands indexed by (s1, s2), s1 along rows (axis 0, index k) and s2 along columns
(axis 1, index l); band (0, 0) is the approximation.

What we implement (analysis, one level, input a_j, output a_{j+1} and b_{j+1}):

    a_{j+1,k,l}         = sum_{n1,n2} c_{n1-Mk}     c_{n2-Ml}     a_{j,n1,n2}      (eq. 4)
    b^{s1,s2}_{j+1,k,l} = sum_{n1,n2} f^{s1}_{n1-Mk} f^{s2}_{n2-Ml} a_{j,n1,n2}     (eq. 5)

with f^0 = c and f^s = d^s. The printed eq. (5) writes ``a_{j+1,n1,n2}`` on the right and
``b_{j,k,l}`` on the left; the analysis input is the finer level a_j (as in eq. 4) and the
details belong to level j+1 (as the text below eq. 5 says), so we implement the above.

Indices n - Mk are taken modulo the array length (periodic extension): with an orthonormal
(paraunitary) bank the transform is then an orthogonal matrix, so synthesis is its transpose,
reconstruction is perfect and the energy (sum of squares) of all bands equals the input's.

Units: heights in metres in, orthonormal coefficients out. One 2-D level multiplies a constant
by M (sqrt(M) per axis); ``mband_approximate`` divides that out to give heights.

Reference code, not used by ingest or the LOD (issue #14 asked: wire it in or say why not).
The tile store is a dyadic pyramid (each level halves the resolution, CDF 5/3 low-pass,
`globeview.terrain.ingest.wavelet`), because the quadtree that every layer, the LOD and the renderer
share is dyadic; a 3-band level has no tile grid there. The `wavelet` LOD provider keeps
Zhang's M-band *resolution ladder* on the dyadic levels
(`builtin.wavelet.provider.stop_levels`), and a
true M-band approximation of a tile could only be computed per tile from its heights each
frame, a Python loop the frame path must not run. The filter banks here are the tested
reading of eq. 4-5 (perfect reconstruction, energy, the printed typos) against which that
choice can be checked.
"""

from __future__ import annotations

import numpy as np

from globeview.terrain.ingest.wavelet import WaveletError, filter_decimate_grid

__all__ = [
    "mband_approximate",
    "mband_approximate_grid",
    "mband_decompose2d",
    "mband_filter_bank",
    "mband_grid_kernel",
    "mband_reconstruct2d",
    "mband_wavedec2",
    "mband_waverec2",
]

Details = dict[tuple[int, int], np.ndarray]


def _check_m(M: int) -> int:
    if not isinstance(M, (int, np.integer)) or isinstance(M, bool) or M < 2:
        raise WaveletError(f"the number of bands M must be an integer >= 2, got {M!r}")
    return int(M)


def mband_filter_bank(M: int, kind: str = "haar") -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal (paraunitary) M-band filter bank: ``c`` of shape (L,), ``d`` of (M-1, L).

    kind 'haar': the M-band Haar family, L = M, the rows of the orthonormal DCT-II matrix
    ``C[s, n] = sqrt(w_s / M) cos(pi (2n+1) s / (2M))`` (w_0 = 1, w_s = 2): row 0 is the
    constant 1/sqrt(M) (block mean up to scale), row s has s sign changes (rising frequency).
    Filters are non-overlapping (length M), so the transform never reaches across blocks.
    """
    M = _check_m(M)
    if kind != "haar":
        raise WaveletError(f"unknown M-band filter family {kind!r}; available: 'haar'")
    s = np.arange(M)[:, None]
    n = np.arange(M)[None, :]
    weight = np.where(s == 0, 1.0, 2.0)
    bank = np.sqrt(weight / M) * np.cos(np.pi * (2 * n + 1) * s / (2 * M))
    return bank[0].copy(), bank[1:].copy()


def _bank(c: np.ndarray, d: np.ndarray, M: int) -> np.ndarray:
    """Stack c and d into an (M, L) array and check the shapes agree with M."""
    c = np.asarray(c, dtype=np.float64)
    d = np.atleast_2d(np.asarray(d, dtype=np.float64))
    if c.ndim != 1 or d.shape != (M - 1, c.size):
        raise WaveletError(
            f"an M={M} filter bank needs c of shape (L,) and d of shape ({M - 1}, L), got "
            f"{c.shape} and {d.shape}"
        )
    return np.vstack([c, d])


def _analysis_1d(a: np.ndarray, bank: np.ndarray, M: int, axis: int) -> np.ndarray:
    """Bands along ``axis``: out[s, ..., k, ...] = sum_t bank[s, t] a[(M k + t) mod N].

    Returns the M bands stacked on a new leading axis. Loops over taps only.
    """
    a = np.moveaxis(a, axis, -1)
    n = a.shape[-1]
    if bank.shape[1] == M:
        # Non-overlapping filters (Haar family): each output sees one block of M samples, so
        # a reshape and one matrix product replace the periodic gathers.
        blocks = a.reshape(*a.shape[:-1], n // M, M)
        out = np.moveaxis(blocks @ bank.T, -1, 0)  # (M, ..., K)
        return np.moveaxis(out, -1, axis + 1)
    k = np.arange(n // M)
    out = np.zeros((M, *a.shape[:-1], n // M), dtype=np.float64)
    for t in range(bank.shape[1]):
        samples = a[..., (M * k + t) % n]
        out += bank[:, t].reshape((M,) + (1,) * samples.ndim) * samples[None]
    return np.moveaxis(out, -1, axis + 1)


def _synthesis_1d(bands: np.ndarray, bank: np.ndarray, M: int, axis: int) -> np.ndarray:
    """Transpose of ``_analysis_1d``: a[n] = sum_s sum_k bank[s, n - M k] bands[s, k]."""
    b = np.moveaxis(bands, axis + 1, -1)  # (M, ..., K)
    K = b.shape[-1]
    n = M * K
    if bank.shape[1] == M:
        # Transpose of the block fast path in _analysis_1d.
        blocks = np.moveaxis(b, 0, -1) @ bank  # (..., K, M)
        return np.moveaxis(blocks.reshape(*blocks.shape[:-2], n), -1, axis)
    k = np.arange(K)
    out = np.zeros((*b.shape[1:-1], n), dtype=np.float64)
    for t in range(bank.shape[1]):
        # For a fixed tap t the targets (M k + t) mod n are distinct, so += is safe.
        contrib = np.tensordot(bank[:, t], b, axes=(0, 0))
        out[..., (M * k + t) % n] += contrib
    return np.moveaxis(out, -1, axis)


def mband_decompose2d(
    a: np.ndarray, M: int, c: np.ndarray, d: np.ndarray
) -> tuple[np.ndarray, Details]:
    """One level of eq. (4)-(5): approximation (band (0, 0)) and the M^2-1 detail bands.

    ``a`` is (M*p, M*q) (float64 computation); returns ``approx`` of (p, q) and ``details``
    mapping (s1, s2) != (0, 0) to (p, q) arrays.

    Raises:
        WaveletError (a ValueError): not 2-D, or a side that is not a positive multiple of M.
    """
    M = _check_m(M)
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] % M or arr.shape[1] % M or min(arr.shape) == 0:
        raise WaveletError(
            f"M-band decomposition with M={M} needs a 2-D array whose sides are multiples of "
            f"{M}, got shape {arr.shape}"
        )
    bank = _bank(c, d, M)
    rows = _analysis_1d(arr, bank, M, axis=0)  # (s1, p, N1)
    both = _analysis_1d(rows, bank, M, axis=2)  # (s2, s1, p, q)
    both = np.swapaxes(both, 0, 1)  # (s1, s2, p, q)
    details = {(s1, s2): both[s1, s2] for s1 in range(M) for s2 in range(M) if (s1, s2) != (0, 0)}
    return both[0, 0], details


def mband_reconstruct2d(
    approx: np.ndarray, details: Details, M: int, c: np.ndarray, d: np.ndarray
) -> np.ndarray:
    """Synthesis: invert ``mband_decompose2d`` (missing detail bands count as zero)."""
    M = _check_m(M)
    bank = _bank(c, d, M)
    approx = np.asarray(approx, dtype=np.float64)
    both = np.zeros((M, M, *approx.shape), dtype=np.float64)
    both[0, 0] = approx
    for (s1, s2), band in details.items():
        if (s1, s2) == (0, 0) or not (0 <= s1 < M and 0 <= s2 < M):
            raise WaveletError(f"detail band index {(s1, s2)} is not valid for M={M}")
        both[s1, s2] = band
    cols = _synthesis_1d(np.swapaxes(both, 0, 1), bank, M, axis=2)  # (s1, p, N1)
    return _synthesis_1d(cols, bank, M, axis=0)


def mband_wavedec2(
    a: np.ndarray, M: int, levels: int, kind: str = "haar"
) -> list[np.ndarray | Details]:
    """Multi-level decomposition, pywt-style: ``[approx_n, details_n, ..., details_1]``.

    Each level decomposes the previous approximation; sides must be multiples of M**levels.
    """
    M = _check_m(M)
    if levels < 1:
        raise WaveletError(f"the number of M-band levels must be >= 1, got {levels}")
    shape = np.shape(a)
    if len(shape) != 2 or shape[0] % M**levels or shape[1] % M**levels or 0 in shape:
        raise WaveletError(
            f"{levels} M-band level(s) with M={M} need sides that are multiples of "
            f"{M**levels}, got shape {shape}"
        )
    c, d = mband_filter_bank(M, kind)
    approx = np.asarray(a, dtype=np.float64)
    stack: list[Details] = []
    for _ in range(levels):
        approx, det = mband_decompose2d(approx, M, c, d)
        stack.append(det)
    return [approx, *reversed(stack)]


def mband_waverec2(coeffs: list[np.ndarray | Details], M: int, kind: str = "haar") -> np.ndarray:
    """Invert ``mband_wavedec2``; a detail entry may be an empty dict (dropped details)."""
    M = _check_m(M)
    c, d = mband_filter_bank(M, kind)
    approx = np.asarray(coeffs[0], dtype=np.float64)
    for det in coeffs[1:]:
        if not isinstance(det, dict):
            raise WaveletError("M-band detail levels must be dicts keyed by (s1, s2)")
        approx = mband_reconstruct2d(approx, det, M, c, d)
    return approx


def mband_approximate(
    a: np.ndarray, M: int, levels: int = 1, kind: str = "haar"
) -> tuple[np.ndarray, np.ndarray]:
    """The LOD approximation: decompose ``levels`` times and drop every detail band.

    Returns ``(coarse, reconstruction)``: ``coarse`` is (N0/M^levels, N1/M^levels) in height
    units (the orthonormal approximation divided by M^levels; for 'haar' the block means),
    ``reconstruction`` is the synthesis with zero details on the original grid, so
    ``max |reconstruction - a|`` is the approximation's geometric error (metres).
    """
    coeffs = mband_wavedec2(a, M, levels, kind)
    approx = np.asarray(coeffs[0])
    recon = mband_waverec2([approx, *({} for _ in range(levels))], M, kind)
    return approx / float(M) ** levels, recon


def mband_grid_kernel(M: int) -> np.ndarray:
    """Symmetric M-band low-pass for node grids: the linear B-spline (hat) mask.

    ``h_t = (M - |t|) / M^2`` for |t| < M: 2M-1 taps, unit sum. The hat function is
    M-refinable with mask (M - |t|)/M, so this is a genuine M-band scaling filter
    (biorthogonal family, not orthonormal). Symmetric with odd length: coarse node j stays on
    fine node M*j and linear ramps are reproduced exactly. For M = 2 it is [1, 2, 1]/4.
    """
    M = _check_m(M)
    t = np.arange(-(M - 1), M)
    return (M - np.abs(t)) / float(M * M)


def mband_approximate_grid(fine: np.ndarray, M: int) -> np.ndarray:
    """Grid-registered M-band approximation: (M*m+1, M*n+1) -> (m+1, n+1) nodes, float32.

    Coarse node (j, i) sits on fine node (M j, M i) and is the ``mband_grid_kernel(M)``
    weighted mean around it (separable). Same borders (odd mirror) and NaN rule as
    ``wavelet.approximate_grid``; the kernel has no negative taps, so every coarse node is a
    convex combination of valid heights.

    Raises:
        WaveletError (a ValueError): M < 2, not 2-D, or sides not of the form M*m+1.
    """
    return filter_decimate_grid(fine, mband_grid_kernel(M), _check_m(M))
