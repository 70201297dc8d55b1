"""Shared fixtures for the renderer tests: one headless GL context, the embedded terrain and
one `GlobeScene` for the whole session (rendering is slow on llvmpipe), plus numpy oracles
that are independent of the renderer (ray/ellipsoid silhouettes, DEM height look-ups)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest

from globeview.geodesy import WGS84, ecef_to_lonlat
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera

MAGENTA = (1.0, 0.0, 1.0)


@pytest.fixture(scope="session")
def gl_ctx(globeview_gl):
    """The plugin-author fixture's context: its leak check fails a test that drops GL
    objects unreleased (`globeview.app.testing`)."""
    return globeview_gl


@pytest.fixture(scope="session")
def terrain(globeview_terrain):
    """The embedded terrain: the run's one stack (`globeview_terrain`, tests/conftest.py),
    which the plugin fixtures draw too (a second stack measures its blend masks again)."""
    return globeview_terrain


@pytest.fixture(scope="session")
def _shared_scene(gl_ctx, terrain):
    # The renderer under test with the built-in chunked screen-space-error selection, called
    # directly (no plugin registry): these tests are about drawing, not plugin management.
    from globeview.lod.sse_policy import ScreenSpaceErrorPolicy
    from globeview.lod.traversal import traverse
    from globeview.render.scene import GlobeScene

    return GlobeScene(
        gl_ctx,
        terrain,
        Camera.from_lonlat(0.0, 20.0, 2.0e7),
        lod=lambda v, t: traverse(v, t, ScreenSpaceErrorPolicy()),
    )


@pytest.fixture
def scene(_shared_scene) -> Iterator:
    """The session's scene with default settings restored for each test."""
    sc = _shared_scene
    defaults = replace(sc.settings)
    tau = sc.tau_px
    yield sc
    s = sc.settings
    for name in ("exaggeration", "wireframe", "hillshade", "fog", "background", "wire_color"):
        setattr(s, name, getattr(defaults, name))
    sc.tau_px = tau


@pytest.fixture
def chunked_scene(scene):
    """The session's scene choosing its tiles as the default provider (chunked-sse) does: the
    fewest triangles within tau, which draws tiles up to `BEYOND_DATA_LEVELS` past the finest
    data (the shared scene's own policy stops at the data)."""
    from globeview.lod.sse_policy import ScreenSpaceErrorPolicy
    from globeview.lod.traversal import traverse

    lod = scene.lod
    scene.lod = lambda v, t: traverse(v, t, ScreenSpaceErrorPolicy(min_triangles=True))
    yield scene
    scene.lod = lod


@pytest.fixture(scope="session")
def targets(gl_ctx):
    """Offscreen targets by size, created once each."""
    from globeview.render.offscreen import OffscreenTarget

    cache: dict[tuple[int, int], OffscreenTarget] = {}

    def get(size: tuple[int, int]) -> OffscreenTarget:
        if size not in cache:
            cache[size] = OffscreenTarget(gl_ctx, size)
        return cache[size]

    return get


def render(scene, targets, camera: Camera, size: tuple[int, int] = (320, 240)):
    """Render ``camera`` into a target of ``size``; returns (rgb (h, w, 3) uint8, result)."""
    tgt = targets(size)
    scene.camera = camera
    result = scene.render(tgt.fbo, size)
    return tgt.read_rgb(), result


def is_colour(rgb: np.ndarray, colour: tuple[float, float, float], tol: int = 2) -> np.ndarray:
    """(h, w) bool: pixels equal to ``colour`` (0..1 floats) within ``tol`` levels."""
    ref = np.round(np.asarray(colour) * 255.0)
    return np.all(np.abs(rgb.astype(np.int32) - ref) <= tol, axis=-1)


def pixel_rays(view: ViewState) -> np.ndarray:
    """(h, w, 3) unit ECEF directions through every pixel centre (row 0 at the top)."""
    w, h = view.viewport
    xs = (np.arange(w) + 0.5) / w * 2.0 - 1.0
    ys = 1.0 - (np.arange(h) + 0.5) / h * 2.0
    t = np.tan(np.radians(view.fovy_deg) / 2.0)
    nx, ny = np.meshgrid(xs * t * view.aspect, ys * t)
    d_cam = np.stack([nx, ny, -np.ones_like(nx)], axis=-1)
    d = d_cam @ view.rotation  # rows of rotation are the camera axes in ECEF
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def ellipsoid_mask(view: ViewState, inflate_m: float = 0.0) -> np.ndarray:
    """(h, w) bool: pixels whose central ray meets the WGS84 ellipsoid (inflated by
    ``inflate_m``), computed in float64 from scratch (scaled-sphere quadratic)."""
    semi = np.array([WGS84.a, WGS84.a, WGS84.b]) + inflate_m
    d = pixel_rays(view) / semi
    o = view.eye / semi
    qa = np.sum(d * d, axis=-1)
    qb = np.sum(d * o, axis=-1)
    qc = float(o @ o) - 1.0
    disc = qb * qb - qa * qc
    return (disc > 0.0) & (qb < 0.0)


