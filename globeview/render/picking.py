"""Picking (thesis §3.5.4, "reverse projection"): read the depth under a pixel and unproject
it to ECEF, then geodetic lon/lat/height; where nothing was drawn, fall back to the ray's
intersection with the ellipsoid."""

from __future__ import annotations

import math
from dataclasses import dataclass

import moderngl
import numpy as np

from globeview.geodesy import ecef_to_lonlat, ray_ellipsoid_intersection
from globeview.render.view_state import ViewState


@dataclass(frozen=True)
class Pick:
    """What lies under a pixel. ``ecef`` in metres; lon/lat degrees; height metres.
    ``on_terrain`` is False when the value comes from the bare ellipsoid (no depth there)."""

    ecef: np.ndarray
    lon: float
    lat: float
    height: float
    on_terrain: bool


def depth_to_view_distance(depth: float | np.ndarray, far: float) -> np.ndarray:
    """Invert the logarithmic depth of shaders/terrain.frag: w = 2^(d log2(1 + far)) - 1."""
    return np.exp2(np.asarray(depth, dtype=np.float64) * math.log2(1.0 + far)) - 1.0


def unproject(view: ViewState, x_px: float, y_px: float, depth: float) -> np.ndarray:
    """ECEF point (m) of pixel (x_px, y_px) (top-left origin, pixel centres at +0.5) whose
    window depth is ``depth`` (0..1, logarithmic)."""
    w = float(depth_to_view_distance(depth, view.far))
    ndc_x = 2.0 * x_px / view.viewport[0] - 1.0
    ndc_y = 1.0 - 2.0 * y_px / view.viewport[1]
    t = math.tan(math.radians(view.fovy_deg) / 2.0)
    p_cam = np.array([ndc_x * t * view.aspect * w, ndc_y * t * w, -w])
    return view.eye + view.rotation.T @ p_cam


def read_depth(fbo: moderngl.Framebuffer, x_px: int, y_px: int) -> float:
    """Window depth of one pixel (top-left origin) of a framebuffer."""
    h = fbo.size[1]
    data = fbo.read(viewport=(int(x_px), h - 1 - int(y_px), 1, 1), attachment=-1, dtype="f4")
    return float(np.frombuffer(data, dtype=np.float32)[0])


def pick(view: ViewState, fbo: moderngl.Framebuffer, x_px: float, y_px: float) -> Pick | None:
    """The point under pixel (x_px, y_px) (top-left origin; the pixel's centre is used)."""
    xi, yi = int(x_px), int(y_px)
    if not (0 <= xi < view.viewport[0] and 0 <= yi < view.viewport[1]):
        return None
    depth = read_depth(fbo, xi, yi)
    if depth < 1.0:
        p = unproject(view, xi + 0.5, yi + 0.5, depth)
        on_terrain = True
    else:
        ray = view.pixel_ray(xi, yi)
        p = np.asarray(ray_ellipsoid_intersection(view.eye, ray), dtype=np.float64)
        if not np.all(np.isfinite(p)):
            return None
        on_terrain = False
    lon, lat, h = ecef_to_lonlat(p)
    return Pick(p, float(lon), float(lat), float(h), on_terrain)
