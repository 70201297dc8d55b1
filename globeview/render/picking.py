"""Picking (thesis §3.5.4, "reverse projection"): read the depth under a pixel and unproject
it to ECEF, then geodetic lon/lat/height; where nothing was drawn, fall back to the ray's
intersection with the ellipsoid.

The depth buffer holds a logarithmic depth computed per vertex and interpolated linearly
across each triangle (shaders/terrain.vert): exact at vertices, approximate inside the large
triangles of a coarse LOD. So when the terrain is at hand, the pick is refined along the same
pixel ray to the point whose height equals the DEM's height there (a few fixed-point steps of
ray / height-inflated-ellipsoid intersection). The result stays on the pixel's ray (it
re-projects to the same pixel) and reports the DEM's height, which is what a GIS user expects
in the status bar."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import moderngl
import numpy as np

from globeview.geodesy import ecef_to_lonlat, ray_ellipsoid_intersection, ray_ellipsoid_t
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
    vp = (int(x_px), h - 1 - int(y_px), 1, 1)
    data = fbo.read(viewport=vp, attachment=-1, components=1, dtype="f4")
    # Reading the depth attachment leaves the framebuffer's read buffer at GL_NONE; a window
    # framebuffer (Qt's) then grabs black. One colour read restores the read buffer.
    fbo.read(viewport=vp, components=3)
    return float(np.frombuffer(data, dtype=np.float32)[0])


def refine_on_terrain(
    view: ViewState,
    direction: np.ndarray,
    t0: float,
    height_at: Callable[[float, float], float],
    steps: int = 8,
) -> float:
    """Ray parameter t (m along the unit ``direction`` from the eye) where the ray meets the
    terrain surface drawn at ``view.exaggeration``, starting from the estimate ``t0``."""
    exag = view.exaggeration
    best_t, best_f = t0, math.inf
    t = t0
    for _ in range(steps):
        lon, lat, h = ecef_to_lonlat(view.eye + t * direction)
        hd = height_at(float(lon), float(lat)) * exag
        f = abs(float(h) - hd)
        if f < best_f:
            best_t, best_f = t, f
        if f < 0.01:
            break
        t_new = float(ray_ellipsoid_t(view.eye, direction, h=hd))
        if not math.isfinite(t_new):
            break
        t = t_new
    return best_t


def pick(
    view: ViewState,
    fbo: moderngl.Framebuffer,
    x_px: float,
    y_px: float,
    height_at: Callable[[float, float], float] | None = None,
) -> Pick | None:
    """The point under pixel (x_px, y_px) (top-left origin; the pixel's centre is used).

    ``height_at(lon, lat) -> metres`` (the composed DEM) refines the depth-buffer estimate
    onto the terrain surface; heights are reported without exaggeration."""
    xi, yi = int(x_px), int(y_px)
    if not (0 <= xi < view.viewport[0] and 0 <= yi < view.viewport[1]):
        return None
    depth = read_depth(fbo, xi, yi)
    ray = view.pixel_ray(xi, yi)
    if depth < 1.0:
        p = unproject(view, xi + 0.5, yi + 0.5, depth)
        on_terrain = True
        if height_at is not None:
            t = refine_on_terrain(view, ray, float(ray @ (p - view.eye)), height_at)
            p = view.eye + t * ray
    else:
        p = np.asarray(ray_ellipsoid_intersection(view.eye, ray), dtype=np.float64)
        if not np.all(np.isfinite(p)):
            return None
        on_terrain = False
    lon, lat, h = ecef_to_lonlat(p)
    h = float(h) / view.exaggeration if on_terrain else float(h)
    if view.exaggeration != 1.0:
        from globeview.geodesy import lonlat_to_ecef

        p = np.asarray(lonlat_to_ecef(float(lon), float(lat), h), dtype=np.float64)
    return Pick(p, float(lon), float(lat), h, on_terrain)
