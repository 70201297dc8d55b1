"""Tool overlays in headless renders (issue #15 item 8): a Marker's label is drawn beside it,
and a Polyline is depth-tested by default (a London–New York chord, a straight ECEF segment
through the Earth, is hidden where the globe covers it) or drawn on top when it asks."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.geodesy import lonlat_to_ecef
from globeview.model.camera import Camera
from globeview.plugins.api import Marker, Polyline

pytestmark = pytest.mark.gl
SIZE = (400, 300)
LONDON = (-0.1276, 51.5072)
NEW_YORK = (-74.006, 40.7128)
CHORD = (1.0, 0.0, 1.0, 1.0)  # magenta: no terrain colour is


@pytest.fixture(scope="module")
def rig(gl_ctx):
    """A target and the tool overlay renderer on the render suite's one GL context (a second
    EGL context in the same process breaks later tests' GL state)."""
    from globeview.render.offscreen import OffscreenTarget
    from globeview.render.overlay_tools import ToolOverlayRenderer

    target = OffscreenTarget(gl_ctx, SIZE)
    tools = ToolOverlayRenderer(gl_ctx)
    yield target, tools
    tools.release()
    target.release()


@pytest.fixture
def session(scene, rig):
    """The suite's scene looking down on the North Atlantic, with the target and renderer."""
    scene.settings.fog = False
    scene.camera = Camera.from_lonlat(-40.0, 50.0, 8.0e6)
    scene.target, scene.tools_renderer = rig
    return scene


def _ecef(lon: float, lat: float, h: float = 0.0) -> np.ndarray:
    return np.asarray(lonlat_to_ecef(lon, lat, h), np.float64).reshape(3)


def _draw(s, prims):
    s.render(s.target.fbo, SIZE)
    result = s.render(s.target.fbo, SIZE)
    before = s.target.read_rgb()
    s.tools_renderer.draw(result.view, prims, s.target.fbo)
    return before, s.target.read_rgb(), result.view


def _pixel(view, p: np.ndarray) -> tuple[int, int]:
    c = view.rotation @ (p - np.asarray(view.eye, np.float64))
    w, h = view.viewport
    t = np.tan(np.radians(view.fovy_deg) / 2.0)
    x, y = c[0] / -c[2] / (t * w / h), c[1] / -c[2] / t
    return round(float((1 - y) / 2 * h - 0.5)), round(float((x + 1) / 2 * w - 0.5))


def _magenta(rgb: np.ndarray) -> np.ndarray:
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return (r > 200) & (g < 80) & (b > 200)


def _around(mask: np.ndarray, rc: tuple[int, int], r: int = 3) -> int:
    row, col = rc
    return int(mask[max(row - r, 0) : row + r + 1, max(col - r, 0) : col + r + 1].sum())


@pytest.mark.slow
def test_london_new_york_chord_is_hidden_by_the_globe(session) -> None:
    a, b = _ecef(*LONDON), _ecef(*NEW_YORK)
    chord = np.stack([a, b])
    mid = 0.5 * (a + b)  # about 600 km under the Atlantic
    near_london = a + 0.03 * (b - a)  # 5 km deep: in front of the terrain, with the bias
    _, tested, view = _draw(session, [Polyline(chord, CHORD, 3.0)])
    _, on_top, _ = _draw(session, [Polyline(chord, CHORD, 3.0, depth_test=False)])
    m_tested, m_top = _magenta(tested), _magenta(on_top)
    # On top, the chord shows all along; depth-tested, the globe hides its middle.
    assert _around(m_top, _pixel(view, mid)) > 5
    assert _around(m_tested, _pixel(view, mid)) == 0
    assert _around(m_tested, _pixel(view, near_london)) > 5
    assert m_tested.sum() < 0.5 * m_top.sum()


def test_a_line_on_the_surface_stays_visible_when_depth_tested(session) -> None:
    """Points along the parallel 45 N at 100 m up: not lost in the terrain (the bias)."""
    pts = np.stack([_ecef(lon, 45.0, 100.0) for lon in np.linspace(-60.0, -20.0, 41)])
    _, rgb, view = _draw(session, [Polyline(pts, CHORD, 3.0)])
    m = _magenta(rgb)
    seen = [_around(m, _pixel(view, p)) > 0 for p in pts[5:-5]]
    assert np.mean(seen) > 0.9


def test_marker_labels_are_drawn_beside_the_marker(session) -> None:
    p = _ecef(-40.0, 50.0)
    plain, labelled, view = _draw(session, [Marker(tuple(p), label="Mid-Atlantic 42")])
    _, unlabelled, _ = _draw(session, [Marker(tuple(p))])
    row, col = _pixel(view, p)
    box = (slice(row - 8, row + 9), slice(col + 6, col + 90))  # right of the 8 px disc

    def white(rgb):
        return int(np.all(rgb[box] > 200, axis=-1).sum())

    assert white(labelled) > 40
    assert white(unlabelled) == 0 and white(plain) == 0
    assert session.tools_renderer.labels_drawn == 0  # the last draw had no label


@pytest.mark.slow
def test_labels_beyond_the_horizon_are_not_drawn(session) -> None:
    far = _ecef(140.0, -50.0)  # the other side of the globe
    _, rgb, _ = _draw(session, [Marker(tuple(far), label="Antipodes")])
    assert session.tools_renderer.labels_drawn == 0 and session.tools_renderer.drawn == 0
    plain, _, _ = _draw(session, [])
    assert np.array_equal(rgb, plain)


@pytest.mark.slow
def test_a_still_eye_keeps_the_instance_tables(session, monkeypatch) -> None:
    """The same primitives seen from the same eye draw from last frame's instance tables (no
    projection again: a still tool overlay costs no Python per repaint), the same pixels;
    another eye, or another primitive, makes them again."""
    import globeview.render.overlay_tools as ot

    calls = []
    real = ot.overlay_instances
    monkeypatch.setattr(ot, "overlay_instances", lambda *a: calls.append(1) or real(*a))
    line = Polyline(np.stack([_ecef(-45.0, 48.0), _ecef(-35.0, 52.0)]), width_px=3.0)
    prims = [Marker(tuple(_ecef(-40.0, 50.0)), label="kept"), line]
    _, first, view = _draw(session, prims)
    same = [Marker(tuple(_ecef(-40.0, 50.0)), label="kept"), line]  # equal, not the same objects
    _, again, _ = _draw(session, same)
    assert len(calls) == 1 and np.array_equal(first, again)
    session.tools_renderer.draw(
        view, [*same, Marker(tuple(_ecef(-30.0, 45.0)))], session.target.fbo
    )
    assert len(calls) == 2 and session.tools_renderer.drawn == real(view, prims).shape[0] + 1
    session.camera = Camera.from_lonlat(-41.0, 50.0, 8.0e6)
    _draw(session, same)
    assert len(calls) == 3
