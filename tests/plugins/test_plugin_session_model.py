"""`GlobeSession` keeps its state in the `Globe` model (issue #14): one copy, the session's
properties delegate to it and every change emits the model's event."""

from __future__ import annotations

import pytest

from globeview.model import Camera, Globe

pytestmark = pytest.mark.gl


@pytest.fixture
def session(globeview_gl, globeview_terrain, globeview_registry):
    from globeview.app.session import GlobeSession

    s = GlobeSession(globeview_gl, globeview_terrain, registry=globeview_registry)
    yield s
    s.release_gl()


@pytest.mark.slow
def test_session_state_is_the_globe(session) -> None:
    g = session.globe
    seen: list = []
    g.events.tau_px.connect(lambda v: seen.append(("tau", v)))
    g.events.lod.connect(lambda v: seen.append(("lod", v)))
    g.events.camera.connect(lambda c: seen.append(("camera", c)))
    session.tau_px = 3.0
    session.set_lod("quadtree-clod")
    cam = Camera.from_lonlat(-71.3, 44.27, 3e4)
    session.camera = cam
    assert (g.tau_px, g.lod, g.camera) == (3.0, "quadtree-clod", cam)
    assert seen == [("tau", 3.0), ("lod", "quadtree-clod"), ("camera", cam)]
    assert session.settings is g.display and session.renderer.settings is g.display
    assert session.overlay_layers is g.overlays


@pytest.mark.slow
def test_session_takes_a_globe_made_before_gl(globeview_gl, globeview_terrain, globeview_registry):
    from globeview.app.session import GlobeSession

    globe = Globe(globeview_terrain, lod="quadtree-clod", tau_px=5.0)
    globe.display.exaggeration = 2.0
    s = GlobeSession(globeview_gl, globeview_terrain, registry=globeview_registry, globe=globe)
    try:
        assert s.globe is globe and s.lod_name == "quadtree-clod" and s.tau_px == 5.0
        assert s.settings.exaggeration == 2.0
        with pytest.raises(ValueError, match="not the globe's terrain"):
            GlobeSession(globeview_gl, object(), registry=globeview_registry, globe=globe)
    finally:
        s.release_gl()


@pytest.mark.slow
def test_unknown_lod_changes_nothing(session) -> None:
    from globeview.errors import GlobeviewError

    seen: list = []
    session.globe.events.lod.connect(seen.append)
    with pytest.raises(GlobeviewError):
        session.set_lod("no-such-provider")
    assert session.lod_name == "chunked-sse" and seen == []


@pytest.mark.slow
def test_a_refused_lod_name_at_construction_leaves_no_gl_objects(
    globeview_gl, globeview_terrain, globeview_registry
) -> None:
    from globeview.app.session import GlobeSession
    from globeview.errors import GlobeviewError
    from globeview.render.gpu_objects import gpu_objects

    tracker = gpu_objects(globeview_gl)
    before = tracker.counts()
    with pytest.raises(GlobeviewError, match="no enabled LOD provider"):
        GlobeSession(globeview_gl, globeview_terrain, registry=globeview_registry, lod="nope")
    assert tracker.counts() == before


@pytest.mark.slow
def test_release_gl_disconnects_the_session_from_the_globe(
    globeview_gl, globeview_terrain, globeview_registry
) -> None:
    # A window's model outlives the sessions shown on it: a released session's tool host
    # must not go on following (and holding) the globe's tool events.
    from globeview.app.session import GlobeSession

    globe = Globe(globeview_terrain)
    before = len(globe.events.tool)
    s = GlobeSession(globeview_gl, globeview_terrain, registry=globeview_registry, globe=globe)
    assert len(globe.events.tool) == before + 1  # the tool host follows the globe
    s.release_gl()
    assert len(globe.events.tool) == before
    globe.tool = None  # nothing of the released session runs
    globe.tool = "measure"
    assert globe.tool == "measure"  # no host resets it any more
