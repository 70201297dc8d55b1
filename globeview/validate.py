"""Checks of user-supplied numbers, shared by every layer: each refuses a bad value with a
one-line ValueError naming it and its valid range (the CLI prefixes the option, the window
shows it as is)."""

from __future__ import annotations

import math

__all__ = ["check_finite", "check_number"]


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
        raise ValueError(f"{name} must be a finite number{span}, not {v:g}")
    return v


def check_finite(name: str, value: float) -> float:
    """``value`` as a float if it is finite, else ValueError naming ``name``."""
    return check_number(name, value, -math.inf, math.inf)
