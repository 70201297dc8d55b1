"""Mouse and keyboard navigation, and smooth camera flights.

`Navigator` turns pointer and key input (pixel coordinates, top-left origin, in framebuffer
pixels) into the camera's own operations (`globeview.model.camera.Camera`): it decides
*which* operation and which point on the globe, the camera does the geometry.

- left drag: orbit — the globe point grabbed under the cursor stays under the cursor;
- wheel: zoom toward the point under the cursor;
- right/middle drag: horizontal motion turns the heading, vertical motion tilts, both about
  the globe point at the centre of the view;
- keys (fly mode, thesis §3.4): Up/Down pitch, Left/Right and A/D yaw, W/S forward/back,
  +/- zoom toward the centre point, Home: the whole globe.

`CameraFlight` animates the camera to a pose (lon, lat, height, heading, pitch) over about a
second with a QTimer that stops at the end.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from PyQt6.QtCore import QObject, Qt, QTimer, pyqtSignal

from globeview.geodesy import geodesic_inverse, ray_ellipsoid_intersection
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera
from globeview.render.picking import Pick

#: Camera pose: (lon deg, lat deg, height m, heading deg, pitch deg).
Pose = tuple[float, float, float, float, float]

#: The whole-globe view Home returns to.
HOME_POSE: Pose = (0.0, 20.0, 2.0e7, 0.0, -90.0)
#: Zoom factor per wheel step (one notch = 120 eighths of a degree).
WHEEL_FACTOR = 0.8
#: Degrees of heading / pitch per pixel of right-drag.
HEADING_DEG_PER_PX = 0.25
TILT_DEG_PER_PX = 0.2
#: Fly-mode steps per key press: degrees of yaw/pitch, and fraction of the height forward.
FLY_TURN_DEG = 2.0
FLY_STEP_FRACTION = 0.05


@dataclass
class _Drag:
    button: Qt.MouseButton
    x: float
    y: float
    grabbed: np.ndarray | None  # ECEF point held under the cursor (orbit)
    grabbed_height: float
    pivot: np.ndarray | None  # ECEF point at the view centre (tilt / heading)


class HasCamera(Protocol):
    """What navigation needs of the model: its current camera (`globeview.model.Globe`)."""

    @property
    def camera(self) -> Camera: ...


class Navigator:
    """Maps input to camera operations on ``model.camera``.

    Args:
        model: the globe model (its camera is changed in place; `changed` announces it).
        pick: (x_px, y_px) -> the terrain point under a pixel of the last frame, or None.
        viewport: () -> the framebuffer size (width, height) in pixels.
        changed: called after every camera change (the widget schedules a frame).
    """

    def __init__(
        self,
        model: HasCamera,
        pick: Callable[[float, float], Pick | None],
        viewport: Callable[[], tuple[int, int]],
        changed: Callable[[], None],
    ) -> None:
        self.model = model
        self._pick = pick
        self._viewport = viewport
        self._changed = changed
        self._drag: _Drag | None = None

    @property
    def camera(self) -> Camera:
        return self.model.camera

    @property
    def dragging(self) -> bool:
        return self._drag is not None

    # -- globe points ------------------------------------------------------------------------
    def ray_point(self, x: float, y: float, height: float = 0.0) -> np.ndarray | None:
        """Where the current camera's ray through pixel (x, y) meets the ellipsoid inflated by
        ``height`` metres (ECEF), or None in the sky."""
        vp = self._viewport()
        if vp[0] <= 0 or vp[1] <= 0:
            return None
        view = ViewState.from_camera(self.camera, vp)  # only the eye and the ray are used
        p = np.asarray(
            ray_ellipsoid_intersection(view.eye, view.pixel_ray(x, y), h=height), np.float64
        )
        return p if np.all(np.isfinite(p)) else None

    def ground_point(self, x: float, y: float) -> np.ndarray | None:
        """The terrain point under (x, y) (depth read-back), else the ellipsoid under it."""
        hit = self._pick(x, y)
        if hit is not None:
            return np.asarray(hit.ecef, dtype=np.float64)
        return self.ray_point(x, y)

    def centre_point(self) -> np.ndarray | None:
        w, h = self._viewport()
        return self.ground_point(w / 2.0, h / 2.0)

    # -- pointer -----------------------------------------------------------------------------
    def press(self, x: float, y: float, button: Qt.MouseButton) -> None:
        grabbed, gh, pivot = None, 0.0, None
        if button == Qt.MouseButton.LeftButton:
            hit = self._pick(x, y)
            if hit is not None:
                grabbed, gh = np.asarray(hit.ecef, np.float64), hit.height
            else:
                grabbed = self.ray_point(x, y)
        elif button in (Qt.MouseButton.RightButton, Qt.MouseButton.MiddleButton):
            pivot = self.centre_point()
        else:
            return
        self._drag = _Drag(button, x, y, grabbed, gh, pivot)

    def move(self, x: float, y: float) -> bool:
        """Continue a drag; True when the camera changed."""
        d = self._drag
        if d is None:
            return False
        dx, dy = x - d.x, y - d.y
        d.x, d.y = x, y
        if d.button == Qt.MouseButton.LeftButton:
            if d.grabbed is None:
                return False
            target = self.ray_point(x, y, d.grabbed_height)
            if target is None:
                return False
            self.camera.orbit_drag(d.grabbed, target)
        else:
            if d.pivot is None:
                return False
            if dx:
                self.camera.rotate_heading_about(d.pivot, dx * HEADING_DEG_PER_PX)
            if dy:
                self.camera.tilt_about(d.pivot, -dy * TILT_DEG_PER_PX)
        self._changed()
        return True

    def release(self) -> None:
        self._drag = None

    def wheel(self, x: float, y: float, steps: float) -> bool:
        """Zoom toward the point under (x, y); ``steps`` > 0 zooms in (one notch = 1)."""
        target = self.ground_point(x, y)
        if target is None:
            target = self.centre_point()
        if target is None or steps == 0:
            return False
        self.camera.zoom_toward(target, WHEEL_FACTOR**steps)
        self._changed()
        return True

    # -- keyboard ----------------------------------------------------------------------------
    def key(self, key: int) -> bool:
        """Handle a key (a ``Qt.Key`` value); True when it was a navigation key."""
        k = Qt.Key
        cam = self.camera
        step = max(cam.height * FLY_STEP_FRACTION, 10.0)
        if key in (k.Key_Left, k.Key_A):
            cam.fly_yaw(-FLY_TURN_DEG)
        elif key in (k.Key_Right, k.Key_D):
            cam.fly_yaw(FLY_TURN_DEG)
        elif key == k.Key_Up:
            cam.fly_pitch(FLY_TURN_DEG)
        elif key == k.Key_Down:
            cam.fly_pitch(-FLY_TURN_DEG)
        elif key == k.Key_W:
            cam.fly_forward(step)
        elif key == k.Key_S:
            cam.fly_forward(-step)
        elif key in (k.Key_Plus, k.Key_Equal, k.Key_Minus):
            target = self.centre_point()
            if target is None:
                return False
            cam.zoom_toward(target, WHEEL_FACTOR if key != k.Key_Minus else 1.0 / WHEEL_FACTOR)
        else:
            return False
        self._changed()
        return True


# -- flights -----------------------------------------------------------------------------------
def _wrap180(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


def interpolate_pose(a: Pose, b: Pose, t: float, arc_m: float = 0.0) -> Pose:
    """The pose a fraction ``t`` (0..1) of the way from ``a`` to ``b``.

    Longitude and heading go the short way round; height is interpolated geometrically (equal
    zoom ratios per step) and raised by ``arc_m * 4t(1-t)`` so long flights climb and descend.
    """
    lon = a[0] + _wrap180(b[0] - a[0]) * t
    lat = a[1] + (b[1] - a[1]) * t
    h0, h1 = max(a[2], 1.0), max(b[2], 1.0)
    h = math.exp(math.log(h0) + (math.log(h1) - math.log(h0)) * t) + arc_m * 4.0 * t * (1 - t)
    heading = (a[3] + _wrap180(b[3] - a[3]) * t) % 360.0
    pitch = a[4] + (b[4] - a[4]) * t
    return (_wrap180(lon), lat, h, heading, pitch)


def _ease(t: float) -> float:
    """Smoothstep: zero velocity at both ends."""
    t = min(max(t, 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


class CameraFlight(QObject):
    """Flies ``model.camera`` (a `globeview.model.Globe`'s, or anything with a ``camera``)
    to a pose over ``duration_s`` seconds, one step per timer tick (the camera in use when
    the step is taken: a replaced camera is flown, not the old one).

    Signals: ``started(pose)`` when a flight begins, with its destination (lon, lat,
    height, heading, pitch: the window loads the destination's tiles during the flight),
    ``stepped`` after each step (schedule a frame), ``finished`` at the end, ``stopped``
    when `stop` cut a flight short (its destination is not wanted any more).
    The timer runs only during a flight.
    """

    started = pyqtSignal(object)
    stepped = pyqtSignal()
    finished = pyqtSignal()
    stopped = pyqtSignal()

    def __init__(self, model: HasCamera, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.model = model
        self.duration_s = 1.0
        self._timer = QTimer(self)
        self._timer.setInterval(16)
        self._timer.timeout.connect(self._tick)
        self._from: Pose | None = None
        self._to: Pose | None = None
        self._arc = 0.0
        self._t0 = 0.0

    @property
    def camera(self) -> Camera:
        return self.model.camera

    @property
    def active(self) -> bool:
        return self._timer.isActive()

    def fly_to(self, pose: Pose, duration_s: float = 1.0) -> None:
        """Start a flight to ``pose`` (lon, lat, height, heading, pitch); replaces any other."""
        lon, lat, h, heading, pitch, _ = self.camera.lonlat_hpr()
        self._from = (lon, lat, h, heading, pitch)
        self._to = tuple(float(v) for v in pose)  # type: ignore[assignment]
        _, _, dist = geodesic_inverse(lon, lat, pose[0], pose[1])
        self._arc = max(0.0, min(0.5 * float(dist), 1.5e7) - max(h, pose[2]))
        self.duration_s = max(float(duration_s), 0.0)
        self._t0 = time.perf_counter()
        self.started.emit(self._to)
        if self.duration_s == 0.0:
            self._finish()
            return
        self._timer.start()

    def fly_to_camera(self, target: Camera, duration_s: float = 1.0) -> None:
        lon, lat, h, heading, pitch, _ = target.lonlat_hpr()
        self.fly_to((lon, lat, h, heading, pitch), duration_s)

    def stop(self) -> None:
        """Stop where the camera is now (``stopped`` if a flight was under way)."""
        if self._timer.isActive():
            self._timer.stop()
            self.stopped.emit()

    def _tick(self) -> None:
        assert self._from is not None and self._to is not None
        t = (time.perf_counter() - self._t0) / self.duration_s
        if t >= 1.0:
            self._finish()
            return
        self.camera.set_lonlat(*interpolate_pose(self._from, self._to, _ease(t), self._arc))
        self.stepped.emit()

    def _finish(self) -> None:
        self._timer.stop()
        if self._to is not None:
            self.camera.set_lonlat(*self._to)
        self.stepped.emit()
        self.finished.emit()
