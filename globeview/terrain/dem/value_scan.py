"""A DEM block's statistics in its own dtype (issue #25 C6): the counts of candidate fill
values, the samples outside the possible heights and the range of the others.

`Dem._scan_values` reads every block of a source (up to 50 M pixels) to find undeclared fills
and the value range. It converted each block to float64 and compared it with every candidate
fill (a dozen passes over the block). For a source whose stored values are its heights
(scale 1, offset 0) the same answers come from the block as stored: the block's min and max
first; a candidate outside them cannot be present, and inside [limits] with no candidate
present nothing needs a mask at all (one pass of min and max for a typical tile). Every
comparison stays exact: a candidate is compared in the block's dtype only where that dtype
represents it exactly (no value of the block can equal one it does not), and the block's min,
max and the limits are compared as Python floats (float64, which holds every int16, uint16,
int32 and float32 exactly).

Heights in metres; NaN is no data (not counted); +-inf is outside the limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BlockStats", "native_scan_applies", "scan_block"]


@dataclass(frozen=True)
class BlockStats:
    """counts: per candidate (as given), the samples equal to it; masked: samples that are
    neither NaN, nodata nor a candidate and lie outside [lo_limit, hi_limit] (or are +-inf);
    lo, hi: the range of the others (inf, -inf when there are none)."""

    counts: np.ndarray
    masked: int
    lo: float
    hi: float


def native_scan_applies(dtype: np.dtype) -> bool:
    """Whether `scan_block` is exact for blocks of this dtype (float64 holds its values)."""
    return (dtype.kind in "iu" and dtype.itemsize <= 4) or dtype in (np.float32, np.float64)


def _exact_in(dtype: np.dtype, value: float) -> bool:
    """Whether ``value`` (float64) is a value of ``dtype`` (so a sample may equal it)."""
    if dtype.kind == "f":  # in range first: a cast of a larger float overflows
        return abs(value) <= float(np.finfo(dtype).max) and bool(dtype.type(value) == value)
    info = np.iinfo(dtype)
    return value.is_integer() and info.min <= value <= info.max


def scan_block(
    a: np.ndarray,
    nodata: float | None,
    candidates: np.ndarray,
    lo_limit: float,
    hi_limit: float,
) -> BlockStats:
    """The statistics of one block of raw samples ``a`` (native dtype, see
    `native_scan_applies`) whose values are heights: what `Dem._scan_values` computed in
    float64, exactly. ``candidates``: float64 fill candidates (nodata not among them)."""
    v = a.ravel()
    if v.dtype.kind == "f" and np.isnan(v).any():
        v = v[~np.isnan(v)]
    if nodata is not None and _exact_in(v.dtype, nodata):
        at_nodata = v == v.dtype.type(nodata)
        if at_nodata.any():
            v = v[~at_nodata]
    counts = np.zeros(candidates.size, dtype=np.int64)
    if v.size == 0:
        return BlockStats(counts, 0, np.inf, -np.inf)
    lo, hi = float(v.min()), float(v.max())
    fill: np.ndarray | None = None  # the samples equal to a candidate
    for i, c in enumerate(candidates):
        if lo <= c <= hi and _exact_in(v.dtype, float(c)):
            at_c = v == v.dtype.type(c)
            counts[i] = np.count_nonzero(at_c)
            if counts[i]:
                fill = at_c if fill is None else fill | at_c
    if fill is not None:
        v = v[~fill]
        if v.size == 0:
            return BlockStats(counts, 0, np.inf, -np.inf)
        lo, hi = float(v.min()), float(v.max())
    if lo_limit <= lo and hi <= hi_limit:
        return BlockStats(counts, 0, lo, hi)
    # Some samples lie outside the limits (or are +-inf): compared in float64, exactly.
    h = v.astype(np.float64)
    ok = (h >= lo_limit) & (h <= hi_limit)
    n_ok = int(np.count_nonzero(ok))
    if n_ok == 0:
        return BlockStats(counts, int(h.size), np.inf, -np.inf)
    return BlockStats(counts, int(h.size - n_ok), float(h[ok].min()), float(h[ok].max()))
