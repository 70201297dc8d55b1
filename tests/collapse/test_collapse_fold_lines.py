"""The collapse tool's fold lines lie on the ellipsoid, under the relief: drawn depth-tested
(the overlay default) the Cascades hide half of them in an oblique view. They are feedback,
drawn on top (``depth_test=False``), so the user sees where the land folds. Headless EGL, the
embedded terrain, the built-in plugin through the registry."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from globeview.model.camera import Camera

pytestmark = pytest.mark.gl

SIZE = (320, 240)
CRATER = (-122.1, 42.99)
SALISH = (-122.4, 48.2)
FOLD_RGB = np.array([255, 230, 26])  # the fold lines' colour (1.0, 0.9, 0.1)


@pytest.fixture(scope="module")
def session(globeview_terrain):
    from globeview.app.session import GlobeSession
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.render.offscreen import OffscreenTarget, RenderError, create_headless_context

    try:
        ctx = create_headless_context()
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")
    terrain = globeview_terrain  # the run's one embedded stack (tests/conftest.py)
    reg = PluginRegistry(MemorySettings()).discover()
    camera = Camera.from_lonlat(-121.8, 44.0, 2.5e5, 0.0, -50.0)  # oblique, over the Cascades
    return GlobeSession(ctx, terrain, camera, registry=reg), OffscreenTarget(ctx, SIZE)


def fold_pixels(session, target, primitives) -> int:
    """Fold-line-coloured pixels of a frame with ``primitives`` drawn over the terrain (by
    the frame itself: `GlobeSession.render` draws the tool's overlay)."""
    tool = session.tool()
    original = type(tool).overlay  # the session draws the tool's overlay: give it these
    type(tool).overlay = lambda self, view: primitives
    try:
        for _ in range(50):  # tiles stream in on worker threads
            result = session.render(target.fbo, SIZE)
            if result.stats.tiles_loading == 0:
                break
            time.sleep(0.1)
        assert result.overlay_drawn > 0
    finally:
        type(tool).overlay = original
    rgb = target.read_rgb().astype(int)
    return int((np.abs(rgb - FOLD_RGB).max(axis=2) < 40).sum())


@pytest.mark.slow
def test_fold_lines_stay_visible_over_the_relief(session) -> None:
    session, target = session
    tool = session.tools()["collapse"]
    session.registry.invoke(tool, "set_points", *CRATER, *SALISH, 0.2)
    session.activate_tool("collapse")
    try:
        own = [p for p in tool.overlay(None) if hasattr(p, "depth_test")]
        assert own and not any(p.depth_test for p in own)
        shown = fold_pixels(session, target, own)
        tested = fold_pixels(
            session, target, [dataclasses.replace(p, depth_test=True) for p in own]
        )
    finally:
        session.activate_tool(None)
    assert shown > 600, shown
    assert shown > 1.5 * tested, (shown, tested)  # the mountains hid the depth-tested ones
