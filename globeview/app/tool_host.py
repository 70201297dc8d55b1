"""`ToolHost`: the active tool, from the model's name to the terrain shader's displacement.

Activating a tool changes the model only (`Globe.tool`, an event) and asks the tool's plugin
for its displacement GLSL (`Tool.displacement_glsl`, plugin code: isolated by the registry,
garbage fails the tool). No GL happens then, so the window needs no current context to
switch tools. The GLSL is compiled into the terrain program at the start of the next frame
(`prepare_gpu`, which the frame pipeline calls first): a compile error there fails the
tool's contribution (reported in one line by the registry) and the globe's tool becomes None
(an event), so the terrain keeps the plain shader.

The globe's tool may also be set on the model directly (``globe.tool = name``): the host
follows it (deactivating the previous tool, fetching the new one's GLSL) on the event.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from globeview.app.host_checks import (
    has_method,
    hashable,
    overlay_problem,
    uniforms_problem,
)
from globeview.errors import GlobeviewError
from globeview.geodesy import ecef_to_lonlat, lonlat_to_ecef
from globeview.lod.culling import displacement_chord_error_m
from globeview.lod.view_state import ViewState
from globeview.model.globe import Globe
from globeview.model.plot import Plot
from globeview.plugins.api import PluginKind, Tool
from globeview.plugins.registry import PluginRegistry
from globeview.render.renderer import DisplacementHook, GlobeRenderer
from globeview.terrain.store.backend import TileNotReady

__all__ = ["ToolFrame", "ToolHost"]

#: The host's tool name before it first followed the model (no tool is a valid name: None).
_UNSET = object()


class ToolHost:
    """The active tool of ``globe``, its plugin calls isolated by ``registry``."""

    def __init__(self, globe: Globe, registry: PluginRegistry) -> None:
        self.globe = globe
        self.registry = registry
        self._name: Any = _UNSET  # the tool name the host last followed
        self._glsl: str | None = None  # that tool's displacement GLSL (None: none)
        self._installed: DisplacementHook | None = None  # what prepare_gpu compiled
        self._installed_key: tuple[str, str] | None = None
        self._marker_heights: dict[tuple[float, float, float], float] = {}
        globe.events.tool.connect(self._follow)

    def close(self) -> None:
        """Stop following the globe's tool (the session released its GL; the globe, a
        window's model, may outlive it)."""
        self.globe.events.tool.disconnect(self._follow, missing_ok=True)

    # -- the model side (no GL) --------------------------------------------------------------
    def find(self, name: str) -> Any:
        """The enabled tool ``name`` (importing only its plugin), or None."""
        return self.registry.find(PluginKind.TOOL, name)

    def activate(self, name: str | None) -> None:
        """Make ``name`` the active tool (None: no tool); refuses a name no enabled plugin
        provides (`GlobeviewError`, one line). Activating the active tool again asks it
        for its GLSL again (compiled at the next frame if the text changed)."""
        if name is not None and self.find(name) is None:
            raise GlobeviewError(f"no enabled tool named {name!r:.80}")
        if name == self.globe.tool:
            self._name = _UNSET  # the same tool again: fetch its GLSL afresh
        self.globe.tool = name  # the event makes the host follow
        self._follow()

    def tool(self) -> Any:
        """The active tool object, or None (also None once its plugin has failed, and
        then the globe's tool becomes None)."""
        self._follow()
        if self.globe.tool is None:
            return None
        tool = self.find(self.globe.tool)
        if tool is None:  # its plugin was disabled or failed
            self.globe.tool = None
        return tool

    @property
    def displaces(self) -> bool:
        """Whether the active tool moves the terrain (it has displacement GLSL that has
        not failed); true from activation on, before the GLSL is compiled."""
        return self.tool() is not None and self._glsl is not None

    def _follow(self, *_: object) -> None:
        """Catch up with ``globe.tool``: deactivate the tool the host followed before and
        fetch the new one's displacement GLSL (plugin calls, no GL)."""
        name = self.globe.tool
        if name == self._name:
            return
        previous, self._name, self._glsl = self._name, name, None
        if isinstance(previous, str) and previous != name:
            old = self.find(previous)
            if old is not None:
                self.registry.invoke(old, "deactivate")
        if name is None:
            return
        tool = self.find(name)
        if tool is None:
            self.globe.tool = None  # re-enters _follow with None
            return
        glsl = self.registry.invoke(tool, "displacement_glsl")
        if self.find(name) is None:  # displacement_glsl raised: the tool failed
            self.globe.tool = None
            return
        if glsl is not None and not isinstance(glsl, str):
            self.registry.fail(
                tool,
                TypeError(f"displacement_glsl() returned {type(glsl).__name__}, not GLSL text"),
            )
            self.globe.tool = None
            return
        self._glsl = glsl or None

    # -- the GPU side (at frame time, the context current) -----------------------------------
    def prepare_gpu(self, renderer: GlobeRenderer) -> None:
        """Bring ``renderer``'s displacement hook in line with the active tool: compile the
        tool's GLSL into the terrain program, or remove a hook no tool wants. A compile
        error fails the tool (reported) and leaves the plain program."""
        tool = self.tool()
        want = None
        if tool is not None and self._glsl is not None:
            want = (str(self.globe.tool), self._glsl)
        current = renderer.displacement_hook
        if want is not None and want == self._installed_key and current is self._installed:
            return
        if want is None:
            if current is not None:
                renderer.set_displacement_hook(None)
            self._installed = self._installed_key = None
            return
        hook = DisplacementHook(self.registry.owner_of(tool), want[1])
        try:
            renderer.set_displacement_hook(hook)
        except Exception as exc:  # noqa: BLE001  moderngl.Error: the plugin's GLSL failed to compile
            self.registry.fail(tool, exc)
            self.globe.tool = None
            if renderer.displacement_hook is not None:
                renderer.set_displacement_hook(None)
            self._installed = self._installed_key = None
            return
        self._installed, self._installed_key = hook, want

    # -- the tool's CPU side: displaced points, bend bounds, picks (checked) ------------------
    def fail(self, contribution: Any, problem: str) -> None:
        """Fail ``contribution`` (only it, not its plugin's others) for returning garbage
        (``problem``, one line)."""
        self.registry.fail(contribution, TypeError(problem))

    def checked_points(
        self, tool: Any, out: Any, points: np.ndarray, what: str
    ) -> np.ndarray | None:
        """``out`` as float64 points shaped like ``points`` and finite wherever ``points``
        is; otherwise the tool fails and None comes back."""
        try:
            arr = np.asarray(out, dtype=np.float64)
        except Exception:  # noqa: BLE001  plugin output may raise anything on conversion: the tool fails
            arr = None
        if arr is None or arr.shape != points.shape:
            got = "something else" if arr is None else f"shape {arr.shape}"
            self.fail(tool, f"{what}() returned {got} for points of shape {points.shape}")
            return None
        if not np.isfinite(arr).all() and (~np.isfinite(arr) & np.isfinite(points)).any():
            self.fail(tool, f"{what}() returned NaN or infinite coordinates")
            return None
        return arr

    def displace(self, points: np.ndarray) -> np.ndarray:
        """Where the active tool draws ECEF ``points`` (m; `Tool.displacement_numpy`), or
        ``points`` themselves without a tool or after it failed."""
        tool = self.tool()
        if tool is None:
            return points
        out = self.registry.invoke(tool, "displacement_numpy", points, default=None)
        if out is None:
            return points
        arr = self.checked_points(tool, out, np.asarray(points), "displacement_numpy")
        return points if arr is None else arr

    def to_true(self, drawn: np.ndarray) -> np.ndarray:
        """The true ECEF places of drawn points (`Tool.displacement_inverse_numpy`), or the
        drawn points when the tool has no inverse or it failed."""
        tool = self.tool()
        if tool is None:
            return drawn
        true = self.registry.invoke(tool, "displacement_inverse_numpy", drawn, default=None)
        arr = None
        if true is not None:
            arr = self.checked_points(tool, true, drawn, "displacement_inverse_numpy")
        return drawn if arr is None else arr

    def bend(self, points: np.ndarray, displaced: np.ndarray | None = None) -> np.ndarray:
        """The active tool's bend bound per point (m, `Tool.displacement_bend_m`); the exact
        chord measure when it returns None or its plugin has failed."""
        tool = self.tool()
        bend = None
        if tool is not None:
            bend = self.registry.invoke(tool, "displacement_bend_m", points, displaced)
        if bend is not None:
            try:
                arr = np.asarray(bend, dtype=np.float64)
            except Exception:  # noqa: BLE001  plugin output may raise anything on conversion: the tool fails
                arr = None
            want = np.shape(points)[:1]
            if arr is None or arr.shape != want or not (np.isfinite(arr) & (arr >= 0)).all():
                got = "something else" if arr is None else f"shape {arr.shape}"
                self.fail(
                    tool, f"displacement_bend_m() returned {got}, not {want} finite bends >= 0"
                )
            else:
                return arr
        return displacement_chord_error_m(self.displace, points, displaced)

    # -- what the tool publishes ----------------------------------------------------------------
    def plot(self) -> Plot | None:
        """The plot the active tool publishes now (`Tool.plot`, isolated), or None: no tool,
        a tool without one, or one that failed. Anything but a `Plot` or None fails the tool
        (one line; its plugin's other contributions stay). The window's Plot dock and
        ``render --tool-csv`` both take the plot from here."""
        tool = self.tool()
        if tool is None or not has_method(tool, "plot"):
            return None
        plot = self.registry.invoke(tool, "plot", default=None)
        if plot is not None and not isinstance(plot, Plot):
            self.fail(tool, f"plot() returned {type(plot).__name__}, not a Plot")
            return None
        return plot

    def plot_csv(self) -> str | None:
        """The CSV text of the plot the active tool publishes (`Plot.csv_text`), or None
        when it publishes none or fails: the text is made in isolation, as the tool's code
        (a plugin's `Plot` subclass may override what it calls)."""
        tool = self.tool()
        plot = self.plot()
        if tool is None or plot is None:
            return None
        text = self.registry.call_for(tool, Plot.csv_text, plot)
        return text if isinstance(text, str) else None

    # -- the tool in a frame -------------------------------------------------------------------
    def frame_tool(self, renderer: GlobeRenderer) -> ToolFrame | None:
        """The active tool's part in the next frame drawn by ``renderer``, or None."""
        tool = self.tool()
        return None if tool is None else ToolFrame(self, tool, renderer)

    def drape_marker(self, prim: Any) -> Any:
        """A marker on the ellipsoid (height < 1 m) lifted to the terrain surface (with the
        exaggeration), so it marks the ground the user clicked in oblique views too."""
        pos = getattr(prim, "position", None)
        if pos is None:
            return prim
        lon, lat, h = (float(v) for v in np.asarray(ecef_to_lonlat(np.asarray(pos))).ravel())
        terrain = self.globe.terrain
        if abs(h) >= 1.0 or not terrain.visible_layers:
            return prim
        exag = float(self.globe.display.exaggeration)
        key = (round(lon, 9), round(lat, 9), exag)
        ground = self._marker_heights.get(key)
        if ground is None:
            try:
                ground = float(terrain.height_at(lon, lat)) * exag
            except TileNotReady:
                # A remote tile not fetched yet on the UI thread (which never waits for the
                # network; it is fetched in the background): lifted by a later frame.
                return prim
            except GlobeviewError:  # no data there: keep it on the ellipsoid
                ground = 0.0
            if len(self._marker_heights) > 256:
                self._marker_heights.clear()
            self._marker_heights[key] = ground
        new = tuple(float(v) for v in np.asarray(lonlat_to_ecef(lon, lat, ground)).ravel())
        return replace(prim, position=new)


