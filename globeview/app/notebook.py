"""A `globeview.Globe` in Jupyter: its PNG (``_repr_png_``) and an interactive view.

`GlobeRfbWidget` is a jupyter_rfb ``RemoteFrameBuffer`` (the remote-frame-buffer widget
pygfx and fastplotlib use): the kernel draws each frame headless with EGL (`Globe.render`)
and the widget sends it to the browser as an image; the browser's pointer and wheel events
come back to the kernel. Drag with the left button to turn the globe (the grabbed point
follows the pointer), drag with the right button to turn the heading and tilt, use the wheel
to zoom toward the pointer. Any change of the globe's model (``globe.fly_to``, a new DEM,
the display settings) asks for a new frame.

jupyter_rfb is optional (``pip install globeview[notebook]``): without it `widget()` is one
line saying so.
"""

from __future__ import annotations

import io
import logging
from typing import Any

import numpy as np

from globeview.errors import GlobeviewError
from globeview.geodesy import ecef_to_lonlat, ray_ellipsoid_intersection
from globeview.lod.view_state import ViewState

__all__ = ["GlobeRfbWidget", "png_bytes"]

log = logging.getLogger("globeview.notebook")

#: Zoom factor of one wheel notch (the distance to the point under the pointer is multiplied
#: by it when zooming in), as in the window.
WHEEL_FACTOR = 0.8
#: Browser wheel units (pixels) in one notch.
WHEEL_PX_PER_NOTCH = 100.0
#: Heading and tilt change per pixel of a right-button drag (degrees).
TURN_DEG_PER_PX = 0.25


def png_bytes(globe: Any) -> bytes | None:
    """The globe rendered at its last size, as PNG bytes; None (logged) when it cannot be
    drawn, so Jupyter shows the text form instead of a traceback."""
    from PIL import Image

    try:
        rgba = globe.render()
    except GlobeviewError as exc:
        log.warning("globeview: cannot show the globe as an image: %s", exc)
        return None
    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, format="PNG")
    return buf.getvalue()


def _rfb_base() -> type:
    try:
        from jupyter_rfb import RemoteFrameBuffer  # type: ignore[import-untyped,import-not-found,unused-ignore]
    except ImportError:
        raise GlobeviewError(
            "globe.widget() needs jupyter_rfb: pip install 'globeview[notebook]' (or "
            "jupyter_rfb); the globe still shows itself as a picture"
        ) from None
    return RemoteFrameBuffer


def GlobeRfbWidget(globe: Any, size: tuple[int, int]) -> Any:
    """The interactive widget of ``globe`` (see the module docstring), ``size`` (width,
    height) CSS pixels to start with."""
    base = _rfb_base()
    cls = _WIDGET_CLASSES.get(base)
    if cls is None:
        cls = type("GlobeRfbWidget", (_Interaction, base), {})
        _WIDGET_CLASSES[base] = cls
    return cls(globe, size)


_WIDGET_CLASSES: dict[type, type] = {}


