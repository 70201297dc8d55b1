"""`GlobeWidget`: the OpenGL view of a `Globe` model, drawn by a `GlobeSession`.

The widget holds no state of the globe: camera, tau, LOD provider, tool, overlays and
display settings are the model's (``widget.model``), and every change of the model (its
psygnal events) schedules a frame. The moderngl context is created in ``initializeGL`` from
Qt's current context and the session is built there on the model; each frame is one
``session.render(fbo, viewport)`` into ``ctx.detect_framebuffer()`` (Qt's framebuffer
object, not framebuffer 0): the frame pipeline derives the camera speed, steps the tool's
animation and draws its overlay itself. Frames are drawn on demand only (``update()``);
there is no busy timer, so an idle globe costs nothing.

Pixel coordinates handed to the scene (picking, navigation) are framebuffer pixels, top-left
origin: Qt's logical coordinates times ``devicePixelRatio``.

Tools (the model's ``tool``, an enabled tool plugin): a left click — press and release
without moving more than `CLICK_SLOP_PX` — goes to the tool as a ``press`` and a ``release``
`PointerEvent` (with the true, un-displaced picked point), a drag still navigates; cursor
moves, wheel steps and key presses go to the tool first and to navigation when it does not
consume them. Escape also deactivates the tool (the model's tool is None). While the frame says
the tool animates (``FrameResult.animating``) a 16 ms timer keeps frames coming.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import replace

import moderngl
import numpy as np
from PyQt6.QtCore import QEvent, QPointF, Qt, QTimer, pyqtSignal
from PyQt6.QtGui import (
    QImage,
    QKeyEvent,
    QMouseEvent,
    QSurfaceFormat,
    QWheelEvent,
)
from PyQt6.QtOpenGLWidgets import QOpenGLWidget
from PyQt6.QtWidgets import QWidget

from globeview.app.overlay_host import OverlayHost
from globeview.app.session import DEFAULT_LOD, GlobeSession
from globeview.lod.render_set import FrameStats
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera, camera_for_bounds
from globeview.model.display import DisplaySettings
from globeview.model.globe import Globe
from globeview.plugins.api import KeyEvent, PointerEvent
from globeview.plugins.registry import PluginRegistry
from globeview.render.picking import Pick
from globeview.ui.navigation import HOME_POSE, CameraFlight, Navigator
from globeview.ui.subscriptions import Subscriptions

log = logging.getLogger("globeview.ui")

#: OpenGL version the renderer needs (multi-draw indirect needs 4.3 where available; 3.3 is
#: the floor moderngl's programs need).
GL_VERSION = (3, 3)
#: A left press and release closer than this (framebuffer pixels) is a click for the tool.
CLICK_SLOP_PX = 4.0
#: Repaint interval while a tool animates (ms).
ANIMATION_INTERVAL_MS = 16
#: While tiles load in the background, at most one frame per this interval (ms) shows the
#: tiles finished so far (the frame after the last tile comes at once). Redrawing in a busy
#: loop took a core from the tile workers on a 2-core machine for frames that mostly showed
#: nothing new: a White Mountains loading frame costs 60-100 ms of CPU while 387 tiles cost
#: ~0.5 s to build, and the ancestors it draws change little until the last tiles land
#: (issue #17).
LOADING_FRAME_MS = 500
#: With a remote layer, the cursor is picked again this long after the mouse stops (ms): the
#: UI thread never waits for the network, so a pick over a finest tile not fetched yet is the
#: depth buffer's (unrefined) point while the store fetches the tile in the background; the
#: second pick reads the tile from the cache and refines the height the status bar shows.
REPICK_MS = 400
#: Picks again at most this many times while the cursor rests (a slow server's tile may take
#: a few intervals); each is one depth read and a refine on cached tiles.
REPICK_TRIES = 5

#: Qt keys -> `KeyEvent.key` names (printable keys use their lower-case text).
_KEY_NAMES = {
    Qt.Key.Key_Escape: "Escape",
    Qt.Key.Key_Return: "Return",
    Qt.Key.Key_Enter: "Return",
    Qt.Key.Key_Space: "space",
    Qt.Key.Key_Tab: "Tab",
    Qt.Key.Key_Backspace: "BackSpace",
    Qt.Key.Key_Delete: "Delete",
    Qt.Key.Key_Left: "Left",
    Qt.Key.Key_Right: "Right",
    Qt.Key.Key_Up: "Up",
    Qt.Key.Key_Down: "Down",
    Qt.Key.Key_Home: "Home",
    Qt.Key.Key_End: "End",
    Qt.Key.Key_PageUp: "Prior",
    Qt.Key.Key_PageDown: "Next",
}


def key_name(key: int, text: str) -> str:
    """The `KeyEvent.key` name of a Qt key: "a", "1", "Escape", "Left", ... ("" if none)."""
    try:
        name = _KEY_NAMES.get(Qt.Key(key))
    except ValueError:
        name = None
    if name is not None:
        return name
    if text and text.isprintable():
        return text.lower()
    return ""


def modifier_names(mods: Qt.KeyboardModifier) -> frozenset[str]:
    """``shift``/``ctrl``/``alt``/``meta`` of a Qt modifier set."""
    m = Qt.KeyboardModifier
    table = (
        (m.ShiftModifier, "shift"),
        (m.ControlModifier, "ctrl"),
        (m.AltModifier, "alt"),
        (m.MetaModifier, "meta"),
    )
    return frozenset(name for flag, name in table if mods & flag)


def button_name(button: Qt.MouseButton) -> str | None:
    b = Qt.MouseButton
    return {b.LeftButton: "left", b.MiddleButton: "middle", b.RightButton: "right"}.get(button)


def button_names(buttons: Qt.MouseButton) -> frozenset[str]:
    b = Qt.MouseButton
    table = ((b.LeftButton, "left"), (b.MiddleButton, "middle"), (b.RightButton, "right"))
    return frozenset(name for flag, name in table if buttons & flag)


def surface_format() -> QSurfaceFormat:
    """OpenGL 3.3 core profile, 24-bit depth, no multisampling (depth is read back for
    picking, which a multisampled framebuffer does not allow)."""
    fmt = QSurfaceFormat()
    fmt.setRenderableType(QSurfaceFormat.RenderableType.OpenGL)
    fmt.setVersion(*GL_VERSION)
    fmt.setProfile(QSurfaceFormat.OpenGLContextProfile.CoreProfile)
    fmt.setDepthBufferSize(24)
    fmt.setStencilBufferSize(8)
    fmt.setSamples(0)
    fmt.setSwapInterval(1)
    return fmt


class GlobeWidget(QOpenGLWidget):
    """The globe view.

    Args:
        model: the `Globe` to show (terrain, camera, tau, LOD provider, tool, overlays,
            display settings); the session is built on it once GL is up, and every change of
            it (its events) schedules a frame.
        registry: the plugin registry the `GlobeSession` takes its LOD providers from.
        subscriptions: the window's model subscriptions (default: the widget's own).
        overlays: the `OverlayHost` that opens overlays onto ``model`` without GL (default: a
            new one); the session draws what it opened.

    Signals:
        sceneReady(object): the `GlobeSession`, once the GL context exists.
        frameRendered(object, float): each frame's `FrameStats` and the frame rate (Hz).
        cursorPicked(object): the `Pick` under the cursor (or None) as the mouse moves.
        renderFailed(object): an exception while drawing (the widget keeps running).
        keyUnhandled(int, object): a key press neither the tool nor navigation took (Qt key,
            modifiers): the window matches it against the tool actions' shortcuts.
    """

    sceneReady = pyqtSignal(object)
    frameRendered = pyqtSignal(object, float)
    cursorPicked = pyqtSignal(object)
    renderFailed = pyqtSignal(object)
    keyUnhandled = pyqtSignal(int, object)
    #: Emitted on a tile worker thread when a background tile finished; queued to the UI
    #: thread (`_tiles_ready`).
    _tileReady = pyqtSignal()

    def __init__(
        self,
        model: Globe,
        registry: PluginRegistry,
        parent: QWidget | None = None,
        subscriptions: Subscriptions | None = None,
        overlays: OverlayHost | None = None,
    ) -> None:
        super().__init__(parent)
        self.setFormat(surface_format())
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.setMouseTracking(True)
        self.setMinimumSize(200, 150)
        #: The globe shown (camera, layers, tau, LOD, tool, display): the widget draws it and
        #: redraws when it changes; it holds no copy of that state.
        self.model = model
        self.terrain = model.terrain
        self.registry = registry
        #: Opens overlays onto the model, GL or not (the window's); the session uses it.
        self.overlays = OverlayHost(model, registry) if overlays is None else overlays
        self.ctx: moderngl.Context | None = None
        self.scene: GlobeSession | None = None
        self.frames = 0
        self.fps = 0.0
        self._last_paint = 0.0
        self._render_error: str | None = None
        self.flight = CameraFlight(model, self)
        self.flight.stepped.connect(self._camera_moved)
        self.flight.started.connect(self.prefetch_pose)
        self.flight.stopped.connect(self._drop_prefetch)
        self.navigator: Navigator | None = None
        # Frames while tiles stream in: scheduled by finished tiles, throttled.
        self._loading_frame = QTimer(self)
        self._loading_frame.setSingleShot(True)
        self._loading_frame.setInterval(LOADING_FRAME_MS)
        self._loading_frame.timeout.connect(self.update)
        self._tileReady.connect(self._tiles_ready)
        # One extra frame after motion stops, so the speed-dependent LOD settles.
        self._settle = QTimer(self)
        self._settle.setSingleShot(True)
        self._settle.setInterval(150)
        self._settle.timeout.connect(self.update)
        # Tools: animation repaints, the pending left click.
        self._anim = QTimer(self)
        self._anim.setInterval(ANIMATION_INTERVAL_MS)
        self._anim.timeout.connect(self.update)
        self._click: tuple[float, float] | None = None  # left press a tool may get as a click
        # Remote layers: the cursor picked again once the mouse rests (see REPICK_MS).
        self._repick = QTimer(self)
        self._repick.setSingleShot(True)
        self._repick.setInterval(REPICK_MS)
        self._repick.timeout.connect(self._pick_again)
        self._cursor_px: tuple[float, float] | None = None
        self._repicks_left = 0
        # Every model change schedules a frame: nothing calls request_frame by hand for it.
        #: The model subscriptions, the window's (cleared when it closes), or its own.
        self.subscriptions = Subscriptions() if subscriptions is None else subscriptions
        events = model.events
        self.subscriptions.connect(events.camera, self.request_frame)
        self.subscriptions.connect(events.tau_px, self.request_frame)
        self.subscriptions.connect(events.lod, self.request_frame)
        self.subscriptions.connect(events.tool, self._model_tool)
        self.subscriptions.connect(events.terrain, self.request_frame)
        self.subscriptions.connect(events.overlays, self.request_frame)
        self.subscriptions.connect(model.display.events.all, self.request_frame)

    # -- the model (read through: the Globe holds the state) --------------------------------
    @property
    def camera(self) -> Camera:
        """The model's camera (changed in place by navigation and flights)."""
        return self.model.camera

    @property
    def settings(self) -> DisplaySettings:
        """The model's display settings."""
        return self.model.display

    @property
    def last_stats(self) -> FrameStats | None:
        """The last drawn frame's statistics (the session's last frame), or None."""
        last = None if self.scene is None else self.scene.last
        return None if last is None else last.stats

    @property
    def overlay_drawn(self) -> int:
        """Tool overlay instances (markers, line segments) the last frame drew (0: none)."""
        last = None if self.scene is None else self.scene.last
        return 0 if last is None else last.overlay_drawn

    def _model_tool(self, *_args: object) -> None:
        """The model's tool changed (here, from code, or its plugin failed): a pending click
        belongs to the old tool; no tool, no animation."""
        self._click = None
        if self.model.tool is None:
            self._anim.stop()
        self.update()

    def request_frame(self) -> None:
        """Schedule one frame (coalesced by Qt)."""
        self.update()

    def viewport_px(self) -> tuple[int, int]:
        """Framebuffer size in pixels."""
        r = self.devicePixelRatio()
        return max(round(self.width() * r), 1), max(round(self.height() * r), 1)

    def to_px(self, pos: QPointF) -> tuple[float, float]:
        r = self.devicePixelRatio()
        return pos.x() * r, pos.y() * r

    # -- GL ----------------------------------------------------------------------------------
    def initializeGL(self) -> None:
        self.ctx = moderngl.create_context(require=GL_VERSION[0] * 100 + GL_VERSION[1] * 10)
        available = self.registry.lod_providers()
        if not available:
            # Every LOD plugin is disabled: the globe cannot be drawn without one.
            self.registry.enable(DEFAULT_LOD)
            available = self.registry.lod_providers()
        # The session draws the model (its camera, tau, LOD, tool, overlays and display
        # settings are the Globe's: one copy of the state).
        scene = GlobeSession(
            self.ctx,
            self.terrain,
            registry=self.registry,
            globe=self.model,
            overlay_host=self.overlays,
        )
        # Tiles load on worker threads; frames draw ancestors until they arrive.
        scene.renderer.async_loading = True
        # A worker thread emits; Qt queues the call to this (the UI) thread.
        scene.renderer.on_tile_ready = self._tileReady.emit
        self.scene = scene
        self.navigator = Navigator(self.model, self.pick, self.viewport_px, self._camera_moved)
        log.info("OpenGL %s on %s", self.ctx.info["GL_VERSION"], self.ctx.info["GL_RENDERER"])
        self.sceneReady.emit(scene)

    def paintGL(self) -> None:
        if self.scene is None or self.ctx is None:
            return
        now = time.perf_counter()  # for the frame rate shown, nothing else
        dt = now - self._last_paint if self._last_paint else 0.0
        fbo = self.ctx.detect_framebuffer()
        w, h = self.viewport_px()
        fbo.viewport = (0, 0, w, h)
        try:
            # The whole frame: camera speed, the tool's animation step and overlay included.
            result = self.scene.render(fbo, (w, h))
        except Exception as exc:  # noqa: BLE001  last resort: a failed frame is reported once, the window keeps drawing
            # Clear to the background so a failed frame is not garbage, and report once.
            fbo.use()
            fbo.clear(*self.settings.background, 1.0)
            key = f"{type(exc).__name__}: {exc}"
            if key != self._render_error:
                self._render_error = key
                self.renderFailed.emit(exc)
            return
        self._render_error = None
        self.frames += 1
        if 0.0 < dt < 0.5:
            inst = 1.0 / dt
            self.fps = inst if self.fps == 0.0 else 0.8 * self.fps + 0.2 * inst
        elif result.stats.frame_ms > 0:
            self.fps = 1000.0 / result.stats.frame_ms  # a lone frame: what it could sustain
        self._last_paint = now
        # The tool asked for another frame: keep the 16 ms repaint timer running.
        if result.animating and not self._anim.isActive():
            self._anim.start()
        elif not result.animating and self._anim.isActive():
            self._anim.stop()
        self.frameRendered.emit(result.stats, self.fps)
        if result.stats.tiles_loading > 0:
            # Finished tiles announce themselves (`_tiles_ready`); ones this frame had no
            # budget for are drawn by the next frame.
            self._tiles_ready()
        elif result.view.speed_mps > 0.0:
            self._settle.start()  # one more frame once still, for the speed-dependent LOD

    # -- background tiles ------------------------------------------------------------------
    def _tiles_ready(self) -> None:
        """Tiles finished in the background: draw them. The frame after the last queued tile
        is drawn at once; before that at most one per `LOADING_FRAME_MS`."""
        loader = None if self.scene is None else self.scene.renderer.loader
        if loader is None:
            return
        if loader.building == 0:
            # The last tile (or the last failure: the status must stop saying "loading").
            self._loading_frame.stop()
            self.update()
        elif loader.ready and not self._loading_frame.isActive():
            self._loading_frame.start()

    def _drop_prefetch(self) -> None:
        """A flight was cut short: its destination's tiles no longer go first."""
        loader = None if self.scene is None else self.scene.renderer.loader
        if loader is not None:
            loader.prefetch(np.empty((0, 3), np.int64))

    def prefetch_pose(self, pose: tuple[float, float, float, float, float]) -> int:
        """Start loading the tiles of the view from ``pose`` (lon, lat, height, heading,
        pitch: a flight's destination) ahead of the frames on the way; returns how many
        tiles were queued (0 before GL is up or when the pose is not a camera).

        The selection goes through the frame path (`scene.select` -> `LodHost.select`): a
        provider that fails here is reported and its plugin failed at once, exactly as in a
        frame, and the globe falls back to the default provider (the prefetch then uses
        that one's selection); its time counts against the frame-path budget, so a slow
        select of a far, cold destination can be reported as an overrun. The ``except``
        below catches only what is not a provider's: a pose that is not a camera, a
        renderer error."""
        if self.scene is None:
            return 0
        try:
            camera = Camera.from_lonlat(*pose, fovy_deg=self.camera.fovy_deg)
            view = ViewState.from_camera(
                camera,
                self.viewport_px(),
                tau_px=self.model.tau_px,
                exaggeration=self.settings.exaggeration,
            )
            render_set = self.scene.select(view)
            return self.scene.renderer.prefetch(render_set, view.eye)
        except Exception as exc:  # noqa: BLE001  prefetching is an optimisation only
            log.info("no prefetch for %s: %s", pose, exc)
            return 0

    # -- tools -------------------------------------------------------------------------------
    def active_tool(self):
        """The session's active tool object, or None."""
        if self.scene is None or self.scene.active_tool is None:
            return None
        tool = self.scene.tools().get(self.scene.active_tool)
        if tool is None:
            # Its plugin was disabled or failed: the session leaves it (the model's tool
            # becomes None, an event; the hook goes at the next frame, no GL here).
            self.scene.tool()  # leaves it: the model's tool is None (an event, _model_tool)
        return tool

    def set_tool(self, name: str | None) -> bool:
        """Activate tool ``name`` (None: none) in the session: the model's tool becomes
        ``name`` (the toolbar follows its event) and the previous tool's ``deactivate`` runs.
        Returns whether ``name`` is the model's tool now (a tool whose displacement hook
        fails is disabled and reported by the registry, and the model's tool is None again:
        an event too)."""
        if self.scene is None:
            return name is None
        self.scene.activate_tool(name)  # the model only: the hook compiles in the next frame
        return self.model.tool == name

    @property
    def animating(self) -> bool:
        """Whether the tool animation timer is running."""
        return self._anim.isActive()

    def _pointer_event(
        self,
        kind: str,
        x: float,
        y: float,
        button: str | None,
        buttons: frozenset[str],
        modifiers: frozenset[str],
        wheel_delta: float = 0.0,
        hit: Pick | None = None,
        picked: bool = False,
    ) -> PointerEvent:
        if not picked:
            hit = self.pick(x, y)
        return PointerEvent(
            x=float(x),
            y=float(y),
            kind=kind,  # type: ignore[arg-type]
            button=button,
            buttons=buttons,
            modifiers=modifiers,
            wheel_delta=float(wheel_delta),
            picked=None if hit is None else tuple(float(v) for v in hit.ecef),  # type: ignore[arg-type]
            lonlat=None if hit is None else (hit.lon, hit.lat, hit.height),
        )

    def _send_to_tool(self, event: PointerEvent | KeyEvent) -> bool:
        tool = self.active_tool()
        if tool is None or self.scene is None:
            return False
        method = "on_key" if isinstance(event, KeyEvent) else "on_mouse"
        used = bool(self.scene.registry.invoke(tool, method, event, default=False))
        self.active_tool()  # the tool raised? then its plugin is disabled now: leave it
        if used or not (isinstance(event, PointerEvent) and event.kind == "move"):
            self.update()
        return used

    def deactivate_tool(self) -> None:
        """Leave the active tool (its ``deactivate`` runs; the model's tool event tells the
        window and stops the animation timer, `_model_tool`)."""
        if self.scene is not None and self.scene.active_tool is not None:
            self.set_tool(None)

    def grab_image(self) -> QImage:
        """The current frame as an image (renders one if needed)."""
        return self.grabFramebuffer()

    def pick(self, x_px: float, y_px: float) -> Pick | None:
        """The terrain point under a framebuffer pixel of the last frame (None: sky)."""
        if self.scene is None or self.scene.last is None or self.context() is None:
            return None
        self.makeCurrent()
        try:
            hit = self.scene.pick(x_px, y_px)
            fbo = self.scene.last.target
            if fbo is not None:
                # moderngl's depth read leaves GL_READ_BUFFER at GL_NONE on Qt's framebuffer,
                # after which Qt's own read-backs (grabFramebuffer, window grabs) return
                # garbage; a one-pixel colour read sets it back to colour attachment 0.
                fbo.read(viewport=(0, 0, 1, 1), components=4, attachment=0)
            return hit
        finally:
            self.doneCurrent()

    def has_remote_layers(self) -> bool:
        """Whether a visible layer is a store read over HTTP (its tiles may not be here yet)."""
        return any(
            bool(getattr(ly.store, "is_remote", False)) for ly in self.terrain.visible_layers
        )

    def _pick_again(self) -> None:
        """The cursor rested (`REPICK_MS`): pick it again, now that the finest tile under it
        may have arrived in the background (up to `REPICK_TRIES` times while it rests)."""
        if self._cursor_px is None or (self.navigator is not None and self.navigator.dragging):
            return
        self.cursorPicked.emit(self.pick(*self._cursor_px))
        self._repicks_left -= 1
        if self._repicks_left > 0:
            self._repick.start()

    # -- camera ------------------------------------------------------------------------------
    def _camera_moved(self) -> None:
        """Navigation or a flight moved the camera in place: the model announces it (the
        status bar and this widget subscribe)."""
        self.model.camera_moved()

    def fly_to_camera(self, target: Camera, duration_s: float = 1.0) -> None:
        self.flight.fly_to_camera(target, duration_s)

    def fly_to_bounds(self, bounds: tuple[float, float, float, float]) -> None:
        """Fly over a lon/lat box (west, south, east, north degrees)."""
        self.fly_to_camera(camera_for_bounds(*bounds, fovy_deg=self.camera.fovy_deg))

    def go_home(self, duration_s: float = 1.0) -> None:
        self.flight.fly_to(HOME_POSE, duration_s)

    # -- input -------------------------------------------------------------------------------
    def _nav(self) -> Navigator | None:
        return self.navigator

    def mousePressEvent(self, event: QMouseEvent) -> None:
        nav = self._nav()
        if nav is None:
            return
        self.flight.stop()
        x, y = self.to_px(event.position())
        if self.active_tool() is not None and event.button() == Qt.MouseButton.LeftButton:
            # A click for the tool unless it turns into a drag (then: navigation).
            self._click = (x, y)
        nav.press(x, y, event.button())
        event.accept()

    def mouseMoveEvent(self, event: QMouseEvent) -> None:
        nav = self._nav()
        if nav is None:
            return
        x, y = self.to_px(event.position())
        if self._click is not None:
            if math.hypot(x - self._click[0], y - self._click[1]) <= CLICK_SLOP_PX:
                event.accept()
                return  # still a click: the camera stays put
            self._click = None  # a drag: navigation from here on
        if nav.dragging:
            nav.move(x, y)
        else:
            hit = self.pick(x, y)
            self.cursorPicked.emit(hit)
            self._cursor_px = (x, y)
            if self.has_remote_layers():
                self._repicks_left = REPICK_TRIES
                self._repick.start()
            if self.active_tool() is not None:
                mods = modifier_names(event.modifiers())
                buttons = button_names(event.buttons())
                self._send_to_tool(
                    self._pointer_event("move", x, y, None, buttons, mods, hit=hit, picked=True)
                )
        event.accept()

    def mouseReleaseEvent(self, event: QMouseEvent) -> None:
        nav = self._nav()
        if nav is not None:
            nav.release()
        click, self._click = self._click, None
        if click is not None and event.button() == Qt.MouseButton.LeftButton:
            mods = modifier_names(event.modifiers())
            press = self._pointer_event("press", *click, "left", frozenset({"left"}), mods)
            self._send_to_tool(press)
            release = replace(press, kind="release", buttons=frozenset())
            self._send_to_tool(release)
        event.accept()

    def wheelEvent(self, event: QWheelEvent) -> None:
        nav = self._nav()
        if nav is None:
            return
        self.flight.stop()
        steps = event.angleDelta().y() / 120.0
        x, y = self.to_px(event.position())
        if self.active_tool() is not None:
            ev = self._pointer_event(
                "wheel", x, y, None, button_names(event.buttons()),
                modifier_names(event.modifiers()), wheel_delta=steps,
            )  # fmt: skip
            if self._send_to_tool(ev):
                event.accept()
                return
        nav.wheel(x, y, steps)
        event.accept()

    def event(self, event: QEvent) -> bool:
        # With a tool active, plain keys go to the widget (the tool's on_key) before window
        # shortcuts; keys it does not take are offered to the shortcuts again through
        # keyUnhandled (the window matches tool and manifest-command actions).
        if event.type() == QEvent.Type.ShortcutOverride and self.active_tool() is not None:
            mods = event.modifiers() & ~Qt.KeyboardModifier.ShiftModifier
            if not mods and key_name(event.key(), event.text()):
                event.accept()
                return True
        return super().event(event)

    def keyPressEvent(self, event: QKeyEvent) -> None:
        nav = self._nav()
        if self.active_tool() is not None:
            name = key_name(event.key(), event.text())
            if name:
                ev = KeyEvent(name, modifier_names(event.modifiers()), "press")
                used = self._send_to_tool(ev)
                if name == "Escape":
                    self.deactivate_tool()
                    event.accept()
                    return
                if used:
                    event.accept()
                    return
        if event.key() == Qt.Key.Key_Home:
            self.go_home()
            event.accept()
            return
        if nav is not None and nav.key(event.key()):
            self.flight.stop()
            event.accept()
            return
        if self.active_tool() is not None:
            self.keyUnhandled.emit(int(event.key()), event.modifiers())
        super().keyPressEvent(event)

    def release_gl(self) -> None:
        """Release GL objects (call with the widget's context alive, before closing)."""
        if self.scene is not None and self.context() is not None:
            self.makeCurrent()
            try:
                self.scene.release_gl()
            finally:
                self.doneCurrent()
        self.scene = None
        self.navigator = None
