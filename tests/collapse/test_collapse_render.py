"""The collapse drawn by the GPU (headless EGL): r = 1 is pixel-identical to no collapse, the
vertex shader agrees with the CPU twin (picks through the collapsed frame, inverted, land on
the true terrain where an un-collapsed frame sees it), and no crack opens for any LOD
provider."""

from __future__ import annotations

import math

import numpy as np
import pytest

from globeview.geodesy import WGS84
from globeview.model.camera import Camera

pytestmark = pytest.mark.gl

SIZE = (200, 150)
CRATER = (-122.1, 42.99)  # just north of Crater Lake
SALISH = (-122.4, 48.2)  # the south end of the Salish Sea topobathy
MAGENTA = (1.0, 0.0, 1.0)


@pytest.fixture(scope="module")
def gl():
    from globeview.render.offscreen import OffscreenTarget, RenderError, create_headless_context

    try:
        ctx = create_headless_context()
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")
    return ctx, OffscreenTarget(ctx, SIZE)


@pytest.fixture(scope="module")
def session(gl, globeview_terrain):
    from globeview.app.session import GlobeSession
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    terrain = globeview_terrain  # the run's one embedded stack (tests/conftest.py)
    reg = PluginRegistry(MemorySettings()).discover()
    return GlobeSession(gl[0], terrain, Camera.from_lonlat(-122.25, 45.6, 1.2e6), registry=reg)


def draw(session, gl, camera: Camera, collapse=None):
    """Render ``camera``; ``collapse`` = (A, B, ratio) activates the tool, None removes it.
    Returns the (h, w, 3) uint8 image and the frame result."""
    session.activate_tool(None)
    if collapse is not None:
        tool = session.tools()["collapse"]
        a, b, r = collapse
        session.registry.invoke(tool, "set_points", *a, *b, r)
        session.activate_tool("collapse")
    session.camera = camera
    result = session.render(gl[1].fbo, SIZE)
    return gl[1].read_rgb(), result


@pytest.mark.slow
def test_ratio_one_renders_pixel_identical(session, gl, monkeypatch) -> None:
    # The terrain alone: the frame also draws the tool's markers and fold lines (its
    # overlay), which are not part of what r = 1 must leave unchanged.
    monkeypatch.setattr(type(session.tools()["collapse"]), "overlay", lambda self, view: [])
    cam = Camera.from_lonlat(-122.6, 47.0, 4.0e5, 20.0, -60.0)
    plain, _ = draw(session, gl, cam)
    same, _ = draw(session, gl, cam, (CRATER, SALISH, 1.0))
    assert session.renderer.displacement_hook is not None  # the hook was compiled in
    assert np.array_equal(plain, same)
    moved, _ = draw(session, gl, cam, (CRATER, SALISH, 0.2))
    assert np.mean(np.any(moved != plain, axis=-1)) > 0.3
    assert session.registry.get("collapse").status == "ok"


def pixel_ground_m(view, point: np.ndarray) -> float:
    """Ground size (m) of one pixel at ``point`` for a near-nadir view."""
    dist = float(np.linalg.norm(point - view.eye))
    return dist * 2.0 * math.tan(math.radians(view.fovy_deg) / 2.0) / view.viewport[1]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("a", "b", "ratio", "cam"),
    [
        (CRATER, SALISH, 0.2, (-122.25, 45.6, 1.2e6)),  # 580 km, north-south
        ((-125.5, 49.5), (-113.0, 44.0), 0.3, (-120.0, 47.0, 2.2e6)),  # 1100 km, oblique
    ],
)
def test_gpu_matches_cpu_and_picks_report_true_coordinates(session, gl, a, b, ratio, cam) -> None:
    camera = Camera.from_lonlat(*cam)
    _, res_c = draw(session, gl, camera, (a, b, ratio))
    frame = session.tools()["collapse"].frame()
    xs = np.linspace(20, SIZE[0] - 20, 7)
    ys = np.linspace(15, SIZE[1] - 15, 5)
    picks = [(x, y, session.pick(x, y)) for y in ys for x in xs]
    picks = [(x, y, p) for x, y, p in picks if p is not None and p.on_terrain]
    assert len(picks) >= 30
    true = np.array([p.ecef for _, _, p in picks])
    psi, _ = frame.axis_angles(true)
    # The picks are inverted: they are not where they were drawn (outside the zone by the
    # shift (1 - r) d / 2).
    drawn_px = np.array([(x, y) for x, y, _ in picks])
    true_px = res_c.view.project(true)[:, :2]
    outside = np.abs(psi) > frame.psi0
    shift_px = np.linalg.norm(true_px - drawn_px, axis=1)
    assert outside.sum() >= 5 and np.median(shift_px[outside]) > 10.0
    # The un-collapsed frame sees the true terrain at those true points.
    _, res_t = draw(session, gl, camera)
    checked = 0
    for (x, y, p), (tx, ty), inside in zip(picks, true_px, ~outside, strict=True):
        if not (0 <= tx < SIZE[0] and 0 <= ty < SIZE[1]):
            continue
        q = session.pick(tx, ty)
        assert q is not None and q.on_terrain
        # One pixel's ground size at both ends (and 1/r of it inside the zone, where a drawn
        # pixel stands for 1/r times as much true ground), plus the LOD's tolerance.
        tol = 2.0 * pixel_ground_m(res_t.view, p.ecef) * (1.0 / ratio if inside else 1.0)
        gap = np.linalg.norm(q.ecef - p.ecef)
        assert gap <= tol + 50.0, (x, y, gap, tol)
        checked += 1
    assert checked >= 10


