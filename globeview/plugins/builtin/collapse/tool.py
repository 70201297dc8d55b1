"""`collapse`: the terrain-collapse tool (Wang thesis ch. 6, on the ellipsoid).

Pick A, then B: the land between them is squeezed along the A->B axis by the ratio r (the
zone's length becomes r times as long) and the land beyond slides rigidly toward the zone,
so two distant patches come side by side. The displacement runs in the terrain vertex shader
(collapse.glsl, package data read by `collapse_glsl`); `CollapseFrame` (geometry.py) is its
float64 CPU twin, used for LOD bounds, overlays, and (inverted) for picking. See docs/collapse.md.

State machine: ``idle`` -> (press) ``a_set`` -> (press) collapsing animation -> collapsed; a
third press starts a new pair (the picking is the API's `TwoPointPick`). 'e' expands
(animated), 'c' collapses again, Escape cancels (points cleared at once).
The animation is host-driven: the host calls ``animate(now_s)`` each frame with a monotonic
time in seconds and redraws while it returns True; nothing here needs Qt or a timer.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

from globeview.plugins.api import (
    GlobeviewError,
    KeyEvent,
    Marker,
    Overlay,
    PointerEvent,
    Polyline,
    Setting,
    Tool,
    TwoPointPick,
    lonlat_to_ecef,
)
from globeview.plugins.builtin.collapse.geometry import CollapseFrame, ellipsoid_point_along

__all__ = ["CollapseTool"]


@cache
def collapse_glsl() -> str:
    """The displacement hook's GLSL (collapse.glsl beside this module, read once)."""
    return resources.files(__spec__.parent).joinpath("collapse.glsl").read_text(encoding="utf-8")


#: Duration of the collapse / expand animation (s).
ANIMATION_S = 0.5
#: While animating, the LOD's bend bound is that of the effective ratio rounded toward the
#: final one to one of this many steps (recomputed at each step only).
BEND_STEPS = 4


def _ease(p: float) -> float:
    """Smoothstep easing of a progress in [0, 1]."""
    p = min(max(p, 0.0), 1.0)
    return p * p * (3.0 - 2.0 * p)


