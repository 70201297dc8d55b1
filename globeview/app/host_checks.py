"""Checks of what plugin code hands the host (a tool's uniforms and overlay primitives, any
plugin object's methods): each returns what is wrong in one line, or None, so the caller
fails the plugin that returned garbage (`PluginRegistry.fail`) instead of the frame. The
checks of a layer type's drawables are with the models they become
(`globeview.model.overlay_layers.drawable_problem`)."""

from __future__ import annotations

import math
from collections.abc import Hashable
from numbers import Real

import numpy as np

from globeview.plugins.api import Marker, Polyline

__all__ = [
    "MAX_OVERLAY_PRIMITIVES",
    "finite_numbers",
    "has_method",
    "hashable",
    "overlay_problem",
    "uniforms_problem",
]


def has_method(obj: object, name: str) -> bool:
    """Whether ``obj`` (a plugin's object) has a callable ``name``; a hostile ``__getattr__``
    that raises counts as no."""
    try:
        return callable(getattr(obj, name, None))
    except Exception:  # noqa: BLE001  plugin objects may raise anything: a failed check
        return False


#: Most overlay primitives a tool may draw in one frame.
MAX_OVERLAY_PRIMITIVES = 100_000


def hashable(value: object) -> bool:
    if not isinstance(value, Hashable):
        return False
    try:
        hash(value)
    except Exception:  # noqa: BLE001  plugin objects may raise anything: a failed check
        return False
    return True


def finite_numbers(values: object, lengths: tuple[int, ...]) -> bool:
    """True for a real number (``1 in lengths``) or a sequence of ``lengths`` finite reals."""
    if isinstance(values, Real) and not isinstance(values, bool):
        return 1 in lengths and math.isfinite(values)
    if not isinstance(values, tuple | list) or len(values) not in lengths:
        return False
    return all(isinstance(v, Real) and not isinstance(v, bool) and math.isfinite(v) for v in values)


def uniforms_problem(uniforms: object) -> str | None:
    """What is wrong with a tool's ``displacement_uniforms`` result, or None."""
    if not isinstance(uniforms, dict):
        return f"{type(uniforms).__name__}, not a dict"
    for name, value in uniforms.items():
        if not isinstance(name, str) or not name.startswith("gv_u_"):
            return f"uniform name {name!r:.40} (names start with 'gv_u_')"
        if not finite_numbers(value, (1, 2, 3, 4)):
            return f"{name}={value!r:.40}, not a finite float or 2-4 finite floats"
    return None


def overlay_problem(prims: list | tuple) -> str | None:
    """What is wrong with a tool's ``overlay`` primitives, or None."""
    if len(prims) > MAX_OVERLAY_PRIMITIVES:
        return f"{len(prims)} primitives (at most {MAX_OVERLAY_PRIMITIVES})"
    for p in prims:
        if isinstance(p, Marker):
            if not finite_numbers(tuple(p.position), (3,)):
                return f"a Marker at {p.position!r:.60}, not 3 finite ECEF coordinates"
            if not isinstance(p.label, str):
                return f"a Marker label of {type(p.label).__name__}, not text"
        elif isinstance(p, Polyline):
            try:
                pts = np.asarray(p.points, dtype=np.float64)
            except Exception:  # noqa: BLE001  plugin objects may raise anything: a failed check
                return "a Polyline whose points are not numbers"
            if pts.ndim != 2 or pts.shape[1] != 3 or not np.isfinite(pts).all():
                return f"a Polyline with points of shape {pts.shape}, not finite (N, 3)"
            if not isinstance(getattr(p, "depth_test", True), bool):
                return f"a Polyline depth_test of {type(p.depth_test).__name__}, not a bool"
        else:
            return f"a {type(p).__name__}, not a Marker or Polyline"
    return None
