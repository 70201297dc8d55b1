"""The app model without GL or Qt (issue #14): `Globe` and `DisplaySettings` hold the
state and emit one event per real change; bad values are refused where they are set."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from globeview.model import Camera, DisplaySettings, Globe
from globeview.terrain.stack import TerrainStack


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
    with pytest.raises(ValueError):
        globe.set_overlay_order([a])  # not a reordering
    with pytest.raises(ValueError):
        globe.set_overlay_order([a, a])
    assert globe.overlays == [b, a] and len(got) == 3
    globe.remove_overlay(b)
    assert globe.overlays == [a] and len(got) == 4
    with pytest.raises(ValueError):
        globe.remove_overlay(b)  # not there: refused, no event
    assert len(got) == 4


def test_terrain_changes_reach_the_globe_once(globe: Globe) -> None:
    got = _recorder(globe.events.terrain)
    globe.terrain.set_visible("none", False)
    assert got == [()]


def test_terrain_does_not_keep_a_dropped_globe_alive() -> None:
    import gc
    import weakref

    terrain = TerrainStack()
    ref = weakref.ref(Globe(terrain))
    gc.collect()
    assert ref() is None
    terrain.set_visible("none", True)  # the dead globe's listener drops itself
    assert terrain.listeners == []


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