def erode(mask: np.ndarray, k: int) -> np.ndarray:
    """Binary erosion by a (2k+1)^2 square (outside the image counts as False)."""
    out = mask.copy()
    h, w = mask.shape
    for dy in range(-k, k + 1):
        for dx in range(-k, k + 1):
            shifted = np.zeros_like(mask)
            ys = slice(max(dy, 0), h + min(dy, 0))
            yd = slice(max(-dy, 0), h + min(-dy, 0))
            xs = slice(max(dx, 0), w + min(dx, 0))
            xd = slice(max(-dx, 0), w + min(-dx, 0))
            shifted[yd, xd] = mask[ys, xs]
            out &= shifted
    return out


def sandwiched(bg: np.ndarray, rows: bool = True) -> np.ndarray:
    """(h, w) bool: background pixels with non-background both above and below them in their
    column, or (with ``rows``) both left and right in their row: holes in the drawn surface.
    (Rows are wrong near a horizon, where sky shows between peaks.)"""
    fg = ~bg
    above = np.maximum.accumulate(fg, axis=0)
    below = np.maximum.accumulate(fg[::-1], axis=0)[::-1]
    left = np.maximum.accumulate(fg, axis=1)
    right = np.maximum.accumulate(fg[:, ::-1], axis=1)[:, ::-1]
    return bg & ((above & below) | ((left & right) if rows else False))


def dem_heights(terrain, lon: np.ndarray, lat: np.ndarray, level: int) -> np.ndarray:
    """Heights (m) of the composed DEM at points, bilinear in the tiles of ``level`` (read
    with `TerrainStack.heights`, interpolated here, so independent of the renderer)."""
    from globeview.terrain.quadtree import key_for_lonlat, tile_bounds_arrays

    lon = np.asarray(lon, dtype=np.float64).reshape(-1)
    lat = np.asarray(lat, dtype=np.float64).reshape(-1)
    kx, ky = key_for_lonlat(level, lon, lat)
    kx = np.asarray(kx).reshape(-1)
    ky = np.asarray(ky).reshape(-1)
    out = np.empty(len(lon))
    for x, y in {(int(a), int(b)) for a, b in zip(kx, ky, strict=True)}:
        sel = (kx == x) & (ky == y)
        grid = terrain.heights((level, x, y)).astype(np.float64)
        w, s, e, n = (float(v) for v in tile_bounds_arrays(level, x, y))
        m = grid.shape[0] - 1
        c = np.clip((lon[sel] - w) / (e - w) * m, 0.0, m)
        r = np.clip((n - lat[sel]) / (n - s) * m, 0.0, m)
        c0 = np.minimum(np.floor(c).astype(int), m - 1)
        r0 = np.minimum(np.floor(r).astype(int), m - 1)
        fc, fr = c - c0, r - r0
        top = grid[r0, c0] * (1 - fc) + grid[r0, c0 + 1] * fc
        bot = grid[r0 + 1, c0] * (1 - fc) + grid[r0 + 1, c0 + 1] * fc
        out[sel] = top * (1 - fr) + bot * fr
    return out


def ground_height(terrain, lon: float, lat: float) -> float:
    """The DEM height (m) at one point, at the finest level the data has (capped at 12)."""
    level = min(terrain.max_level, 12)
    return float(dem_heights(terrain, np.array([lon]), np.array([lat]), level)[0])


def camera_above_ground(
    terrain, lon: float, lat: float, agl: float, heading: float, pitch: float
) -> Camera:
    return Camera.from_lonlat(lon, lat, ground_height(terrain, lon, lat) + agl, heading, pitch)


def lonlat_of(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lon, lat, h = ecef_to_lonlat(np.asarray(points, dtype=np.float64))
    return np.asarray(lon), np.asarray(lat), np.asarray(h)


class _Helpers:
    """The module's helper functions, handed to tests as the ``gv`` fixture (test modules
    cannot import a conftest reliably when several test folders have one)."""

    MAGENTA = MAGENTA
    render = staticmethod(render)
    is_colour = staticmethod(is_colour)
    pixel_rays = staticmethod(pixel_rays)
    ellipsoid_mask = staticmethod(ellipsoid_mask)
    erode = staticmethod(erode)
    sandwiched = staticmethod(sandwiched)
    dem_heights = staticmethod(dem_heights)
    ground_height = staticmethod(ground_height)
    camera_above_ground = staticmethod(camera_above_ground)
    lonlat_of = staticmethod(lonlat_of)


@pytest.fixture(scope="session")
def gv() -> type[_Helpers]:
    return _Helpers
