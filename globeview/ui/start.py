"""How the window starts when the command line asks for a view, an LOD provider, a tool or
settings (``globeview gui --camera ... --lod ... --tool ... --set ...``).

`WindowStart` is what `globeview gui` checked before any window exists (cli/view_options.py,
the same checks as `globeview render`); `apply_start` applies it to a `MainWindow`. No Qt is
imported here, so the command line builds a `WindowStart` before it knows there is a display.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["WindowStart", "apply_start"]


@dataclass(frozen=True)
class WindowStart:
    """What the window starts with (each None / empty: the window's own default).

    Attributes:
        camera: (lon, lat, height, heading, pitch, roll) degrees and metres above WGS84,
            checked (`cli.view_options.parse_camera`).
        lod: the LOD provider's contribution name.
        tool: the tool to activate once the globe is up.
        sets: ``NAME.KEY=VALUE`` texts with the option each came from, for this session
            only (not stored).
    """

    camera: tuple[float, ...] | None = None
    lod: str | None = None
    tool: str | None = None
    sets: tuple[tuple[str, str], ...] = ()

    def camera_object(self) -> Any:
        """The `Camera` of ``camera`` (None when none was given)."""
        if self.camera is None:
            return None
        from globeview.model.camera import Camera

        return Camera.from_lonlat(*self.camera)


def apply_start(window: Any, start: WindowStart) -> None:
    """Apply ``start`` to ``window`` (a `MainWindow` made with ``start.camera_object()``):
    the settings for this session (`apply_overrides`: nothing is stored), the LOD provider
    (the plugin panel's choice: a provider that fails to load falls back with a notice), and
    the tool, activated at once or when the globe's session exists (tools need it).
    The names and values were checked on the command line; if a plugin changed since, the
    window's own checks say so in one line (a dialog; the settings are not applied)."""
    from globeview.errors import GlobeviewError
    from globeview.plugins.settings import apply_overrides, resolve_plugin_args

    registry = window.plugins.registry
    if start.sets:
        try:
            assignments = resolve_plugin_args(registry, None, list(start.sets))
        except GlobeviewError as exc:  # a plugin changed since the command line's check
            window.errors.error(exc)
        else:
            apply_overrides(registry, assignments)
            window.plugins.refresh()  # the panel shows the provider's values as they are now
    if start.lod is not None:
        window.plugins.choose(start.lod)
    if start.tool is not None:
        _start_tool(window, start.tool)


def _start_tool(window: Any, name: str) -> None:
    """Activate tool ``name`` now if the globe's session exists, else once it does (the GL
    context comes with the first show)."""
    if window.globe.scene is not None:
        window.tools.set_tool(name)
        return

    def ready(_scene: object) -> None:
        window.globe.sceneReady.disconnect(ready)
        window.tools.set_tool(name)

    # After the window's own sceneReady handlers (plugins bound, tools listed).
    window.globe.sceneReady.connect(ready)