class CollapseTool(Tool):
    """Collapse the terrain between two picked points (see the module docstring).

    Settings: ``ratio`` r in (0, 1] (fraction of the zone's along-axis length kept),
    ``animate`` (animate collapse/expand over 0.5 s).
    """

    name = "collapse"
    label = "Collapse terrain"
    settings = (
        Setting("ratio", "float", 0.2, min=0.01, max=1.0, label="Ratio",
                help="Fraction of the A-B distance kept after the collapse (1 = none)."),
        Setting("animate", "bool", True, label="Animate",
                help="Animate collapsing and expanding over half a second."),
    )  # fmt: skip

    def __init__(self, context: Any = None) -> None:
        super().__init__(context)
        #: A and B, (lon, lat) degrees: picked by clicks or set by `set_points`.
        self.pick = TwoPointPick()
        self.ratio: float = float(self.values["ratio"])
        self.progress: float = 0.0  # 0 = expanded, 1 = fully collapsed
        self._target: float = 0.0
        self._anim_from: float = 0.0
        self._anim_start: float | None = None
        self._frame: CollapseFrame | None = None  # cached for (a, b, effective ratio)
        self._last: CollapseFrame | None = None  # the last frame made (its feet are reused)
        self._overlay: tuple | None = None  # (key, frame, primitives) of the last overlay()
        # While animating: (feet memo, the frame of the current bend step, its bends by
        # lattice bytes).
        self._extreme: tuple | None = None

    # -- state -----------------------------------------------------------------------------
    @property
    def a(self) -> tuple[float, float] | None:
        """Point A, (lon, lat) degrees, or None."""
        return self.pick.a

    @property
    def b(self) -> tuple[float, float] | None:
        """Point B, (lon, lat) degrees, or None."""
        return self.pick.b

    def configure(self, values: dict[str, Any]) -> None:
        super().configure(values)
        self.ratio = float(self.values["ratio"])
        self._frame = None

    @property
    def state(self) -> str:
        """'idle' (no points), 'a_set' (A picked), 'expanded', 'collapsing', 'collapsed',
        'expanding'."""
        if self.a is None:
            return "idle"
        if self.b is None:
            return "a_set"
        if self._anim_start is not None or self.progress not in (0.0, 1.0):
            return "collapsing" if self._target == 1.0 else "expanding"
        return "collapsed" if self.progress == 1.0 else "expanded"

    @property
    def effective_ratio(self) -> float:
        """The ratio drawn now: 1 when expanded, ``ratio`` when collapsed, eased between."""
        return 1.0 + (self.ratio - 1.0) * _ease(self.progress)

    def frame(self) -> CollapseFrame | None:
        """The current `CollapseFrame` (with the effective ratio), or None without A and B."""
        if self.a is None or self.b is None:
            return None
        r = self.effective_ratio
        f = self._frame
        if f is None or (f.ratio != r and f.psi0 > 0.0):
            # The same A and B at another ratio (the animation): keep the memo of feet.
            last = self._last
            same = last is not None and (last.lon_a, last.lat_a) == self.a
            feet = (
                last.feet
                if last is not None and same and (last.lon_b, last.lat_b) == self.b
                else None
            )
            f = CollapseFrame.from_lonlat(*self.a, *self.b, r, feet)
            self._frame = self._last = f
        return f

    def set_points(
        self,
        lon_a: float,
        lat_a: float,
        lon_b: float,
        lat_b: float,
        ratio: float | None = None,
        animate: bool = False,
    ) -> None:
        """Set A and B (degrees) and collapse with ``ratio`` (default: the setting); at once
        unless ``animate``. Raises ValueError for an impossible pair (near-antipodal)."""
        r = self.ratio if ratio is None else float(ratio)
        CollapseFrame.from_lonlat(lon_a, lat_a, lon_b, lat_b, r)  # validate
        self.ratio = r
        self.pick.a, self.pick.b = (float(lon_a), float(lat_a)), (float(lon_b), float(lat_b))
        self._frame = None
        if animate:
            self.progress = 0.0
            self._start(1.0)
        else:
            self.progress, self._target, self._anim_start = 1.0, 1.0, None
        self.request_redraw()

    def place_points(self, points: Sequence[tuple[float, float]]) -> bool:
        """Headless input (`Tool.place_points`): A and B, collapsed at once to the ``ratio``
        setting (a headless frame has no time to animate). One-line `GlobeviewError` for
        anything but two points or an impossible pair."""
        if len(points) != 2:
            raise GlobeviewError(f"the collapse tool takes two points A and B, not {len(points)}")
        (lon_a, lat_a), (lon_b, lat_b) = points
        try:
            self.set_points(lon_a, lat_a, lon_b, lat_b)
        except ValueError as exc:
            raise GlobeviewError(f"collapse: {exc}") from None
        return True

    def collapse(self) -> None:
        """Collapse (animated if the setting says so) the current A-B pair."""
        if self.b is not None:
            self._start(1.0)

    def expand(self) -> None:
        """Expand back to the true terrain (animated if the setting says so), keeping A, B."""
        if self.b is not None:
            self._start(0.0)

    def cancel(self) -> None:
        """Drop A and B: the terrain is drawn true at once."""
        self.pick.clear()
        self._uncollapse()

    def _uncollapse(self) -> None:
        """Draw the terrain true at once (no animation; the points are kept)."""
        self.progress, self._target, self._anim_start = 0.0, 0.0, None
        self._frame = None
        self.request_redraw()

    def _check_pair(self, a: tuple[float, float], b: tuple[float, float]) -> None:
        """ValueError for a pair the collapse cannot fold (near-antipodal)."""
        CollapseFrame.from_lonlat(*a, *b, self.ratio)

    def _start(self, target: float) -> None:
        self._target = target
        self._frame = None
        if not self.values.get("animate", True):
            self.progress, self._anim_start = target, None
        else:
            self._anim_from = self.progress
            self._anim_start = math.nan  # started by the next animate(now)
        self.request_redraw()

    def animate(self, now_s: float) -> bool:
        """Advance the animation to time ``now_s`` (s, any monotonic clock; the first call
        after a start fixes its origin). Returns True while animating (redraw again)."""
        if self._anim_start is None:
            return False
        if math.isnan(self._anim_start):
            self._anim_start = float(now_s)
        span = self._target - self._anim_from
        frac = 1.0 if span == 0.0 else (float(now_s) - self._anim_start) / ANIMATION_S
        frac = min(max(frac, 0.0), 1.0)
        self.progress = self._anim_from + span * frac
        self._frame = None
        if frac >= 1.0:
            self.progress, self._anim_start = self._target, None
            return False
        return True

    # -- events ------------------------------------------------------------------------------
    def on_mouse(self, event: PointerEvent) -> bool:
        """Left press on terrain: first sets A, second sets B and collapses; a press after
        that starts a new pair (`TwoPointPick`); a B the collapse cannot fold is refused
        with a status line."""
        try:
            step = self.pick.on_mouse(event, check=self._check_pair)
        except ValueError as exc:
            self.set_status(f"collapse: {exc}")
            return True
        if step is None:
            return False
        if step == "a":
            lon, lat = self.pick.a  # the point just picked
            self._uncollapse()
            self.set_status(f"collapse: A at {lon:.4f}, {lat:.4f}; pick B")
            return True
        self.progress = 0.0
        self._start(1.0)
        f = self.frame()
        d_km = 0.0 if f is None else CollapseFrame.from_lonlat(*self.a, *self.b, 1.0).d_m / 1e3
        self.set_status(f"collapse: {d_km:.1f} km collapsed to {self.ratio * d_km:.1f} km")
        return True

    def on_key(self, event: KeyEvent) -> bool:
        """Escape cancels, 'e' expands, 'c' collapses again."""
        if event.kind != "press":
            return False
        if self.pick.on_key(event):  # Escape: A and B cleared
            self._uncollapse()
            return True
        if event.key.lower() == "e" and self.b is not None:
            self.expand()
            return True
        if event.key.lower() == "c" and self.b is not None:
            self.collapse()
            return True
        return False

    def deactivate(self) -> None:
        """Leaving the tool keeps nothing collapsed."""
        self.cancel()

    # -- overlay -----------------------------------------------------------------------------
    def overlay(self, view: Any) -> list[Overlay]:
        """Markers at A and B and the two fold lines (zone edges), in **true** ECEF (m) on
        the ellipsoid: the host applies ``displacement_numpy`` to overlays, which puts them
        where the collapsed terrain is drawn. The central axis A-B is drawn thin. The lines lie
        on the ellipsoid, under any relief: they are feedback drawn on top (``depth_test=
        False``; the host drops what is beyond the horizon), not hidden by the mountains."""
        f = self.frame()
        # The primitives depend on A, B and the frame only (not on the view): made once per
        # frame object, so a still collapse does not rebuild its lines every redraw.
        key = (self.a, self.b, id(f))
        if self._overlay is not None and self._overlay[0] == key and self._overlay[1] is f:
            return list(self._overlay[2])
        out = self._make_overlay(f)
        self._overlay = (key, f, out)
        return list(out)

    def _make_overlay(self, f: CollapseFrame | None) -> list[Overlay]:
        out: list[Overlay] = []
        for p, label in ((self.a, "A"), (self.b, "B")):
            if p is not None:
                pos = lonlat_to_ecef(p[0], p[1], 0.0)
                out.append(Marker(tuple(float(v) for v in pos), (1.0, 0.3, 0.1, 1.0), 10.0, label))
        if f is None or f.psi0 == 0.0:
            return out
        half = min(max(2.0 * f.psi0, 0.002), 0.6)  # cross-axis extent (rad)
        for psi in (-f.psi0, f.psi0):
            out.append(
                Polyline(f.edge_line(psi, half), (1.0, 0.9, 0.1, 1.0), 2.0, depth_test=False)
            )
        psis = np.linspace(-f.psi0, f.psi0, 64)
        dirs = np.cos(psis)[:, None] * f.m + np.sin(psis)[:, None] * f.t
        axis = ellipsoid_point_along(dirs)
        out.append(Polyline(axis, (1.0, 1.0, 1.0, 0.6), 1.0, depth_test=False))
        return out

    # -- displacement hook -----------------------------------------------------------------
    def displacement_glsl(self) -> str:
        """The vertex-shader twin of `CollapseFrame.forward` (collapse.glsl)."""
        return collapse_glsl()

    def displacement_uniforms(self, view: Any) -> dict[str, float | tuple[float, ...]]:
        """Uniforms for this frame: M - eye in float64, the frame axes, the map knots."""
        f = self.frame()
        if f is None:
            return {"gv_u_map": (0.0, 0.0, 1.0, 0.0)}
        return f.gpu_uniforms(view.eye)

    def displacement_key(self) -> tuple | None:
        """A hashable summary of the current displacement (None = identity): hosts may key
        caches on it (e.g. an LOD provider's per-view cache) instead of disabling them."""
        f = self.frame()
        if f is None or f.psi0 == 0.0 or f.ratio == 1.0:
            return None
        return (self.a, self.b, f.ratio)

    def displacement_numpy(self, points_ecef: np.ndarray) -> np.ndarray:
        """True ECEF points (N, 3) -> where the collapsed terrain draws them."""
        f = self.frame()
        pts = np.asarray(points_ecef, dtype=np.float64)
        return pts if f is None else f.forward(pts)

    def displacement_bend_m(
        self, points_ecef: np.ndarray, displaced: np.ndarray | None = None
    ) -> np.ndarray:
        """A cheap upper bound of the collapse's bend per tile bounding lattice (N, K, 3) ->
        (N,) m: `CollapseFrame.bend_bound_m` (exact only for tiles a fold line crosses).

        While the collapse animates, the bound of a slightly more collapsed frame: the
        effective ratio rounded toward the ``ratio`` setting to one of `BEND_STEPS` steps
        (the effective ratio stays between the setting and 1). The map is a rotation by
        (1 - r) g(psi) with g fixed by A and B, and its bend grows with 1 - r (checked against
        the exact measure in tests/collapse/test_collapse_feet.py), so that bound covers the
        frame drawn; it changes only at each step, so it is computed once per lattice and
        step and looked up by the lattice's bytes in between, instead of measuring every
        tile again at every ratio. The steps keep the refinement close to the animation's
        (rounding to the final ratio at once would draw the final triangles from the start)."""
        f = self.frame()
        pts = np.asarray(points_ecef, dtype=np.float64)
        if f is None:
            return np.zeros(len(pts))
        if self.state not in ("collapsing", "expanding") or self.ratio >= f.ratio:
            return f.bend_bound_m(pts, displaced)
        share = (1.0 - f.ratio) / (1.0 - self.ratio)  # how far collapsed, 0..1
        step = min(math.ceil(share * BEND_STEPS - 1e-9), BEND_STEPS)
        r_step = 1.0 - (1.0 - self.ratio) * step / BEND_STEPS
        ext = self._extreme
        if ext is None or ext[0] is not f.feet or ext[1].ratio != r_step:
            ext = (f.feet, f.with_ratio(r_step), {})
            self._extreme = ext
        memo: dict = ext[2]
        p = np.ascontiguousarray(pts)
        key = (p.shape, p.tobytes())
        bend = memo.get(key)
        if bend is None:
            if len(memo) >= 128:
                memo.clear()
            bend = memo[key] = ext[1].bend_bound_m(p)
        return bend.copy()

    def displacement_inverse_numpy(self, points_ecef: np.ndarray) -> np.ndarray:
        """Drawn ECEF points (N, 3) -> true ones (exact inverse of ``displacement_numpy``)."""
        f = self.frame()
        pts = np.asarray(points_ecef, dtype=np.float64)
        return pts if f is None else f.inverse(pts)
