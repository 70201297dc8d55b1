"""`Globe`: the application model, free of Qt and GL.

One globe view as plain objects: the camera, the terrain layers (`TerrainStack`), the
overlay layers, the active LOD provider and tool (by plugin contribution name), the
screen-space error threshold and the display settings. Every change emits an event under
``globe.events`` (psygnal signals); the Qt window and the renderer subscribe, nothing here
knows either. A render adapter (`globeview.render`) makes GPU objects from this state when a
frame is drawn, so changing the model never needs a GL context.
"""

from __future__ import annotations

from typing import Any, Final

from psygnal import Signal, SignalGroup, SignalInstance

from globeview.model.bookmarks import Bookmarks
from globeview.model.camera import Camera
from globeview.model.display import DisplaySettings
from globeview.terrain.compose.stack import TerrainStack
from globeview.validate import check_tau

#: Events emitted while an event is delivered wait for it to finish (see `GlobeEvents`).
_QUEUED: Final = "queued"

#: The LOD provider a new globe starts with (a built-in plugin contribution).
DEFAULT_LOD = "chunked-sse"


class GlobeEvents(SignalGroup):
    """The signals of a `Globe`. Each passes the new value (``terrain`` and ``overlays``
    pass nothing: read the globe).

    A listener may change the globe while an event is delivered (the tool host sets
    ``tool`` back to None when the named tool is unavailable): that event is queued until
    the current one reached every listener, so all listeners see the changes in order and
    the last event they see is the globe's state."""

    #: The camera moved or was replaced (argument: the `Camera`).
    camera = Signal(object, reemission=_QUEUED)
    #: The active LOD provider's name changed.
    lod = Signal(str, reemission=_QUEUED)
    #: The active tool's name changed (None: no tool).
    tool = Signal(object, reemission=_QUEUED)
    #: The screen-space error threshold (pixels) changed.
    tau_px = Signal(float, reemission=_QUEUED)
    #: Terrain layers were added, removed, moved, shown or hidden.
    terrain = Signal(reemission=_QUEUED)
    #: Overlay layers were added, removed, reordered, shown, hidden or restyled.
    overlays = Signal(reemission=_QUEUED)