class _Interaction:
    """The widget's behaviour, mixed into jupyter_rfb's ``RemoteFrameBuffer``."""

    def __init__(self, globe: Any, size: tuple[int, int]) -> None:
        super().__init__(css_width=f"{size[0]}px", css_height=f"{size[1]}px")  # type: ignore[call-arg]
        self.globe = globe
        self.frame_size = size
        self._drag: tuple[str, float, float, np.ndarray | None] | None = None
        events = globe.model.events
        for signal in (events.camera, events.terrain, events.overlays, events.lod):
            signal.connect(self._model_changed)
        globe.model.display.events.connect(self._model_changed)

    def _model_changed(self, *_args: object) -> None:
        self.request_draw()  # type: ignore[attr-defined]

    # -- jupyter_rfb's side --------------------------------------------------------------------
    def get_frame(self) -> np.ndarray:
        """The frame to send: the globe drawn at the widget's size (RGBA uint8)."""
        return self.globe.render(self.frame_size)

    def handle_event(self, event: dict) -> None:
        """Browser events: resize, pointer drags, wheel."""
        kind = event.get("event_type")
        if kind == "resize":
            ratio = float(event.get("pixel_ratio", 1.0) or 1.0)
            w = max(16, round(float(event["width"]) * ratio))
            h = max(16, round(float(event["height"]) * ratio))
            self.frame_size = (w, h)
            self.request_draw()  # type: ignore[attr-defined]
        elif kind == "pointer_down":
            self._press(event)
        elif kind == "pointer_move":
            self._move(event)
        elif kind == "pointer_up":
            self._drag = None
        elif kind == "wheel":
            self._wheel(event)

    # -- navigation (the window's, in brief: ui/navigation.py) --------------------------------
    def _px(self, event: dict) -> tuple[float, float]:
        """The event's position in frame pixels (the browser's are CSS pixels)."""
        w, h = self.frame_size
        cw, ch = self._css_size()
        return float(event["x"]) * w / cw, float(event["y"]) * h / ch

    def _css_size(self) -> tuple[float, float]:
        w, h = self.frame_size
        try:
            cw = float(str(self.css_width).removesuffix("px"))  # type: ignore[attr-defined]
            ch = float(str(self.css_height).removesuffix("px"))  # type: ignore[attr-defined]
        except (AttributeError, ValueError):
            return float(w), float(h)
        return (cw, ch) if cw > 0 and ch > 0 else (float(w), float(h))

    def ground_point(self, x: float, y: float) -> np.ndarray | None:
        """The ECEF point under frame pixel (x, y): the terrain's (depth of the last frame),
        else the ellipsoid's; None in the sky."""
        hit = self.globe._pick(x, y)
        if hit is not None:
            return np.asarray(hit.ecef, dtype=np.float64)
        view = ViewState.from_camera(self.globe.model.camera, self.frame_size)
        p = np.asarray(ray_ellipsoid_intersection(view.eye, view.pixel_ray(x, y)), np.float64)
        return p if np.all(np.isfinite(p)) else None

    def _press(self, event: dict) -> None:
        x, y = self._px(event)
        button = "left" if int(event.get("button", 1)) == 1 else "turn"
        grabbed = self.ground_point(x, y) if button == "left" else self._centre()
        self._drag = (button, x, y, grabbed)

    def _centre(self) -> np.ndarray | None:
        w, h = self.frame_size
        return self.ground_point(w / 2.0, h / 2.0)

    def _move(self, event: dict) -> None:
        if self._drag is None:
            return
        button, x0, y0, point = self._drag
        x, y = self._px(event)
        self._drag = (button, x, y, point)
        if point is None:
            return
        camera = self.globe.model.camera
        if button == "left":
            view = ViewState.from_camera(camera, self.frame_size)
            grabbed_h = float(ecef_to_lonlat(point)[2])  # the grabbed point stays under it
            target = np.asarray(
                ray_ellipsoid_intersection(view.eye, view.pixel_ray(x, y), h=grabbed_h),
                np.float64,
            )
            if not np.all(np.isfinite(target)):
                return
            camera.orbit_drag(point, target)
        else:
            camera.rotate_heading_about(point, (x - x0) * TURN_DEG_PER_PX)
            camera.tilt_about(point, -(y - y0) * TURN_DEG_PER_PX)
        self.globe.model.camera_moved()  # redraws this widget and any window on the globe

    def _wheel(self, event: dict) -> None:
        steps = -float(event.get("dy", 0.0)) / WHEEL_PX_PER_NOTCH
        if steps == 0:
            return
        target = self.ground_point(*self._px(event)) if "x" in event else None
        target = target if target is not None else self._centre()
        if target is None:
            return
        self.globe.model.camera.zoom_toward(target, WHEEL_FACTOR**steps)
        self.globe.model.camera_moved()
