"""Picking: the point under a pixel, read back from the depth buffer, lies under that pixel,
on the terrain the DEM describes; space gives nothing."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.geodesy import lonlat_to_ecef, ray_ellipsoid_intersection
from globeview.model.camera import Camera

pytestmark = pytest.mark.gl

SIZE = (320, 240)


def check_pick(scene, gv, terrain, x: int, y: int, level: int, height: bool = True) -> None:
    view = scene.last.view
    p = scene.pick(x, y)
    assert p is not None and p.on_terrain
    # Re-projected, the point is the picked pixel (its centre).
    px, py, depth = view.project(p.ecef)[0]
    assert depth > 0
    assert np.hypot(px - (x + 0.5), py - (y + 0.5)) < 1.0
    lon, lat, h = gv.lonlat_of(p.ecef)
    assert (float(lon), float(lat), float(h)) == pytest.approx((p.lon, p.lat, p.height), abs=1e-6)
    if not height:
        return
    # The height is that of the DEM around the place, give or take the geometric error the
    # LOD may leave (tau pixels at this distance) and the flat chords of coarse tiles.
    err_m = view.tau_px * depth / view.sse_factor
    radius = max(np.degrees(2.0 * depth / view.sse_factor / 6.37e6), 0.01)
    g1, g2 = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 9))
    near = gv.dem_heights(
        terrain,
        p.lon + radius * g1.ravel() / np.cos(np.radians(p.lat)),
        p.lat + radius * g2.ravel(),
        level,
    )
    assert near.min() - err_m - 5.0 <= p.height <= near.max() + err_m + 5.0


GLOBE_PIXELS = [(160, 120), (130, 100), (200, 150), (110, 140)]


@pytest.mark.slow
def test_pick_on_the_whole_globe(scene, targets, gv, terrain) -> None:
    _, result = gv.render(scene, targets, Camera.from_lonlat(0.0, 20.0, 2.0e7), SIZE)
    view = result.view
    for x, y in GLOBE_PIXELS:
        check_pick(scene, gv, terrain, x, y, level=3, height=False)
        # lon/lat agree with where the pixel's ray meets the ellipsoid, to within a pixel's
        # footprint (about 80 km here).
        p = scene.pick(x, y)
        q = ray_ellipsoid_intersection(view.eye, view.pixel_ray(x, y))
        assert np.linalg.norm(np.asarray(q) - p.ecef) < 3.0e5
        lon, lat, _ = gv.lonlat_of(q)
        assert (p.lon, p.lat) == pytest.approx((float(lon), float(lat)), abs=1.5)


def test_picked_height_on_the_whole_globe(scene, targets, gv, terrain) -> None:
    gv.render(scene, targets, Camera.from_lonlat(0.0, 20.0, 2.0e7), SIZE)
    for x, y in GLOBE_PIXELS:
        check_pick(scene, gv, terrain, x, y, level=3)


@pytest.mark.slow
def test_pick_a_known_place(scene, targets, gv, terrain) -> None:
    _, result = gv.render(scene, targets, Camera.from_lonlat(-71.3, 44.2, 3.0e4, 0.0, -90.0), SIZE)
    h = gv.ground_height(terrain, -71.25, 44.26)
    x, y, _ = result.view.project(lonlat_to_ecef(-71.25, 44.26, h))[0]
    p = scene.pick(x, y)
    assert p is not None and p.on_terrain
    # Within a pixel's footprint (30 km * 0.83 / 240 px ~ 100 m) of the place.
    assert p.lon == pytest.approx(-71.25, abs=0.003) and p.lat == pytest.approx(44.26, abs=0.002)
    assert p.height == pytest.approx(h, abs=60.0)


@pytest.mark.slow
@pytest.mark.parametrize(("agl", "pitch"), [(6000.0, -10.0), (800.0, -20.0)])
def test_pick_on_a_low_oblique_view(scene, targets, gv, terrain, agl: float, pitch: float) -> None:
    cam = gv.camera_above_ground(terrain, -71.3, 44.2, agl, 10.0, pitch)
    gv.render(scene, targets, cam, SIZE)
    view = scene.last.view
    for x, y in [(160, 200), (40, 230), (280, 180), (160, 150)]:
        check_pick(scene, gv, terrain, x, y, level=12)
        # The picked point is where the pixel's ray first meets the DEM (marched here).
        p = scene.pick(x, y)
        ray = view.pixel_ray(x, y)
        t = np.linspace(1.0, 1.5 * np.linalg.norm(p.ecef - view.eye), 4000)
        pts = view.eye + t[:, None] * ray
        lon, lat, hh = gv.lonlat_of(pts)
        below = hh <= gv.dem_heights(terrain, lon, lat, 12)
        assert below.any()
        t_hit = t[np.argmax(below)]
        t_pick = np.linalg.norm(p.ecef - view.eye)
        tol = 3.0 * view.tau_px * t_hit / view.sse_factor / max(abs(ray @ view.rotation[1]), 0.05)
        assert abs(t_pick - t_hit) <= tol + (t[1] - t[0]) + 5.0, (x, y, t_pick, t_hit, tol)


def test_pick_in_space_and_outside_the_image(scene, targets, gv) -> None:
    gv.render(scene, targets, Camera.from_lonlat(0.0, 20.0, 2.0e7), SIZE)
    assert scene.pick(2, 2) is None  # the ray misses the Earth
    assert scene.pick(-1, 100) is None and scene.pick(320, 100) is None
    assert scene.pick(100, 240) is None


@pytest.mark.slow
def test_every_pixel_on_the_globe_picks_terrain(scene, targets, gv) -> None:
    _, result = gv.render(scene, targets, Camera.from_lonlat(0.0, 0.0, 4.0e5, 0.0, -20.0), SIZE)
    mask = gv.erode(gv.ellipsoid_mask(result.view), 3)
    ys, xs = np.nonzero(mask)
    assert len(ys) > 1000
    for k in np.linspace(0, len(ys) - 1, 12).astype(int):
        p = scene.pick(int(xs[k]), int(ys[k]))
        assert p is not None and p.on_terrain
    ys, xs = np.nonzero(~gv.ellipsoid_mask(result.view, inflate_m=2.0e4))
    assert len(ys) > 1000  # sky above the horizon
    for k in np.linspace(0, len(ys) - 1, 6).astype(int):
        assert scene.pick(int(xs[k]), int(ys[k])) is None


@pytest.mark.slow
def test_read_depth_is_one_value_per_pixel(scene, targets, gv) -> None:
    _, result = gv.render(scene, targets, Camera.from_lonlat(0.0, 20.0, 2.0e7), SIZE)
    depth = targets(SIZE).read_depth()
    assert depth.shape == (SIZE[1], SIZE[0])
    # Space is at depth 1 (nothing drawn), the globe nearer.
    inside = gv.erode(gv.ellipsoid_mask(result.view), 3)
    space = ~gv.ellipsoid_mask(result.view, 2e4)
    assert (depth[inside] < 1.0).all() and (depth[space] == 1.0).all()


def test_terrain_height_at_matches_the_dem(terrain, gv) -> None:
    # The height the camera and status bar use (TerrainStack.height_at), against the tile
    # heights interpolated here.
    want = gv.ground_height(terrain, -71.3, 44.27)
    assert 300.0 < want < 1950.0
    assert terrain.height_at(-71.3, 44.27) == pytest.approx(want, abs=0.01)
