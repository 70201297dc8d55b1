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

from typing import Any

import numpy as np

from globeview.errors import GlobeviewError
from globeview.model.globe import Globe
from globeview.plugins.api import PluginKind
from globeview.plugins.registry import PluginRegistry
from globeview.render.renderer import DisplacementHook, GlobeRenderer

__all__ = ["ToolHost"]

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
        globe.events.tool.connect(self._follow)

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
        except Exception as exc:  # moderngl.Error: the plugin's GLSL failed to compile
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
        except Exception:
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
        from globeview.lod.culling import displacement_chord_error_m

        tool = self.tool()
        bend = None
        if tool is not None:
            bend = self.registry.invoke(tool, "displacement_bend_m", points, displaced)
        if bend is not None:
            try:
                arr = np.asarray(bend, dtype=np.float64)
            except Exception:
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
