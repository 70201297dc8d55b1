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
from globeview.lod.view_state import ViewState


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
    """Invert the logarithmic depth of shaders/log_depth.glsl: w = 2^(d log2(1 + far)) - 1."""
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
    to_true: Callable[[np.ndarray], np.ndarray] | None = None,
) -> float:
    """Ray parameter t (m along the unit ``direction`` from the eye) where the ray meets the
    terrain surface drawn at ``view.exaggeration``, starting from the estimate ``t0``.

    ``to_true`` maps drawn ECEF points (N, 3) to the true terrain points they show (a tool's
    displacement inverse, e.g. the collapse): the terrain drawn at a place is then the terrain
    of another place, so each step compares the true point's height with the DEM's height
    at the true lon/lat and moves the drawn point by that gap (the displacements keep heights
    above the ellipsoid, so the gap carries over)."""
    exag = view.exaggeration

    def gap(t: float) -> tuple[float, float]:
        """(signed height of the ray point above the drawn surface, the surface's height)."""
        p = view.eye + t * direction
        lon, lat, h = ecef_to_lonlat(p)
        if to_true is None:
            hd = height_at(float(lon), float(lat)) * exag
        else:
            tl, tb, th = ecef_to_lonlat(np.asarray(to_true(p[None, :]), dtype=np.float64)[0])
            hd = float(h) + height_at(float(tl), float(tb)) * exag - float(th)
        return float(h) - hd, hd

    best_t, best_f = t0, math.inf
    above: float | None = None  # largest t seen above the surface
    below: float | None = None  # smallest t seen below it
    t = t0
    for _ in range(steps):
        g, hd = gap(t)
        if abs(g) < best_f:
            best_t, best_f = t, abs(g)
        if abs(g) < 0.01:
            return t
        if g > 0:
            above = t if above is None else max(above, t)
        else:
            below = t if below is None else min(below, t)
        t_new = float(ray_ellipsoid_t(view.eye, direction, h=hd))
        if not math.isfinite(t_new):
            break
        t = t_new
    # The fixed point did not settle (steep slopes, a tool's fold): bisect between a point
    # above and one below the surface, found around the estimate if need be.
    for d in (1.0, 10.0, 100.0, 1000.0):
        if above is not None and below is not None:
            break
        for tt in (t0 - d, t0 + d):
            if tt > 0:
                g, _ = gap(tt)
                if g > 0:
                    above = tt if above is None else max(above, tt)
                else:
                    below = tt if below is None else min(below, tt)
    if above is None or below is None or above >= below:
        return best_t
    lo, hi = above, below
    for _ in range(48):
        mid = 0.5 * (lo + hi)
        g, _ = gap(mid)
        if abs(g) < best_f:
            best_t, best_f = mid, abs(g)
        if abs(g) < 0.01 or hi - lo < 1e-3:
            break
        lo, hi = (mid, hi) if g > 0 else (lo, mid)
    return best_t


def pick(
    view: ViewState,
    fbo: moderngl.Framebuffer,
    x_px: float,
    y_px: float,
    height_at: Callable[[float, float], float] | None = None,
    to_true: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Pick | None:
    """The point under pixel (x_px, y_px) (top-left origin; the pixel's centre is used).

    ``height_at(lon, lat) -> metres`` (the composed DEM's ellipsoidal height h) refines the
    depth-buffer estimate onto the terrain surface; heights are reported without
    exaggeration, as h (the UI converts to orthometric). ``to_true``: see
    `refine_on_terrain` (the returned point is still the drawn one)."""
    xi, yi = int(x_px), int(y_px)
    if not (0 <= xi < view.viewport[0] and 0 <= yi < view.viewport[1]):
        return None
    depth = read_depth(fbo, xi, yi)
    ray = view.pixel_ray(xi, yi)
    if depth < 1.0:
        p = unproject(view, xi + 0.5, yi + 0.5, depth)
        on_terrain = True
        if height_at is not None:
            t0 = float(ray @ (p - view.eye))
            t = refine_on_terrain(view, ray, t0, height_at, to_true=to_true)
            p = view.eye + t * ray
    else:
        p = np.asarray(ray_ellipsoid_intersection(view.eye, ray), dtype=np.float64)
        if not np.all(np.isfinite(p)):
            return None
        on_terrain = False
    lon, lat, h_drawn = ecef_to_lonlat(p)
    h = float(h_drawn) / view.exaggeration if on_terrain else float(h_drawn)
    if view.exaggeration != 1.0:
        from globeview.geodesy import lonlat_to_ecef

        p = np.asarray(lonlat_to_ecef(float(lon), float(lat), h), dtype=np.float64)
    return Pick(p, float(lon), float(lat), h, on_terrain)