def ellipsoid_mask(view) -> np.ndarray:
    """(h, w) bool: pixels whose ray meets the WGS84 ellipsoid (float64, from scratch)."""
    w, h = view.viewport
    t = math.tan(math.radians(view.fovy_deg) / 2.0)
    nx, ny = np.meshgrid(
        ((np.arange(w) + 0.5) / w * 2 - 1) * t * view.aspect, (1 - (np.arange(h) + 0.5) / h * 2) * t
    )
    d = np.stack([nx, ny, -np.ones_like(nx)], axis=-1) @ view.rotation
    semi = np.array([WGS84.a, WGS84.a, WGS84.b])
    d, o = d / semi, view.eye / semi
    qa, qb, qc = np.sum(d * d, -1), np.sum(d * o, -1), float(o @ o) - 1.0
    inside = (qb * qb - qa * qc > 0) & (qb < 0)
    core = inside.copy()  # eroded by 2 px: the outline's pixels may be either
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            core &= np.roll(np.roll(inside, dy, 0), dx, 1)
    return core


@pytest.mark.slow
@pytest.mark.parametrize(
    ("cam", "pair", "ratio"),
    [
        ((-100.0, 30.0, 1.6e7), ((-122.0, 40.0), (-75.0, 40.0)), 0.2),  # 4000 km, whole globe
        ((-122.35, 47.7, 4.0e4), (CRATER, SALISH), 0.2),  # straight down on the B zone edge
        # Oblique 0.1 collapse: long edges across the fold lines would open gaps between
        # tiles of different strides unless each provider refines where the fold bends.
        ((-120.0, 44.0, 5.0e5, 300.0, -55.0), ((-123.0, 48.5), (-118.0, 44.0)), 0.1),
    ],
)
def test_no_cracks_with_the_collapse_for_every_lod_provider(session, gl, cam, pair, ratio):
    session.settings.background = MAGENTA
    try:
        for name in sorted(session.lod_providers()):
            session.set_lod(name)
            rgb, res = draw(session, gl, Camera.from_lonlat(*cam), (*pair, ratio))
            magenta = np.all(np.abs(rgb.astype(int) - [255, 0, 255]) <= 2, axis=-1)
            if len(cam) == 3 and cam[2] < 1e6:  # nadir close-up: the view is all ground
                assert not magenta.any(), name
            else:
                assert not magenta[ellipsoid_mask(res.view)].any(), name
    finally:
        session.set_lod("chunked-sse")
        session.settings.background = (0.0, 0.0, 0.0)


@pytest.mark.slow
def test_session_view_carries_the_collapse_bend_hook(session, gl) -> None:
    """With the collapse active the view carries its bend bound and displacement key (LOD
    providers use them); the bound covers the exact measure; without a tool, neither."""
    from globeview.lod.culling import displacement_bend_m, displacement_chord_error_m

    cam = Camera.from_lonlat(-120.0, 44.0, 5.0e5, 300.0, -55.0)
    draw(session, gl, cam, ((-123.0, 48.5), (-118.0, 44.0), 0.1))
    try:
        view = session.view_state(SIZE)
        assert view.displace is not None and view.displacement_bend is not None
        assert view.displacement_key is not None
        rng = np.random.default_rng(11)
        w, s = rng.uniform(-130.0, -110.0, 300), rng.uniform(38.0, 52.0, 300)
        from globeview.lod.culling import tile_bounding_points

        pts, _ = tile_bounding_points(w, s, w + 0.4, s + 0.4, np.zeros(300), np.full(300, 2e3))
        exact = displacement_chord_error_m(view.displace, pts)
        assert np.all(displacement_bend_m(view, pts) >= exact - 1e-6)
    finally:
        session.activate_tool(None)
    view = session.view_state(SIZE)
    assert view.displace is None and view.displacement_bend is None
