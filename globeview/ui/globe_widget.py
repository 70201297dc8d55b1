"""`GlobeWidget`: the OpenGL view hosting a `GlobeScene`.

The moderngl context is created in ``initializeGL`` from Qt's current context and each frame
draws into ``ctx.detect_framebuffer()`` (Qt's framebuffer object, not framebuffer 0). Frames
are drawn on demand only: something that changes the view calls ``request_frame()``
(``update()``); there is no busy timer, so an idle globe costs nothing.

Pixel coordinates handed to the scene (picking, navigation) are framebuffer pixels, top-left
origin: Qt's logical coordinates times ``devicePixelRatio``.
"""

from __future__ import annotations

import logging
import time

import moderngl
import numpy as np
from PyQt6.QtCore import QPointF, Qt, QTimer, pyqtSignal
from PyQt6.QtGui import QImage, QKeyEvent, QMouseEvent, QSurfaceFormat, QWheelEvent
from PyQt6.QtOpenGLWidgets import QOpenGLWidget
from PyQt6.QtWidgets import QWidget

from globeview.plugins.registry import PluginRegistry
from globeview.plugins.session import DEFAULT_LOD, GlobeSession
from globeview.render.camera import Camera
from globeview.render.picking import Pick
from globeview.render.render_set import FrameStats
from globeview.render.renderer import RenderSettings
from globeview.terrain.stack import TerrainStack
from globeview.ui.navigation import HOME_POSE, CameraFlight, Navigator

log = logging.getLogger("globeview.ui")

#: OpenGL version the renderer needs (multi-draw indirect needs 4.3 where available; 3.3 is
#: the floor moderngl's programs need).
GL_VERSION = (3, 3)


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
    """

    sceneReady = pyqtSignal(object)
    frameRendered = pyqtSignal(object, float)
    cursorPicked = pyqtSignal(object)
    cameraChanged = pyqtSignal()
    renderFailed = pyqtSignal(object)

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
        self.settings = RenderSettings()
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
        try:
            result = self.scene.render(fbo, (w, h))
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
        nav.press(*self.to_px(event.position()), event.button())
        event.accept()

    def mouseMoveEvent(self, event: QMouseEvent) -> None:
        nav = self._nav()
        if nav is None:
            return
        x, y = self.to_px(event.position())
        if nav.dragging:
            nav.move(x, y)
        else:
            self.cursorPicked.emit(self.pick(x, y))
        event.accept()

    def mouseReleaseEvent(self, event: QMouseEvent) -> None:
        nav = self._nav()
        if nav is not None:
            nav.release()
        event.accept()

    def wheelEvent(self, event: QWheelEvent) -> None:
        nav = self._nav()
        if nav is None:
            return
        self.flight.stop()
        steps = event.angleDelta().y() / 120.0
        nav.wheel(*self.to_px(event.position()), steps)
        event.accept()

    def keyPressEvent(self, event: QKeyEvent) -> None:
        nav = self._nav()
        if event.key() == Qt.Key.Key_Home:
            self.go_home()
            event.accept()
            return
        if nav is not None and nav.key(event.key()):
            self.flight.stop()
            event.accept()
            return
        super().keyPressEvent(event)

    def release_gl(self) -> None:
        """Release GL objects (call with the widget's context alive, before closing)."""
        if self.scene is not None and self.context() is not None:
            self.makeCurrent()
            try:
                self.scene.renderer.release()
            finally:
                self.doneCurrent()
        self.scene = None
