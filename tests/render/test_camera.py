"""Camera: (lon, lat, height, heading, pitch, roll) round trips and the navigation operations,
checked through what the view shows (ViewState.project)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from globeview.geodesy import enu_basis, lonlat_to_ecef, ray_ellipsoid_intersection
from globeview.lod.view_state import ViewState
from globeview.model.camera import MIN_HEIGHT_M, Camera

VIEWPORT = (640, 480)


def angle_diff(a: float, b: float) -> float:
    """Smallest difference between two angles in degrees."""
    return abs((a - b + 180.0) % 360.0 - 180.0)


def ground_point_at_pixel(cam: Camera, x: float, y: float) -> np.ndarray:
    view = ViewState.from_camera(cam, VIEWPORT)
    p = ray_ellipsoid_intersection(view.eye, view.pixel_ray(x, y))
    assert np.all(np.isfinite(p)), "the test pixel must see the globe"
    return np.asarray(p)


def project(cam: Camera, p: np.ndarray) -> np.ndarray:
    return ViewState.from_camera(cam, VIEWPORT).project(p)[0]


# -- round trips -------------------------------------------------------------------------------
ROUND_TRIP_CASES = [
    (lon, lat, h, hd, pt, rl)
    for (lon, lat), h, (hd, pt, rl) in itertools.product(
        [
            (0.0, 0.0),
            (-71.3, 44.2),
            (139.7, -35.0),
            (179.999, 10.0),
            (-179.999, -10.0),
            (45.0, 89.5),
            (-120.0, -89.5),
        ],
        [10.0, 3.0e4, 2.0e7],
        [
            (0.0, -45.0, 0.0),
            (90.0, 0.0, 0.0),
            (200.0, -10.0, 15.0),
            (315.0, 30.0, -40.0),
            (10.0, -89.0, 5.0),
            (170.0, 60.0, 170.0),
        ],
    )
]


@pytest.mark.parametrize(("lon", "lat", "h", "heading", "pitch", "roll"), ROUND_TRIP_CASES)
def test_lonlat_hpr_round_trip(
    lon: float, lat: float, h: float, heading: float, pitch: float, roll: float
) -> None:
    cam = Camera.from_lonlat(lon, lat, h, heading, pitch, roll)
    lon2, lat2, h2, hd2, pt2, rl2 = cam.lonlat_hpr()
    assert angle_diff(lon2, lon) < 1e-8
    assert lat2 == pytest.approx(lat, abs=1e-8)
    assert h2 == pytest.approx(h, abs=1e-5)
    assert angle_diff(hd2, heading) < 1e-6
    assert pt2 == pytest.approx(pitch, abs=1e-6)
    assert angle_diff(rl2, roll) < 1e-6


@pytest.mark.parametrize("heading", [0.0, 37.0, 90.0, 181.0, 300.0])
@pytest.mark.parametrize(("lon", "lat"), [(0.0, 0.0), (-71.3, 44.2), (180.0, -60.0)])
def test_straight_down_heading_comes_from_the_image_up_vector(
    heading: float, lon: float, lat: float
) -> None:
    cam = Camera.from_lonlat(lon, lat, 5000.0, heading, -90.0, 0.0)
    lon2, lat2, _, hd2, pt2, rl2 = cam.lonlat_hpr()
    # asin near -1 loses about sqrt(eps) rad: 1e-6 degrees is the best it can do.
    assert pt2 == pytest.approx(-90.0, abs=1e-5)
    assert angle_diff(hd2, heading) < 1e-6
    assert rl2 == pytest.approx(0.0, abs=1e-9)
    # The top of the image points to the compass direction `heading`.
    e, n, _ = enu_basis(lon2, lat2)
    top = cam.up
    assert angle_diff(math.degrees(math.atan2(top @ e, top @ n)), heading) < 1e-6


@pytest.mark.parametrize(
    ("lon", "lat", "h", "heading", "pitch", "roll"),
    [
        (10.0, -90.0, 1.0e6, 30.0, -90.0, 20.0),  # straight down with roll: folds into heading
        (0.0, 90.0, 2.0e6, 45.0, -30.0, 0.0),  # exactly at the pole: longitude is arbitrary
        (-180.0, 0.0, 1.0e5, 270.0, -90.0, 0.0),
        (180.0, 45.0, 1.0e3, 90.0, 89.0, -10.0),
    ],
)
def test_round_trip_reproduces_the_same_view_in_degenerate_cases(
    lon: float, lat: float, h: float, heading: float, pitch: float, roll: float
) -> None:
    cam = Camera.from_lonlat(lon, lat, h, heading, pitch, roll)
    again = Camera.from_lonlat(*cam.lonlat_hpr())
    np.testing.assert_allclose(again.eye, cam.eye, atol=1e-4)
    np.testing.assert_allclose(again.rotation, cam.rotation, atol=1e-7)


def test_heading_pitch_roll_mean_what_the_image_shows() -> None:
    lon, lat, h = 8.0, 46.0, 1000.0
    e, n, u = enu_basis(lon, lat)
    eye = lonlat_to_ecef(lon, lat, h)
    w, hgt = VIEWPORT
    # Heading 0, pitch 0: a point due north at eye level is in the image centre, a point to
    # the north-east is right of centre, a point north and lower is below centre.
    cam = Camera.from_lonlat(lon, lat, h, 0.0, 0.0, 0.0)
    x, y, d = project(cam, eye + 5000.0 * n)
    assert (x, y) == pytest.approx((w / 2, hgt / 2), abs=1e-6) and d > 0
    assert project(cam, eye + 5000.0 * n + 1000.0 * e)[0] > w / 2 + 10
    assert project(cam, eye + 5000.0 * n - 1000.0 * u)[1] > hgt / 2 + 10
    # Heading 90 looks east.
    x, y, d = project(Camera.from_lonlat(lon, lat, h, 90.0, 0.0, 0.0), eye + 5000.0 * e)
    assert (x, y) == pytest.approx((w / 2, hgt / 2), abs=1e-6) and d > 0
    # Pitch -90 looks down; the north is at the top of the image for heading 0.
    down = Camera.from_lonlat(lon, lat, h, 0.0, -90.0, 0.0)
    x, y, d = project(down, eye - 500.0 * u)
    assert (x, y) == pytest.approx((w / 2, hgt / 2), abs=1e-6) and d > 0
    assert project(down, eye - 500.0 * u + 100.0 * n)[1] < hgt / 2 - 10
    # Roll 30 (Cesium's convention): the camera banks clockwise, its right side dipping, so
    # the world turns counter-clockwise in the image: a point straight ahead and above the
    # view axis moves to the left of centre, and the horizon tilts up to the right.
    rolled = Camera.from_lonlat(lon, lat, h, 0.0, 0.0, 30.0)
    assert rolled.right @ u == pytest.approx(-0.5, abs=1e-9)
    x, y, _ = project(rolled, eye + 5000.0 * n + 1000.0 * u)
    assert x < w / 2 - 10 and y < hgt / 2
    east_far, west_far = (project(rolled, eye + 5000.0 * n + s * 2000.0 * e) for s in (1, -1))
    assert east_far[1] < west_far[1]


# -- globe-orbit navigation ---------------------------------------------------------------------
@pytest.mark.parametrize(
    ("start", "grab_px", "target_px"),
    [
        ((10.0, 30.0, 5.0e6, 0.0, -90.0, 0.0), (320.0, 240.0), (420.0, 200.0)),
        ((-71.3, 44.2, 3.0e4, 40.0, -35.0, 0.0), (300.0, 350.0), (250.0, 400.0)),
        ((179.5, -20.0, 1.0e6, 300.0, -60.0, 10.0), (100.0, 100.0), (500.0, 380.0)),
    ],
)
def test_orbit_drag_carries_the_grabbed_point_under_the_cursor(
    start: tuple[float, ...], grab_px: tuple[float, float], target_px: tuple[float, float]
) -> None:
    cam = Camera.from_lonlat(*start)
    grabbed = ground_point_at_pixel(cam, *grab_px)
    target = ground_point_at_pixel(cam, *target_px)
    before = project(cam, grabbed)
    cam.orbit_drag(grabbed, target)
    after = project(cam, grabbed)
    want = np.array(target_px) + 0.5  # pixel_ray goes through the pixel centre
    # The drag turns about the Earth's centre by the rotation between the two directions, so
    # on the (non-spherical) ellipsoid it is exact only up to the radius difference of the
    # two points: a small fraction of a pixel.
    assert np.hypot(*(after[:2] - want)) < 0.25
    assert np.hypot(*(after[:2] - before[:2])) > 10.0  # the globe did move
    # The camera turned about the Earth's centre: its distance from it is unchanged.
    assert np.linalg.norm(cam.eye) == pytest.approx(np.linalg.norm(lonlat_to_ecef(*start[:3])))


@pytest.mark.parametrize("factor", [0.5, 0.1, 1.7])
def test_zoom_toward_keeps_the_target_pixel_fixed(factor: float) -> None:
    cam = Camera.from_lonlat(-71.3, 44.2, 2.0e4, 20.0, -40.0, 0.0)
    target = ground_point_at_pixel(cam, 400.0, 300.0)
    d0 = np.linalg.norm(cam.eye - target)
    before = project(cam, target)
    cam.zoom_toward(target, factor)
    after = project(cam, target)
    assert np.hypot(*(after[:2] - before[:2])) < 1e-6
    assert np.linalg.norm(cam.eye - target) == pytest.approx(d0 * factor, rel=1e-9)


def test_zoom_toward_stops_above_the_ground() -> None:
    cam = Camera.from_lonlat(0.0, 0.0, 100.0, 0.0, -90.0)
    target = lonlat_to_ecef(0.0, 0.0, 0.0)
    eye0 = cam.eye.copy()
    cam.zoom_toward(target, 0.001)  # would end 0.1 m above the ellipsoid
    np.testing.assert_array_equal(cam.eye, eye0)
    cam.zoom_toward(target, 0.5)
    assert cam.height == pytest.approx(50.0, abs=1e-6)
    assert cam.height >= MIN_HEIGHT_M


def test_tilt_and_rotate_about_a_pivot_keep_it_in_place() -> None:
    cam = Camera.from_lonlat(-71.3, 44.2, 5000.0, 0.0, -90.0)
    pivot = np.asarray(lonlat_to_ecef(-71.3, 44.2, 0.0))
    c = np.array(VIEWPORT) / 2
    cam.rotate_heading_about(pivot, 30.0)
    lon, lat, h, hd, pt, _ = cam.lonlat_hpr()
    assert (lon, lat, h) == pytest.approx((-71.3, 44.2, 5000.0), abs=1e-6)
    assert angle_diff(hd, 30.0) < 1e-6 and pt == pytest.approx(-90.0, abs=1e-6)
    assert project(cam, pivot)[:2] == pytest.approx(c, abs=1e-6)
    cam.tilt_about(pivot, 30.0)  # nose up by 30 degrees, still looking at the pivot
    _, _, h, hd, pt, _ = cam.lonlat_hpr()
    assert pt == pytest.approx(-60.0, abs=0.1)
    assert angle_diff(hd, 30.0) < 0.1
    assert h < 5000.0  # swung down and back around the pivot
    assert project(cam, pivot)[:2] == pytest.approx(c, abs=1e-6)


# -- fly navigation ------------------------------------------------------------------------------
def test_fly_yaw_turns_right_in_place() -> None:
    cam = Camera.from_lonlat(-71.3, 44.2, 3000.0, 10.0, -20.0, 0.0)
    eye0 = cam.eye.copy()
    cam.fly_yaw(25.0)
    _, _, _, hd, pt, rl = cam.lonlat_hpr()
    np.testing.assert_array_equal(cam.eye, eye0)
    assert angle_diff(hd, 35.0) < 1e-6
    assert pt == pytest.approx(-20.0, abs=1e-6) and rl == pytest.approx(0.0, abs=1e-6)
    cam.fly_yaw(-50.0)
    assert angle_diff(cam.lonlat_hpr()[3], 345.0) < 1e-6


def test_fly_pitch_raises_the_nose_in_place() -> None:
    cam = Camera.from_lonlat(-71.3, 44.2, 3000.0, 120.0, -20.0, 0.0)
    eye0 = cam.eye.copy()
    cam.fly_pitch(15.0)
    _, _, _, hd, pt, rl = cam.lonlat_hpr()
    np.testing.assert_array_equal(cam.eye, eye0)
    assert pt == pytest.approx(-5.0, abs=1e-6)
    assert angle_diff(hd, 120.0) < 1e-6 and rl == pytest.approx(0.0, abs=1e-6)
    cam.fly_pitch(-40.0)
    assert cam.lonlat_hpr()[4] == pytest.approx(-45.0, abs=1e-6)


def test_orbit_drag_is_exact_along_a_parallel() -> None:
    cam = Camera.from_lonlat(30.0, 50.0, 2.0e6, 0.0, -90.0)
    grabbed = np.asarray(lonlat_to_ecef(30.0, 50.0, 0.0))
    target = np.asarray(lonlat_to_ecef(33.0, 50.0, 0.0))
    want = project(cam, target)
    cam.orbit_drag(grabbed, target)
    assert project(cam, grabbed)[:2] == pytest.approx(want[:2], abs=1e-6)
    # The globe turned east under the cursor: the camera went about 3 degrees west (the
    # smallest rotation is about an axis a little off the Earth's, so not exactly).
    assert cam.lonlat_hpr()[:2] == pytest.approx((27.0, 50.0), abs=0.1)


def test_fly_forward_moves_along_the_view() -> None:
    cam = Camera.from_lonlat(-71.3, 44.2, 3000.0, 0.0, -30.0, 0.0)
    ahead = np.asarray(ray_ellipsoid_intersection(cam.eye, cam.forward))
    d0 = np.linalg.norm(ahead - cam.eye)
    eye0 = cam.eye.copy()
    cam.fly_forward(1000.0)
    assert np.linalg.norm(cam.eye - eye0) == pytest.approx(1000.0, rel=1e-9)
    assert np.linalg.norm(ahead - cam.eye) < d0 - 999.0
    assert cam.height == pytest.approx(3000.0 - 500.0, abs=1.0)  # sin(30 deg) of the move
    # The point ahead stays in the image centre: the move is along the view axis.
    assert project(cam, ahead)[:2] == pytest.approx(np.array(VIEWPORT) / 2, abs=1e-6)
    cam.fly_forward(-1000.0)
    np.testing.assert_allclose(cam.eye, eye0, atol=1e-6)
    # Flying into the ground is refused.
    cam.fly_forward(1.0e4)
    np.testing.assert_allclose(cam.eye, eye0, atol=1e-6)
    assert cam.height == pytest.approx(3000.0, abs=1e-6)


# -- hostile values (issue #13): the model refuses them, whoever sets them -------------------
@pytest.mark.parametrize(
    ("args", "needle"),
    [
        ((math.nan, 0.0, 1e7), "longitude"),
        ((math.inf, 0.0, 1e7), "longitude"),
        ((0.0, 95.0, 1e7), "latitude must be a finite number in -90..90 deg, not 95"),
        ((0.0, math.nan, 1e7), "latitude"),
        ((0.0, 0.0, -12001.0), "height"),
        ((0.0, 0.0, 1.1e9), "height"),
        ((0.0, 0.0, math.inf), "height"),
        ((0.0, 0.0, 1e7, math.nan, -90.0), "heading"),
        ((0.0, 0.0, 1e7, 0.0, -91.0), "pitch"),
        ((0.0, 0.0, 1e7, 0.0, -90.0, -math.inf), "roll"),
    ],
)
def test_from_lonlat_refuses_non_finite_and_out_of_range(args: tuple, needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        Camera.from_lonlat(*args)


@pytest.mark.parametrize("fov", [0.0, -10.0, 170.5, math.nan])
def test_camera_refuses_a_degenerate_field_of_view(fov: float) -> None:
    with pytest.raises(ValueError, match="field of view"):
        Camera.from_lonlat(0.0, 0.0, 1e7, fovy_deg=fov)


def test_extreme_but_valid_placements_give_a_finite_view() -> None:
    for args in [(540.0, 90.0, -12000.0), (-1e9, -90.0, 1e9, 1e300, 90.0, -7e15)]:
        cam = Camera.from_lonlat(*args)
        view = ViewState.from_camera(cam, VIEWPORT)
        assert np.all(np.isfinite(view.proj)) and np.all(np.isfinite(view.frustum_planes))
        lon = cam.lonlat_hpr()[0]
        assert -180.0 <= lon <= 180.0


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"tau_px": 0.0}, "tau"),
        ({"tau_px": -1.0}, "tau"),
        ({"tau_px": math.nan}, "tau"),
        ({"exaggeration": math.inf}, "exaggeration"),
        ({"exaggeration": -1.0}, "exaggeration"),
        ({"exaggeration": 1e9}, "exaggeration"),
    ],
)
def test_view_state_refuses_bad_tau_and_exaggeration(kw: dict, needle: str) -> None:
    cam = Camera.from_lonlat(0.0, 0.0, 1e7)
    with pytest.raises(ValueError, match=needle):
        ViewState.from_camera(cam, VIEWPORT, **kw)


@pytest.mark.slow
@pytest.mark.gl
@pytest.mark.parametrize("tau", [0.0, -1.0, math.nan, math.inf])
def test_scene_tau_setter_refuses_bad_values(scene, tau: float) -> None:
    before = scene.tau_px
    with pytest.raises(ValueError, match="tau"):
        scene.tau_px = tau
    assert scene.tau_px == before
