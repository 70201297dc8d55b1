"""`GlobeWidget`: the OpenGL view hosting a `GlobeScene`.

The moderngl context is created in ``initializeGL`` from Qt's current context and each frame
draws into ``ctx.detect_framebuffer()`` (Qt's framebuffer object, not framebuffer 0). Frames
are drawn on demand only: something that changes the view calls ``request_frame()``
(``update()``); there is no busy timer, so an idle globe costs nothing.

Pixel coordinates handed to the scene (picking, navigation) are framebuffer pixels, top-left
origin: Qt's logical coordinates times ``devicePixelRatio``.

Tools (``GlobeSession.tool()``, the active tool plugin): a left click — press and release
without moving more than `CLICK_SLOP_PX` — goes to the tool as a ``press`` and a ``release``
`PointerEvent` (with the true, un-displaced picked point), a drag still navigates; cursor
moves, wheel steps and key presses go to the tool first and to navigation when it does not
consume them. Escape also deactivates the tool (``toolDeactivated``). Each frame the widget
advances the tool's ``animate(now)`` (a 16 ms timer keeps frames coming while it returns
True) and draws the tool's overlay primitives (`ToolOverlayRenderer`) over the terrain.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace

import moderngl
import numpy as np
from PyQt6.QtCore import QEvent, QPointF, Qt, QTimer, pyqtSignal
from PyQt6.QtGui import (
    QImage,
    QKeyEvent,
    QMouseEvent,
    QOpenGLContext,
    QSurfaceFormat,
    QWheelEvent,
)
from PyQt6.QtOpenGLWidgets import QOpenGLWidget
from PyQt6.QtWidgets import QWidget

from globeview.lod.render_set import FrameStats
from globeview.model.camera import Camera
from globeview.model.display import DisplaySettings
from globeview.plugins.api import KeyEvent, PointerEvent
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.session import DEFAULT_LOD, GlobeSession
from globeview.render.picking import Pick
from globeview.terrain.stack import TerrainStack
from globeview.ui.navigation import HOME_POSE, CameraFlight, Navigator

log = logging.getLogger("globeview.ui")

#: OpenGL version the renderer needs (multi-draw indirect needs 4.3 where available; 3.3 is
#: the floor moderngl's programs need).
GL_VERSION = (3, 3)
#: A left press and release closer than this (framebuffer pixels) is a click for the tool.
CLICK_SLOP_PX = 4.0
#: Repaint interval while a tool animates (ms).
ANIMATION_INTERVAL_MS = 16

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
        terrain: the DEM layers; the scene is built on it once GL is up.
        registry: the plugin registry the `GlobeSession` takes its LOD providers from.
        camera: the initial camera (changed in place by navigation and flights).
        lod: name of the LOD provider to start with.

    Signals:
        sceneReady(object): the `GlobeSession`, once the GL context exists.
        frameRendered(object, float): each frame's `FrameStats` and the frame rate (Hz).
        cursorPicked(object): the `Pick` under the cursor (or None) as the mouse moves.
        cameraChanged(): navigation or a flight moved the camera.
        renderFailed(object): an exception while drawing (the widget keeps running).
        toolDeactivated(): the widget deactivated the active tool (Escape, or its plugin
            failed).
        keyUnhandled(int, object): a key press neither the tool nor navigation took (Qt key,
            modifiers): the window matches it against the tool actions' shortcuts.
    """

    sceneReady = pyqtSignal(object)
    frameRendered = pyqtSignal(object, float)
    cursorPicked = pyqtSignal(object)
    cameraChanged = pyqtSignal()
    renderFailed = pyqtSignal(object)
    toolDeactivated = pyqtSignal()
    keyUnhandled = pyqtSignal(int, object)

    def __init__(
        self,
        terrain: TerrainStack,
        registry: PluginRegistry,
        camera: Camera | None = None,
        lod: str = DEFAULT_LOD,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self.setFormat(surface_format())
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.setMouseTracking(True)
        self.setMinimumSize(200, 150)
        self.terrain = terrain
        self.camera = camera or Camera.from_lonlat(*HOME_POSE)
        self.settings = DisplaySettings()
        self.tau_px = 2.0
        self.registry = registry
        self.lod = lod
        self.ctx: moderngl.Context | None = None
        self.scene: GlobeSession | None = None
        self.frames = 0
        self.fps = 0.0
        self.last_stats: FrameStats | None = None
        self._last_paint = 0.0
        self._last_eye = self.camera.eye.copy()
        self._render_error: str | None = None
        self.flight = CameraFlight(self.camera, self)
        self.flight.stepped.connect(self._camera_moved)
        self.navigator: Navigator | None = None
        # One extra frame after motion stops, so the speed-dependent LOD settles.
        self._settle = QTimer(self)
        self._settle.setSingleShot(True)
        self._settle.setInterval(150)
        self._settle.timeout.connect(self.update)
        # Tools: animation repaints, the pending left click, overlay drawing.
        self.overlay_drawn = 0
        self._anim = QTimer(self)
        self._anim.setInterval(ANIMATION_INTERVAL_MS)
        self._anim.timeout.connect(self.update)
        self._click: tuple[float, float] | None = None  # left press a tool may get as a click

    # -- model wiring ----------------------------------------------------------------------
    def set_tau(self, tau_px: float) -> None:
        """Screen-space error threshold in pixels."""
        self.tau_px = float(tau_px)
        if self.scene is not None:
            self.scene.tau_px = self.tau_px
        self.request_frame()

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
        if self.lod not in available and available:
            self.lod = DEFAULT_LOD if DEFAULT_LOD in available else next(iter(available))
        scene = GlobeSession(self.ctx, self.terrain, self.camera, self.registry, self.lod)
        scene.renderer.settings = self.settings
        # Tiles load on worker threads; frames draw ancestors until they arrive.
        scene.renderer.async_loading = True
        scene.tau_px = self.tau_px
        self.scene = scene
        self.navigator = Navigator(scene, self.pick, self.viewport_px, self._camera_moved)
        log.info("OpenGL %s on %s", self.ctx.info["GL_VERSION"], self.ctx.info["GL_RENDERER"])
        self.sceneReady.emit(scene)

    def paintGL(self) -> None:
        if self.scene is None or self.ctx is None:
            return
        now = time.perf_counter()
        dt = now - self._last_paint if self._last_paint else 0.0
        moved = float(np.linalg.norm(self.camera.eye - self._last_eye))
        self.scene.speed_mps = moved / dt if 0.0 < dt < 0.5 else 0.0
        fbo = self.ctx.detect_framebuffer()
        w, h = self.viewport_px()
        fbo.viewport = (0, 0, w, h)
        self._animate_tool()
        try:
            result = self.scene.render(fbo, (w, h))
            self._draw_tool_overlay(fbo, result.view)
        except Exception as exc:
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
        self._last_eye = self.camera.eye.copy()
        self.last_stats = result.stats
        self.frameRendered.emit(result.stats, self.fps)
        if result.stats.tiles_loading > 0:
            self.update()  # keep drawing while tiles stream in
        elif self.scene.speed_mps > 0.0:
            self._settle.start()

    # -- tools -------------------------------------------------------------------------------
    def active_tool(self):
        """The session's active tool object, or None."""
        if self.scene is None or self.scene.active_tool is None:
            return None
        tool = self.scene.tools().get(self.scene.active_tool)
        if tool is None:
            # Its plugin was disabled or failed: the session drops the displacement hook,
            # which recompiles the terrain shader, so our context must be current.
            self._anim.stop()
            if QOpenGLContext.currentContext() is self.context() or self.context() is None:
                self.scene.tool()
            else:
                self.makeCurrent()
                try:
                    self.scene.tool()
                finally:
                    self.doneCurrent()
            self.toolDeactivated.emit()
        return tool

    def set_tool(self, name: str | None) -> bool:
        """Activate tool ``name`` (None: none) in the session, compiling its displacement hook
        with this widget's context current. Returns whether ``name`` is now active (a tool
        whose hook fails to compile is disabled and reported by the registry)."""
        if self.scene is None:
            return name is None
        self._click = None
        self.makeCurrent()
        try:
            self.scene.activate_tool(name)
        finally:
            self.doneCurrent()
        self.update()
        return self.scene.active_tool == name

    def _animate_tool(self) -> None:
        """Advance the active tool's animation; keep the repaint timer running while it moves."""
        tool = self.active_tool()
        moving = False
        if tool is not None and callable(getattr(tool, "animate", None)):
            moving = bool(
                self.scene.registry.invoke(tool, "animate", time.monotonic(), default=False)
            )
        if moving and not self._anim.isActive():
            self._anim.start()
        elif not moving and self._anim.isActive():
            self._anim.stop()

    @property
    def animating(self) -> bool:
        """Whether the tool animation timer is running."""
        return self._anim.isActive()

    def _draw_tool_overlay(self, fbo: moderngl.Framebuffer, view) -> None:
        """Draw the active tool's overlay primitives over the terrain just drawn."""
        self.overlay_drawn = 0
        if self.active_tool() is None or self.scene is None:
            return
        self.overlay_drawn = self.scene.draw_tool_overlay(fbo, view)

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
            picked=None if hit is None else tuple(float(v) for v in hit.ecef),
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
        """Leave the active tool (its ``deactivate`` runs) and tell the window."""
        if self.scene is not None and self.scene.active_tool is not None:
            self.set_tool(None)
            self._anim.stop()
            self.toolDeactivated.emit()

    @contextmanager
    def gl_current(self) -> Iterator[None]:
        """Make this widget's GL context current for the block (for creating or releasing GL
        objects outside paintGL, e.g. attaching overlay layers); a no-op when it already is
        (inside initializeGL / paintGL and their signals)."""
        ctx = self.context()
        if ctx is None or QOpenGLContext.currentContext() is ctx:
            yield
            return
        self.makeCurrent()
        try:
            yield
        finally:
            self.doneCurrent()

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
            fbo = self.scene._last_fbo
            if fbo is not None:
                # moderngl's depth read leaves GL_READ_BUFFER at GL_NONE on Qt's framebuffer,
                # after which Qt's own read-backs (grabFramebuffer, window grabs) return
                # garbage; a one-pixel colour read sets it back to colour attachment 0.
                fbo.read(viewport=(0, 0, 1, 1), components=4, attachment=0)
            return hit
        finally:
            self.doneCurrent()

    # -- camera ------------------------------------------------------------------------------
    def _camera_moved(self) -> None:
        self.cameraChanged.emit()
        self.update()

    def fly_to_camera(self, target: Camera, duration_s: float = 1.0) -> None:
        self.flight.fly_to_camera(target, duration_s)

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
        self.navigator = None  # it holds the session