class Globe:
    """The globe a user sees, as data.

    Args:
        terrain: the DEM layers, composed by priority.
        camera: where the viewer is (ECEF metres; default: 20 000 km above 0°E 20°N).
        lod: name of the active LOD provider contribution.
        tau_px: screen-space error threshold in pixels (`check_tau` range).
        display: display settings (evented on their own: ``globe.display.events``).
    """

    def __init__(
        self,
        terrain: TerrainStack,
        camera: Camera | None = None,
        *,
        lod: str = DEFAULT_LOD,
        tau_px: float = 2.0,
        display: DisplaySettings | None = None,
    ) -> None:
        self.events = GlobeEvents()
        self._terrain = terrain
        self._camera = camera or Camera.from_lonlat(0.0, 20.0, 2.0e7)
        self._lod = str(lod)
        self._tool: str | None = None
        self._tau_px = check_tau(tau_px)
        self.display = display if display is not None else DisplaySettings()
        self.overlays: list[Any] = []
        #: Named camera views (evented on their own: ``globe.bookmarks.changed``).
        self.bookmarks = Bookmarks()
        # psygnal holds the bound method weakly: a terrain outlives the globes shown on it
        # (a test session's shared stack, a window reopening a globe) without keeping them.
        terrain.changed.connect(self._terrain_changed)

    # -- terrain ---------------------------------------------------------------------------
    @property
    def terrain(self) -> TerrainStack:
        return self._terrain

    def _terrain_changed(self) -> None:
        self.events.terrain.emit()

    # -- camera ----------------------------------------------------------------------------
    @property
    def camera(self) -> Camera:
        return self._camera

    @camera.setter
    def camera(self, camera: Camera) -> None:
        self._camera = camera
        self.events.camera.emit(camera)

    def camera_moved(self) -> None:
        """Announce that the camera was moved in place (``camera.fly_yaw(...)`` etc.)."""
        self.events.camera.emit(self._camera)

    # -- LOD, tool, tau ----------------------------------------------------------------------
    @property
    def lod(self) -> str:
        """Name of the active LOD provider contribution."""
        return self._lod

    @lod.setter
    def lod(self, name: str) -> None:
        if not isinstance(name, str):
            raise TypeError(f"LOD provider name must be text, not {type(name).__name__}")
        if name != self._lod:
            self._lod = str(name)
            self.events.lod.emit(self._lod)

    @property
    def tool(self) -> str | None:
        """Name of the active tool contribution, or None."""
        return self._tool

    @tool.setter
    def tool(self, name: str | None) -> None:
        if name is not None and not isinstance(name, str):
            raise TypeError(f"tool name must be text or None, not {type(name).__name__}")
        if name != self._tool:
            self._tool = name
            self.events.tool.emit(name)

    @property
    def tau_px(self) -> float:
        """Screen-space error threshold (pixels). Refused where it is set (ValueError, one
        line with the valid range), so no frame trips over a NaN or zero tau."""
        return self._tau_px

    @tau_px.setter
    def tau_px(self, value: float) -> None:
        value = check_tau(value)
        if value != self._tau_px:
            self._tau_px = value
            self.events.tau_px.emit(value)

    # -- overlays --------------------------------------------------------------------------
    def add_overlay(self, layer: Any) -> None:
        """Show ``layer`` on top of the other overlays (ValueError if it is shown already:
        one layer object is one row, one GPU twin)."""
        if any(ly is layer for ly in self.overlays):
            raise ValueError(f"overlay {getattr(layer, 'name', layer)!r:.60} is shown already")
        self.overlays.append(layer)
        changed = getattr(layer, "changed", None)
        if isinstance(changed, SignalInstance):
            # The layer's own setters (visibility, opacity, style), called by the window, by
            # code or by a plugin, reach every listener as one `overlays` event. psygnal holds
            # this bound method weakly: a layer does not keep a dropped globe alive.
            changed.connect(self._overlay_changed)
        self.events.overlays.emit()

    def remove_overlay(self, layer: Any) -> None:
        """Take ``layer`` (this very object) off the globe (ValueError if it is not shown)."""
        # By identity, not ==: a layer's fields may be numpy arrays, and two layers opened
        # from one file hold equal data yet are two rows.
        index = self._index(layer)
        del self.overlays[index]
        changed = getattr(layer, "changed", None)
        if isinstance(changed, SignalInstance):
            changed.disconnect(self._overlay_changed, missing_ok=True)
        self.events.overlays.emit()

    def _index(self, layer: Any) -> int:
        """Position of ``layer`` (by identity) in the overlays; ValueError if absent."""
        for i, ly in enumerate(self.overlays):
            if ly is layer:
                return i
        raise ValueError(f"overlay {getattr(layer, 'name', layer)!r:.60} is not shown")

    def set_overlay_order(self, layers: list[Any]) -> None:
        """Reorder the overlays (bottom first); ``layers`` must be the same layers."""
        if sorted(map(id, layers)) != sorted(map(id, self.overlays)):
            raise ValueError("set_overlay_order: not a reordering of the globe's overlays")
        if [id(ly) for ly in layers] != [id(ly) for ly in self.overlays]:
            self.overlays[:] = layers
            self.events.overlays.emit()

    def overlays_changed(self) -> None:
        """Announce an in-place change of an overlay made without its setters (e.g. an
        attribute written directly). The setters (``layer.set_visible(False)``,
        ``set_opacity``, ``set_style``) announce themselves: one event per real change."""
        self.events.overlays.emit()

    def _overlay_changed(self) -> None:
        self.events.overlays.emit()