class ToolFrame:
    """The active tool's part in one frame (`globeview.render.frame_pipeline.FrameTool`):
    its animation step, CPU displacement, shader uniforms and overlay, each the plugin's
    code behind the host's checks. Garbage fails the tool (one line, its plugin's other
    contributions stay) and the neutral value comes back, so the frame goes on without it.
    The displacement hook itself is the tool host's (`ToolHost.prepare_gpu`): a frame never
    installs or drops it, except that a tool failing during the frame is taken out of the
    terrain shader at once (once: the tool stays failed)."""

    def __init__(self, host: ToolHost, tool: Any, renderer: GlobeRenderer) -> None:
        self.host = host
        self.tool = tool
        self.renderer = renderer

    def _active(self) -> bool:
        """Whether the tool is still the active one (it fails when it returns garbage)."""
        return self.host.tool() is self.tool

    def animate(self, now_s: float) -> bool:
        if not has_method(self.tool, "animate"):
            return False
        moving = self.host.registry.invoke(self.tool, "animate", now_s, default=False)
        try:
            return bool(moving)
        except Exception:  # noqa: BLE001  a hostile __bool__: the plugin's fault, not the frame's
            self.host.fail(self.tool, f"animate() returned {type(moving).__name__}")
            return False

    def shape_view(self, view: ViewState) -> ViewState:
        """``view`` plus the tool's CPU displacement (``displace``), its
        ``displacement_key()`` if it has one and, when the tool overrides
        `Tool.displacement_bend_m`, its bend bound (``displacement_bend``)."""
        host, tool = self.host, self.tool
        if not self._active() or not host.displaces:
            return view
        own_bend = getattr(type(tool), "displacement_bend_m", None) not in (
            None,
            Tool.displacement_bend_m,
        )
        key = None
        if has_method(tool, "displacement_key"):  # tools need not subclass Tool
            key = host.registry.invoke(tool, "displacement_key")
            if key is not None and not hashable(key):
                host.fail(tool, f"displacement_key() returned an unhashable {type(key).__name__}")
                return view
        return replace(
            view,
            displace=host.displace,
            displacement_bend=host.bend if own_bend else None,
            displacement_key=key,
        )

    def uniforms(self, view: ViewState) -> dict[str, object] | None:
        """The hook's ``gv_u_*`` uniforms for this frame (``{}`` without a hook, or when a
        tool has no ``displacement_uniforms`` or returns None); None when the tool failed
        (raised or returned garbage): its hook is then out of the terrain shader."""
        host, tool = self.host, self.tool
        if not self._active():
            return None
        if not host.displaces or not has_method(tool, "displacement_uniforms"):
            return {}
        failed = object()
        uniforms = host.registry.invoke(
            tool, "displacement_uniforms", view, default=failed, budgeted=True
        )
        if uniforms is None:
            return {}
        problem = None if uniforms is failed else uniforms_problem(uniforms)
        if problem is not None:
            host.fail(tool, f"displacement_uniforms() returned {problem}")
        if uniforms is failed or problem is not None:
            host.prepare_gpu(self.renderer)  # the tool failed: its hook goes, once
            return None
        return dict(uniforms)

    def overlay(self, view: ViewState) -> tuple[list, Any]:
        host, tool = self.host, self.tool
        if not self._active():
            return [], None
        prims = host.registry.invoke(tool, "overlay", view, default=None, budgeted=True)
        if not isinstance(prims, list | tuple) or not prims:
            if prims is not None and not isinstance(prims, list | tuple):
                host.fail(tool, f"overlay() returned {type(prims).__name__}, not a list")
            return [], None
        problem = overlay_problem(prims)
        if problem is not None:
            host.fail(tool, f"overlay() returned {problem}")
            return [], None
        displace = host.displace if host.displaces else None
        return [host.drape_marker(p) for p in prims], displace
