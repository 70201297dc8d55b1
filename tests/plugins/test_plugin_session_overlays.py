"""Overlay layers are GL-free models (issue #14): opening, adding, hiding, restyling and
removing one makes or frees no GL object; the renderer builds GPU twins from the model when
a frame is drawn, rebuilds a restyled one once, releases a removed one, and drops a layer
the GL side refuses with one line, leaving the others drawn."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.model.camera import Camera
from globeview.render.gpu_objects import gpu_objects

pytestmark = pytest.mark.gl
SIZE = (160, 120)


@pytest.fixture
def session(globeview_gl, globeview_terrain, globeview_registry):
    from globeview.app.session import GlobeSession
    from globeview.render.offscreen import OffscreenTarget

    s = GlobeSession(
        globeview_gl, globeview_terrain, Camera.from_lonlat(10.0, 46.0, 3.0e6), globeview_registry
    )
    s.target = OffscreenTarget(globeview_gl, SIZE)
    s.render(s.target.fbo, SIZE)  # the terrain's own GL objects exist before we count
    yield s
    s.release_gl()
    s.target.release()


def _frame(s):
    return s.render(s.target.fbo, SIZE)


@pytest.mark.slow
def test_model_changes_make_no_gl_objects_until_a_frame(session) -> None:
    tracker = gpu_objects(session.ctx)
    before = tracker.counts()
    events: list = []
    session.globe.events.overlays.connect(lambda: events.append("overlays"))
    borders, cities = (
        session.add_overlay("data/ne_110m_countries.geojson", layer_type="vector"),
        session.add_overlay("data/ne_cities.geojson", layer_type="points"),
    )
    borders.set_visible(False)
    cities.set_style(size_px=14.0)
    assert tracker.counts() == before  # nothing made without a frame
    assert events == ["overlays"] * 4  # two added, one hidden, one restyled
    result = _frame(session)
    assert sum(tracker.counts().values()) > sum(before.values())
    assert result.stats.extra.get("objects", 0) > 0  # the cities are drawn
    assert (
        "vector_segments" not in result.stats.extra or not result.stats.extra["vector_segments"]
    )  # the hidden borders are not
    session.remove_overlay(borders)
    session.remove_overlay(cities)
    assert sum(tracker.counts().values()) > sum(before.values())  # freed at the frame
    _frame(session)
    assert tracker.counts() == before


@pytest.mark.slow
def test_a_restyled_layer_is_rebuilt_once(session) -> None:
    tracker = gpu_objects(session.ctx)
    layer = session.add_overlay("data/ne_110m_countries.geojson", layer_type="vector")
    _frame(session)
    twin = session.renderer.overlays.vectors[-1]
    _frame(session)
    assert session.renderer.overlays.vectors[-1] is twin  # not rebuilt per frame
    layer.set_style(color=(1.0, 0.0, 1.0, 1.0), width_px=3.0)
    with pytest.raises(ValueError, match="no style 'lines'"):
        layer.set_style(lines=None)
    counts = tracker.counts()
    _frame(session)
    new = session.renderer.overlays.vectors[-1]
    assert new is not twin and new.style.color == (1.0, 0.0, 1.0, 1.0)
    assert tracker.counts() == counts  # the old twin was released, the new one made
    session.remove_overlay(layer)


@pytest.mark.slow
def test_a_file_opened_twice_is_two_rows_and_removing_one_keeps_the_other(session) -> None:
    # Layers compare by identity: the dataclass __eq__ compared their numpy arrays, so
    # removing one of two equal layers raised "truth value of an array is ambiguous".
    first = session.add_overlay("data/ne_cities.geojson", layer_type="points")
    second = session.add_overlay("data/ne_cities.geojson", layer_type="points")
    assert first is not second and first != second
    _frame(session)
    assert len(session.renderer.overlays.points) == 2
    session.remove_overlay(first)
    assert session.overlay_layers == [second]
    assert first not in session.overlay_layers and second in session.overlay_layers
    result = _frame(session)
    assert result.stats.extra.get("objects", 0) > 0  # the other one still draws
    assert len(session.renderer.overlays.points) == 1
    with pytest.raises(ValueError, match="not shown"):
        session.remove_overlay(first)  # gone already: one line, the other stays
    assert session.overlay_layers == [second]
    session.remove_overlay(second)


@pytest.mark.slow
def test_hiding_a_layer_from_code_is_one_event_and_the_next_frame_shows_it(session) -> None:
    # What a plugin or script does: call the layer's setter; the globe announces it.
    cities = session.add_overlay("data/ne_cities.geojson", layer_type="points")
    assert _frame(session).stats.extra.get("objects", 0) > 0
    events: list = []
    session.globe.events.overlays.connect(lambda: events.append("overlays"))
    cities.set_visible(False)
    assert events == ["overlays"]
    assert not _frame(session).stats.extra.get("objects", 0)  # hidden at the next frame
    cities.set_visible(False)
    assert events == ["overlays"]  # no change, no event
    cities.set_visible(True)
    assert events == ["overlays", "overlays"]
    assert _frame(session).stats.extra.get("objects", 0) > 0
    session.remove_overlay(cities)


@pytest.mark.slow
def test_a_layer_the_gpu_side_refuses_is_dropped_with_one_line(session) -> None:
    from globeview.model.overlay_layers import PointsLayer

    good = session.add_overlay("data/ne_cities.geojson", layer_type="points")
    bad = PointsLayer("spheres", np.array([10.0]), np.array([46.0]), [], object_kind="sphere")
    session.globe.add_overlay(bad)  # a model the point adapter cannot draw
    result = _frame(session)
    assert session.globe.overlays == [good]
    assert len(session.overlay_errors) == 1
    msg = session.overlay_errors[0]
    assert msg.startswith("cannot draw spheres: ") and "\n" not in msg
    assert result.stats.extra.get("objects", 0) > 0  # the other layer is drawn
    assert session.take_overlay_errors() == [msg]
    assert session.take_overlay_errors() == [] and session.overlay_errors == []  # taken once
    session.remove_overlay(good)


OLD_MANIFEST = """
    name = "oldlayer"
    version = "0.1.0"
    description = "an API 1.0 layer object"
    kinds = ["layer"]
    api_version = "1.0"

    [[contributions]]
    name = "oldlayer"
    kind = "layer"
    target = "gvt_oldlayer.impl:OldType"
    label = "Old"
    extensions = [".old"]
    """

OLD_IMPL = """
class Old:
    name = "old style"
    calls = []

    def __init__(self, broken):
        self.broken = broken

    def attach(self, renderer):
        Old.calls.append("attach")
        if self.broken:
            raise RuntimeError("no GL for you")

    def detach(self, renderer):
        Old.calls.append("detach")

    def set_visible(self, renderer, visible):
        Old.calls.append(f"visible {visible}")


