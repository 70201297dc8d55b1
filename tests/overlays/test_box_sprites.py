"""Boxes drawn as ray-cast point sprites (small, inside the view) look as the same boxes drawn
as meshes, and the per-frame choice between the two (`sprite_classes`) culls, keeps edges and
near boxes as meshes, and sends the small ones to sprites (one GL context for the module)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from globeview.model.camera import Camera

pytestmark = pytest.mark.gl
SIZE = (320, 240)


@pytest.fixture(scope="module")
def session(globeview_gl, globeview_terrain):
    from globeview.app.session import GlobeSession
    from globeview.render.offscreen import OffscreenTarget

    s = GlobeSession(globeview_gl, globeview_terrain, Camera.from_lonlat(10.0, 46.0, 4.0e6))
    s.settings.fog = False
    s.target = OffscreenTarget(globeview_gl, SIZE)
    yield s
    s.release_gl()
    s.target.release()


def _render(session, overlay, sprite_max_px, monkeypatch):
    import globeview.render.overlay_points as op

    monkeypatch.setattr(op, "SPRITE_MAX_PX", sprite_max_px)
    overlay._split = None  # choose again with the patched limit
    session.render(session.target.fbo, SIZE)
    return session.target.read_rgb()


@pytest.mark.slow
@pytest.mark.parametrize(
    ("camera", "scale_m"),
    [
        ((10.0, 46.0, 4.0e6, 0.0, -90.0), 6000.0),  # the scene: sub-pixel boxes
        ((10.0, 46.0, 1.5e6, 0.0, -90.0), 20000.0),  # a few pixels
        ((9.0, 44.0, 4.0e5, 30.0, -35.0), 8000.0),  # oblique: sprites, meshes and edges
    ],
)
def test_sprites_look_like_meshes(session, camera, scale_m, monkeypatch) -> None:
    """The same boxes as sprites (default) and as meshes (SPRITE_MAX_PX = 0) differ in at most
    a few pixels (faces' edges sampled a hair apart), and many box pixels are drawn."""
    from globeview.render.overlay_points import PointOverlay, PointStyle

    rng = np.random.default_rng(3)
    n = 3000
    lon, lat = rng.uniform(0.0, 20.0, n), rng.uniform(38.0, 54.0, n)
    session.camera = Camera.from_lonlat(*camera)
    ov = PointOverlay(
        session.ctx,
        lon,
        lat,
        None,
        PointStyle("box", scale_m=scale_m, color=(0.0, 1.0, 0.0, 1.0)),
        heading_deg=rng.uniform(0, 90, n),
    )
    session.renderer.overlays.points.append(ov)
    try:
        session.render(session.target.fbo, SIZE)  # pages the boxes in
        mesh = _render(session, ov, 0.0, monkeypatch).astype(int)
        assert ov.n_sprites == 0 and ov.n_meshes > 0
        sprite = _render(session, ov, 64.0, monkeypatch).astype(int)
        assert ov.n_sprites > 0
    finally:
        session.renderer.overlays.points.remove(ov)
        ov.release()
    green = (mesh[..., 1] > 100) & (mesh[..., 0] < 20) & (mesh[..., 2] < 20)
    assert green.sum() > 300
    differ = np.abs(mesh - sprite).max(axis=2) > 24
    assert differ.sum() <= max(0.03 * green.sum(), 4), (differ.sum(), green.sum())


@pytest.mark.slow
def test_sprite_classes(session) -> None:
    """Behind the eye or off the view's sides: neither; straddling an edge, near the eye or
    large: a mesh; small and inside: a sprite."""
    from globeview.render.overlay_points import SPRITE_MAX_PX, sprite_classes

    session.camera = Camera.from_lonlat(10.0, 46.0, 1.0e6, 0.0, -90.0)
    view = session.render(session.target.fbo, SIZE).view
    w, h = view.viewport
    px_m = 2.0 * math.tan(math.radians(view.fovy_deg) / 2.0) / h
    right, up, back = np.asarray(view.rotation, np.float64)
    depth = 1.0e6

    def at(x_px: float, y_px: float, z: float = depth) -> np.ndarray:
        """The point z metres in front of the eye seen at pixel offset (x, y) from the centre."""
        return -back * z + right * x_px * px_m * z + up * y_px * px_m * z

    small = 2.0 * px_m * depth  # a radius of 2 px
    rel = np.array(
        [
            at(0, 0),  # centre, small: sprite
            at(0.5 * w - 1.0, 0),  # straddles the right edge: mesh
            at(0.5 * w + 50.0, 0),  # beyond the right edge: neither
            -at(0, 0),  # behind the eye: neither
            at(0, 0),  # centre, large: mesh
            at(0, 0, 50.0),  # close to the eye (its radius is 40 m): mesh
        ]
    )
    radius = np.array([small, small, small, small, SPRITE_MAX_PX * px_m * depth, 40.0])
    sprite, mesh = sprite_classes(view, rel, radius)
    assert sprite.tolist() == [True, False, False, False, False, False]
    assert mesh.tolist() == [False, True, False, False, True, True]
    # Many boxes: the classes are disjoint, and every box seen is in one of them.
    rng = np.random.default_rng(1)
    rel = at(0, 0) + rng.normal(0.0, 4.0e5, (5000, 3))
    radius = rng.uniform(1.0, 3.0e4, 5000)
    sprite, mesh = sprite_classes(view, rel, radius)
    assert not (sprite & mesh).any() and sprite.sum() > 100 and mesh.sum() > 100
    # Hostile rows: no size, NaN or infinite positions: drawn in neither way.
    rel = np.array([at(0, 0), [np.nan, 0.0, 0.0], [np.inf, 1.0, 1.0], at(0, 0)])
    sprite, mesh = sprite_classes(view, rel, np.array([0.0, small, small, np.nan]))
    assert not sprite.any() and not mesh.any()


@pytest.mark.slow
@pytest.mark.parametrize(
    "camera", [(10.0, 46.0, 4.0e6, 0.0, -90.0), (9.0, 44.0, 4.0e5, 30.0, -35.0)]
)
def test_placemark_sprites_look_like_billboards(session, camera, monkeypatch) -> None:
    """Placemarks as point sprites (default) and as billboard quads (SPRITE_MAX_PX = 0) give
    the same image; those at the viewport's edges stay quads, so none is cut off there."""
    from globeview.render.overlay_points import PointOverlay, PointStyle

    rng = np.random.default_rng(4)
    n = 2000
    lon, lat = rng.uniform(0.0, 20.0, n), rng.uniform(38.0, 54.0, n)
    session.camera = Camera.from_lonlat(*camera)
    ov = PointOverlay(session.ctx, lon, lat, None, PointStyle("placemark", size_px=9.0))
    session.renderer.overlays.points.append(ov)
    try:
        session.render(session.target.fbo, SIZE)
        quads = _render(session, ov, 0.0, monkeypatch).astype(int)
        assert ov.n_sprites == 0 and ov.n_meshes > 0
        sprites = _render(session, ov, 64.0, monkeypatch).astype(int)
        assert ov.n_sprites > 0
        assert ov.n_meshes > 0 or camera[2] > 1.0e6  # the oblique view has some at its edges
    finally:
        session.renderer.overlays.points.remove(ov)
        ov.release()
    red = (quads[..., 0] > 230) & (quads[..., 1] < 90)
    assert red.sum() > 500
    differ = np.abs(quads - sprites).max(axis=2) > 24
    assert differ.sum() <= max(0.01 * red.sum(), 4), (differ.sum(), red.sum())


@pytest.mark.slow
def test_cones_out_of_view_are_culled_without_changing_the_image(session, monkeypatch) -> None:
    """Cones are drawn only where they may be seen: the same image as drawing every resident
    cone (the classes patched to keep all), with fewer instances drawn."""
    import globeview.render.overlay_points as op
    from globeview.render.overlay_points import PointOverlay, PointStyle

    rng = np.random.default_rng(6)
    n = 3000
    lon, lat = rng.uniform(0.0, 20.0, n), rng.uniform(38.0, 54.0, n)
    session.camera = Camera.from_lonlat(9.0, 44.0, 4.0e5, 30.0, -35.0)
    ov = PointOverlay(session.ctx, lon, lat, None, PointStyle("cone", scale_m=8000.0))
    session.renderer.overlays.points.append(ov)
    try:
        session.render(session.target.fbo, SIZE)
        culled = session.target.read_rgb().astype(int)
        drawn = ov.n_meshes
        keep_all = lambda view, rel, radius: (np.zeros(len(rel), bool), np.ones(len(rel), bool))  # noqa: E731
        monkeypatch.setattr(op, "sprite_classes", keep_all)
        ov._split = None
        session.render(session.target.fbo, SIZE)
        every = session.target.read_rgb().astype(int)
        assert ov.n_meshes == ov.resident > drawn > 0
    finally:
        session.renderer.overlays.points.remove(ov)
        ov.release()
    assert np.abs(culled - every).max() <= 2


@pytest.mark.slow
def test_a_still_view_keeps_its_sprite_choice(session, monkeypatch) -> None:
    """A still camera over the same boxes keeps last frame's sprite/mesh choice (no
    `sprite_classes` over every box, no upload); a turn, or boxes paged in again, choose
    again, and the same view draws the same image either way."""
    import globeview.render.overlay_points as op

    calls = []
    real = op.sprite_classes
    monkeypatch.setattr(op, "sprite_classes", lambda *a: calls.append(1) or real(*a))
    rng = np.random.default_rng(5)
    lon, lat = rng.uniform(0.0, 20.0, 500), rng.uniform(38.0, 54.0, 500)
    ov = op.PointOverlay(session.ctx, lon, lat, None, op.PointStyle("box", scale_m=20000.0))
    session.renderer.overlays.points.append(ov)
    try:
        session.camera = Camera.from_lonlat(10.0, 46.0, 1.5e6, 0.0, -90.0)
        session.render(session.target.fbo, SIZE)
        first = session.target.read_rgb()
        n = len(calls)
        session.render(session.target.fbo, SIZE)
        assert len(calls) == n and ov.n_sprites > 0  # still: the choice is kept
        assert np.array_equal(session.target.read_rgb(), first)
        session.camera.fly_yaw(0.5)
        session.render(session.target.fbo, SIZE)
        assert len(calls) == n + 1  # turned: chosen again
        ov._sig = None  # the objects paged in again: chosen again, even for the same view
        session.render(session.target.fbo, SIZE)
        assert len(calls) == n + 2
    finally:
        session.renderer.overlays.points.remove(ov)
        ov.release()
