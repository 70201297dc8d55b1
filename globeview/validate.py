"""Checks of user-supplied numbers, shared by every layer: each refuses a bad value with a
one-line ValueError naming it and its valid range (the CLI prefixes the option, the window
shows it as is)."""

from __future__ import annotations

import math
import re

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "EXAGGERATION_RANGE",
    "TAU_RANGE_PX",
    "check_exaggeration",
    "check_finite",
    "check_number",
    "check_numbers",
    "check_tau",
    "format_number",
    "parse_float",
]

#: A number as people write one: ASCII digits with an optional fraction and exponent, or
#: nan/inf (refused later as not finite, with the reason). Python's float() also reads "1_0"
#: as 10 (a typo for 1.0 or 1,0 becomes a place 9 degrees away) and other scripts' digits.
_NUMBER = re.compile(
    r"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?|nan|inf|infinity)", re.ASCII | re.IGNORECASE
)


def parse_float(text: str) -> float:
    """``text`` (surrounding spaces allowed) as a float if it is a number as people write one
    (`_NUMBER`), else ValueError, as float() raises for what it does not read."""
    if not _NUMBER.fullmatch(text.strip()):
        raise ValueError(f"could not convert string to float: {text!r}")
    return float(text)


def format_number(value: float) -> str:
    """``value`` for a message: short (``%g``) when that is exactly the value, else every digit
    (``repr``), so a latitude of 90.0000001 does not read as 90 in "outside -90..90"."""
    short = f"{value:g}"
    return short if float(short) == value or not math.isfinite(value) else repr(float(value))


def check_number(name: str, value: float, lo: float, hi: float, unit: str = "") -> float:
    """``value`` as a float if it is finite and within ``lo..hi``; otherwise ValueError with
    one line naming ``name`` and the valid range (e.g. "latitude must be a finite number in
    -90..90 deg, not nan"). The CLI prefixes the option name; the window shows it as is."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, not {value!r}") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        span = f" in {lo:g}..{hi:g}{unit}" if math.isfinite(lo) or math.isfinite(hi) else ""
        raise ValueError(f"{name} must be a finite number{span}, not {format_number(v)}")
    return v


def check_finite(name: str, value: float) -> float:
    """``value`` as a float if it is finite, else ValueError naming ``name``."""
    return check_number(name, value, -math.inf, math.inf)


def check_numbers(
    name: str, values: ArrayLike, lo: float = -math.inf, hi: float = math.inf, unit: str = ""
) -> NDArray[np.float64]:
    """`check_number` for an array: ``values`` as float64 if every element is finite and within
    ``lo..hi``, else `check_number`'s ValueError for the first that is not."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers, not {values!r:.80}") from None
    bad = ~(np.isfinite(arr) & (arr >= lo) & (arr <= hi))
    if bad.any():
        check_number(name, float(arr[bad].flat[0]), lo, hi, unit)
    return arr


#: Screen-space error thresholds (pixels) a view accepts: 0 would ask for infinitely fine
#: terrain, and beyond 1000 px every tile is already coarser than the screen.
TAU_RANGE_PX = (0.05, 1000.0)
#: Vertical exaggerations a view accepts (0 = flat; 100 already lifts Everest to 885 km).
EXAGGERATION_RANGE = (0.0, 100.0)


def check_tau(tau_px: float) -> float:
    """``tau_px`` as a float, or ValueError (one line, with the valid range)."""
    return check_number("tau", tau_px, *TAU_RANGE_PX, " px")


def check_exaggeration(exaggeration: float) -> float:
    """``exaggeration`` as a float, or ValueError (one line, with the valid range)."""
    return check_number("exaggeration", exaggeration, *EXAGGERATION_RANGE)