class OldType:
    name = "oldlayer"
    label = "Old"
    extensions = (".old",)

    def __init__(self, context=None):
        self.context = context

    def open(self, path, **style):
        return Old(open(path).read().strip() == "broken")
"""


@pytest.mark.slow
def test_api_1_0_layer_objects_are_called_at_frame_time(
    globeview_gl, globeview_terrain, plugin_site, tmp_path
) -> None:
    from globeview.app.session import GlobeSession
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.render.offscreen import OffscreenTarget

    plugin_site.add("gvt_oldlayer", OLD_MANIFEST, {"impl": OLD_IMPL})
    good, broken = tmp_path / "good.old", tmp_path / "broken.old"
    good.write_text("fine")
    broken.write_text("broken")
    reg = PluginRegistry(MemorySettings()).discover()
    s = GlobeSession(globeview_gl, globeview_terrain, registry=reg)
    target = OffscreenTarget(globeview_gl, SIZE)
    try:
        layer = s.add_overlay(str(good))
        calls = type(layer.layer_object).calls
        layer.set_visible(False)
        assert calls == []  # opening and hiding called nothing (no GL, no context)
        s.render(target.fbo, SIZE)
        assert calls == ["attach", "visible False"]
        s.render(target.fbo, SIZE)
        assert calls == ["attach", "visible False"]  # told once per change
        s.remove_overlay(layer)
        assert calls[-1] == "visible False"
        s.render(target.fbo, SIZE)
        assert calls[-1] == "detach"
        # An object whose attach raises: dropped at the frame, one line, its type fails.
        s.add_overlay(str(broken))
        assert s.render(target.fbo, SIZE).stats.tiles_drawn > 0
        assert s.overlay_layers == [] and len(s.overlay_errors) == 1
        msg = s.overlay_errors[0]
        assert msg.startswith("cannot draw old style: could not attach: ") and "\n" not in msg
        assert "no GL for you" in msg and reg.failure_of("oldlayer") is not None
    finally:
        s.release_gl()
        target.release()


@pytest.mark.slow
def test_overlays_open_before_any_session_and_are_drawn_by_it(
    globeview_gl, globeview_terrain, globeview_registry
) -> None:
    """An `OverlayHost` opens files onto a globe that has no session, hence no renderer and
    no GL (a window opens them before its context exists); a session built on that globe
    with that host draws them at its first frame."""
    from globeview.app.overlay_host import OverlayHost
    from globeview.app.session import GlobeSession
    from globeview.model.globe import Globe
    from globeview.render.offscreen import OffscreenTarget

    globe = Globe(globeview_terrain, Camera.from_lonlat(10.0, 46.0, 3.0e6))
    host = OverlayHost(globe, globeview_registry)
    cities = host.open("data/ne_cities.geojson", "points")
    assert globe.overlays == [cities]
    other = Globe(globeview_terrain)
    with pytest.raises(ValueError, match="overlay_host"):
        GlobeSession(globeview_gl, globeview_terrain, globe=other, overlay_host=host)
    s = GlobeSession(globeview_gl, globeview_terrain, globe=globe, overlay_host=host)
    target = OffscreenTarget(globeview_gl, SIZE)
    try:
        assert s.overlay_host is host and s.overlay_layers == [cities]
        result = s.render(target.fbo, SIZE)
        assert result.stats.extra.get("objects", 0) > 0  # the cities are drawn
    finally:
        s.release_gl()
        target.release()
