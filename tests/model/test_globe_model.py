"""The app model without GL or Qt (issue #14): `Globe` and `DisplaySettings` hold the
state and emit one event per real change; bad values are refused where they are set."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from globeview.model import Camera, DisplaySettings, Globe
from globeview.terrain.compose.stack import TerrainStack


def _recorder(signal) -> list:
    got: list = []
    signal.connect(lambda *args: got.append(args))
    return got


@pytest.fixture
def globe() -> Globe:
    return Globe(TerrainStack())


def test_model_imports_neither_gl_nor_qt() -> None:
    code = (
        "import sys, globeview.model; "
        "bad = [m for m in ('moderngl', 'PyQt6') if m in sys.modules]; "
        "print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_lod_tool_tau_events_fire_once_per_real_change(globe: Globe) -> None:
    lod, tool, tau = (
        _recorder(s) for s in (globe.events.lod, globe.events.tool, globe.events.tau_px)
    )
    globe.lod = "quadtree-clod"
    globe.lod = "quadtree-clod"  # unchanged: no event
    globe.tool = "collapse"
    globe.tool = "collapse"
    globe.tool = None
    globe.tau_px = 4.0
    globe.tau_px = 4.0
    assert lod == [("quadtree-clod",)]
    assert tool == [("collapse",), (None,)]
    assert tau == [(4.0,)]
    assert (globe.lod, globe.tool, globe.tau_px) == ("quadtree-clod", None, 4.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, 1e9, "two"])
def test_tau_refused_where_set_and_nothing_changes(globe: Globe, bad) -> None:
    tau = _recorder(globe.events.tau_px)
    with pytest.raises((ValueError, TypeError)) as info:
        globe.tau_px = bad
    assert "\n" not in str(info.value) and "tau" in str(info.value)
    assert globe.tau_px == 2.0 and tau == []


def test_camera_events(globe: Globe) -> None:
    got = _recorder(globe.events.camera)
    cam = Camera.from_lonlat(10.0, 45.0, 5e5)
    globe.camera = cam
    globe.camera_moved()
    assert globe.camera is cam and got == [(cam,), (cam,)]


def test_overlays_list_and_events(globe: Globe) -> None:
    got = _recorder(globe.events.overlays)
    a, b = object(), object()
    globe.add_overlay(a)
    globe.add_overlay(b)
    assert globe.overlays == [a, b] and len(got) == 2
    globe.set_overlay_order([b, a])
    globe.set_overlay_order([b, a])  # unchanged: no event
    assert globe.overlays == [b, a] and len(got) == 3
    with pytest.raises(ValueError, match="not a reordering"):
        globe.set_overlay_order([a])
    with pytest.raises(ValueError, match="not a reordering"):
        globe.set_overlay_order([a, a])
    assert globe.overlays == [b, a] and len(got) == 3
    globe.remove_overlay(b)
    assert globe.overlays == [a] and len(got) == 4
    with pytest.raises(ValueError, match="is not shown"):  # not there: refused, no event
        globe.remove_overlay(b)
    assert len(got) == 4


def test_terrain_changes_reach_the_globe_once(globe: Globe) -> None:
    from globeview.terrain.compose.stack import TerrainLayer

    terrain = globe.terrain
    terrain.layers = [TerrainLayer(None, "a"), TerrainLayer(None, "b")]  # type: ignore[arg-type]
    got = _recorder(globe.events.terrain)
    terrain.set_visible("a", False)
    assert got == [()]
    terrain.set_visible("a", False)  # already hidden
    terrain.set_visible("none", False)  # no such layer
    terrain.remove("none")
    terrain.move("a", 0)  # already at the bottom
    assert got == [()]  # no real change: no event
    terrain.move("a", 1)
    terrain.remove("b")
    assert got == [(), (), ()] and [ly.name for ly in terrain.layers] == ["a"]


def test_terrain_does_not_keep_a_dropped_globe_alive() -> None:
    import gc
    import weakref

    terrain = TerrainStack()
    ref = weakref.ref(Globe(terrain))
    gc.collect()
    assert ref() is None
    assert len(terrain.changed) == 0  # psygnal dropped the dead globe's connection


def test_display_settings_events_once_per_change() -> None:
    display = DisplaySettings()
    globe = Globe(TerrainStack(), display=display)
    got = _recorder(display.events.wireframe)
    globe.display.wireframe = True
    globe.display.wireframe = True
    globe.display.wireframe = False
    assert [args[0] for args in got] == [True, False]  # psygnal passes (new, old)


def test_an_overlay_is_shown_once(globe: Globe) -> None:
    got = _recorder(globe.events.overlays)
    a = object()
    globe.add_overlay(a)
    with pytest.raises(ValueError, match="shown already"):
        globe.add_overlay(a)
    assert globe.overlays == [a] and len(got) == 1


def test_a_change_made_by_a_listener_reaches_everyone_after_the_first(globe: Globe) -> None:
    # E.g. the tool host turning an unavailable tool name back to None while the name's
    # event is delivered: every later listener sees both, in order, and the globe's state.
    def refuse(name) -> None:
        if name == "gone":
            globe.tool = None

    globe.events.tool.connect(refuse)
    seen = _recorder(globe.events.tool)
    globe.tool = "gone"
    assert [args[0] for args in seen] == ["gone", None] and globe.tool is None


@pytest.mark.parametrize("bad", [42, ["a"], b"collapse", 1.5])
def test_names_that_are_not_text_are_refused(globe: Globe, bad) -> None:
    seen = _recorder(globe.events.tool)
    with pytest.raises(TypeError, match="must be text"):
        globe.tool = bad
    with pytest.raises(TypeError, match="must be text"):
        globe.lod = bad
    assert (globe.tool, globe.lod, seen) == (None, "chunked-sse", [])


def _points(name: str = "cities"):
    import numpy as np

    from globeview.model.overlay_layers import PointsLayer

    return PointsLayer(name, np.array([10.0, 11.0]), np.array([46.0, 47.0]), ["a", "b"])


def test_a_layer_setter_emits_one_overlays_event_per_real_change(globe: Globe) -> None:
    # The setters announce themselves, so a plugin or script editing a layer reaches the
    # window without anyone calling overlays_changed().
    from globeview.model.overlay_layers import DrawnLayer

    layer = _points()
    globe.add_overlay(layer)
    got = _recorder(globe.events.overlays)
    assert layer.set_visible(False) is True
    assert layer.set_visible(False) is False  # no change: no event
    assert len(got) == 1 and layer.visible is False
    version = layer.style_version
    layer.set_style(size_px=14.0, color=(0, 1, 0))
    layer.set_style(size_px=14.0, color=(0, 1, 0, 1))  # the same style
    assert len(got) == 2 and layer.style_version == version + 1  # one GPU rebuild
    with pytest.raises(ValueError, match="size_px"):
        layer.set_style(size_px=math.nan)
    assert len(got) == 2 and layer.size_px == 14.0
    group = DrawnLayer("both", [_points("a"), _points("b")])
    globe.add_overlay(group)
    got.clear()
    group.set_visible(False)
    group.set_style(size_px=3.0)
    assert len(got) == 2  # one per change, not one per part
    globe.remove_overlay(layer)
    got.clear()
    layer.set_visible(True)  # off the globe: not the globe's event any more
    assert got == []


def test_a_layer_does_not_keep_a_dropped_globe_alive() -> None:
    import gc
    import weakref

    layer = _points()
    globe = Globe(TerrainStack())
    globe.add_overlay(layer)
    ref = weakref.ref(globe)
    del globe
    gc.collect()
    assert ref() is None
    layer.set_visible(False)  # its dead connection is dropped, nothing raises


def test_a_drape_opacity_change_is_one_event_and_nan_is_refused(globe: Globe) -> None:
    import numpy as np

    from globeview.model.drawables import RasterDrape
    from globeview.model.overlay_layers import drape_layer

    drape = drape_layer(RasterDrape(np.zeros((4, 8, 4), np.uint8), (0, 0, 10, 5)), "d")
    globe.add_overlay(drape)
    got = _recorder(globe.events.overlays)
    drape.set_opacity(0.5)
    drape.set_opacity(0.5)
    assert len(got) == 1
    with pytest.raises(ValueError, match="not a number"):
        drape.set_opacity(math.nan)
    assert drape.layer.opacity == 0.5 and len(got) == 1


@pytest.mark.parametrize("bad", [math.nan, math.inf, -1.0, 1e9, "x", None])
def test_a_bad_exaggeration_is_refused_where_it_is_set(bad) -> None:
    display = DisplaySettings()
    display.exaggeration = 3
    got = _recorder(display.events.exaggeration)
    with pytest.raises(ValueError, match="exaggeration") as info:
        display.exaggeration = bad
    assert "\n" not in str(info.value)
    assert display.exaggeration == 3.0 and got == []  # nothing changed, no event
    with pytest.raises(ValueError, match="exaggeration"):
        DisplaySettings(exaggeration=bad)
