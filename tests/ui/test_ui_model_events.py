"""The window is a thin shell over the `Globe` model (issue #14): its widgets subscribe to
the model's events, so a change made on the model from code (not through a widget) shows in
every widget without anyone calling a refresh, and nothing the model is given from code
brings the window down. Each test fails if the subscription it names is removed. A real
window under Xvfb."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PyQt6.QtCore import Qt

from globeview.model.camera import Camera
from globeview.model.globe import DEFAULT_LOD

pytestmark = pytest.mark.gui

DATA = Path(__file__).resolve().parents[2] / "data"


def test_tau_set_on_the_model_moves_the_slider(reused_window, wait_frame) -> None:
    win = reused_window
    panel = win.plugin_panel
    win.model.tau_px = 7.3  # PluginPanel subscribes to model.events.tau_px
    assert panel.tau_slider.value() == 73 and panel.tau_label.text() == "7.3 px"
    assert win.globe.scene.tau_px == pytest.approx(7.3)
    assert float(win.qsettings.value("view/tau")) == pytest.approx(7.3)  # the window's
    # Beyond the slider's range: the label says the model's value, the slider stops at its
    # end, and showing it there does not set the model back to the slider's value.
    win.model.tau_px = 500.0
    assert panel.tau_slider.value() == panel.tau_slider.maximum()
    assert panel.tau_label.text() == "500.0 px" and win.model.tau_px == 500.0
    wait_frame(win)
    assert win.globe.last_stats.triangles > 0
    # A bad tau is refused where it is set (one line) and nothing changes.
    for bad in (float("nan"), 0.0, -1.0, math.inf):
        with pytest.raises(ValueError, match="tau"):
            win.model.tau_px = bad
    assert win.model.tau_px == 500.0 and panel.tau_label.text() == "500.0 px"
    # The user's slider still drives the model.
    panel.tau_slider.setValue(45)
    assert win.model.tau_px == pytest.approx(4.5) and win.globe.scene.tau_px == pytest.approx(4.5)


def test_tool_set_on_the_model_checks_its_action(reused_window, wait_frame) -> None:
    win = reused_window
    act = win.tools.actions["measure"]
    assert not act.isChecked() and win.tools.options.tool_name is None
    win.model.tool = "measure"  # the window subscribes to model.events.tool
    assert act.isChecked() and win.tools.options.tool_name == "measure"
    wait_frame(win)
    assert win.model.tool == "measure" and win.tools.active_tool_name() == "measure"
    # The session's own switch (no window call) shows too.
    win.globe.scene.activate_tool("collapse")
    assert win.tools.actions["collapse"].isChecked() and not act.isChecked()
    assert win.tools.options.tool_name == "collapse"
    win.model.tool = None
    assert not any(a.isChecked() for a in win.tools.actions.values())
    assert win.tools.options.tool_name is None
    wait_frame(win)
    assert win.globe.scene.renderer.displacement_hook is None
    # A tool no plugin provides, set from code: no action is checked, the globe keeps drawing.
    win.model.tool = "no-such-tool"
    wait_frame(win)
    assert not any(a.isChecked() for a in win.tools.actions.values())
    assert win.globe.last_stats.triangles > 0


def test_overlays_changed_on_the_model_are_listed(reused_window, wait_frame) -> None:
    win = reused_window
    panel = win.layer_panel.overlays
    assert panel.names() == []
    layers = win.globe.scene.add_embedded_overlays(imagery=True)  # models: no GL context
    # Added through the session, not the window: the model's event lists them.
    assert len(layers) == 2
    assert panel.names() == [ly.name for ly in reversed(layers)]
    win.model.set_overlay_order(list(reversed(layers)))
    assert panel.names() == [ly.name for ly in layers]
    win.globe.scene.remove_overlay(layers[0])
    assert panel.names() == [layers[1].name]
    assert win.overlay_layers() == [layers[1]]
    wait_frame(win)
    assert win.globe.last_stats.triangles > 0


def test_overlay_setters_called_from_code_show_in_the_panel(reused_window, wait_frame) -> None:
    """A script or plugin calling a layer's setters: the layer announces the change (the
    Globe's overlays event), so the panel follows without anyone announcing by hand; an edit
    in the panel is one event."""
    win = reused_window
    win.files.open_embedded_overlays()  # as embedded_overlays=True opens them
    panel = win.layer_panel.overlays
    borders, marble = panel.layer_at(0), panel.layer_at(1)
    assert panel.list.item(1).checkState() == Qt.CheckState.Unchecked
    marble.set_visible(True)
    assert panel.list.item(1).checkState() == Qt.CheckState.Checked
    panel.select(borders)
    borders.set_style(width_px=7.0)
    assert panel.width_spin.value() == 7.0
    panel.select(marble)
    marble.set_opacity(0.25)
    assert panel.opacity_slider.value() == 25 and panel.opacity_value.text() == "25 %"
    events = []
    win.model.events.overlays.connect(lambda *_a: events.append(1))
    panel.set_visible(marble, False)  # as a click on the checkbox
    assert events == [1] and not marble.visible
    panel.set_width(borders, 7.0)  # no change: no event
    assert events == [1]
    wait_frame(win)
    assert win.globe.last_stats.triangles > 0


def test_changing_the_model_from_the_window_makes_no_context_current(
    reused_window, wait_frame, monkeypatch
) -> None:
    """Tools, overlays (open, hide, restyle, reorder, remove), tau, LOD and display settings
    change the model only; GPU objects follow at the next frame, which Qt draws with its
    own context current."""
    win = reused_window
    win.files.open_embedded_overlays()  # as embedded_overlays=True opens them
    calls = []
    real = win.globe.makeCurrent
    monkeypatch.setattr(win.globe, "makeCurrent", lambda: (calls.append(1), real())[1])
    panel = win.layer_panel.overlays
    assert (
        win.tools.set_tool("collapse")
        and win.tools.set_tool("measure")
        and win.tools.set_tool(None)
    )
    borders, marble = panel.layer_at(0), panel.layer_at(1)
    (cities,) = win.files.open_overlays([str(DATA / "ne_cities.geojson")])
    panel.set_visible(marble, True)
    panel.set_opacity(marble, 0.5)
    panel.set_width(borders, 4.0)
    panel.select(borders)
    panel.move_selected(+1)
    assert panel.names() == [cities.name, marble.name, borders.name]
    panel.remove(borders)
    win.plugin_panel.tau_slider.setValue(40)
    win.plugins.choose("wavelet")
    win.view_bar.exag_slider.setValue(25)
    win.view_bar.wire_check.setChecked(True)
    assert calls == []
    wait_frame(win)
    assert win.globe.last_stats.lod_provider == "wavelet"
    assert win.globe.scene.renderer.overlays.vectors == []  # the removed one's twin is freed
    assert len(win.globe.scene.renderer.overlays.points) == 1  # the opened one's is made
    assert win.globe.last_stats.triangles > 0


def test_overlays_open_before_the_window_has_gl(qtbot, tmp_path, embedded, monkeypatch) -> None:
    """A window not shown yet has no GL context and no session: overlays open anyway (the
    window's `OverlayHost` makes models, nothing waits for GL), are listed at once and are
    drawn by the first frame."""
    from PyQt6.QtCore import QSettings

    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.ui.app import embedded_stack
    from globeview.ui.main_window import MainWindow

    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    settings = QSettings(str(tmp_path / "globeview.ini"), QSettings.Format.IniFormat)
    registry = PluginRegistry(MemorySettings()).discover()
    shown: list = []
    win = MainWindow(embedded_stack(embedded), settings, registry, show_error=shown.append)
    qtbot.addWidget(win)
    try:
        assert win.globe.scene is None and win.globe.context() is None
        (cities,) = win.files.open_overlays([str(DATA / "ne_cities.geojson")])
        assert win.overlay_layers() == [cities] and win.layer_panel.overlays.names() == [
            cities.name
        ]
        assert win.globe.scene is None and not shown
        win.resize(800, 600)
        win.show()
        qtbot.waitExposed(win)
        qtbot.waitUntil(lambda: win.globe.frames > 0, timeout=20000)
        assert win.globe.scene.overlay_layers == [cities]
        qtbot.waitUntil(lambda: len(win.globe.scene.renderer.overlays.points) == 1)
    finally:
        win.files.loader.shutdown()


def test_terrain_changed_on_the_model_is_listed(make_window, wait_frame) -> None:
    win = make_window()
    panel = win.layer_panel
    names = panel.names()
    assert names, "the embedded stack has layers"
    top = names[0]
    assert panel.list.item(0).checkState() == Qt.CheckState.Checked
    win.terrain.set_visible(top, False)  # LayerPanel subscribes to model.events.terrain
    assert panel.list.item(0).checkState() == Qt.CheckState.Unchecked
    layer = next(ly for ly in win.terrain.layers if ly.name == top)
    win.terrain.remove(top)
    assert top not in panel.names()
    win.terrain.add(layer.store, "again")
    assert panel.names()[0] == "again"
    wait_frame(win)
    assert win.globe.last_stats.triangles > 0


def test_lod_set_on_the_model_shows_in_panel_and_status(make_window, wait_frame) -> None:
    win = make_window()
    panel = win.plugin_panel
    win.model.lod = "distance-regions"  # PluginHost subscribes to model.events.lod
    assert panel.lod_combo.currentData() == "distance-regions"
    assert win.status.lod.text() == "LOD distance-regions"
    assert win.globe.scene.lod_name == "distance-regions"
    wait_frame(win)
    assert win.globe.last_stats.lod_provider == "distance-regions"
    # A name no plugin provides, chosen in the window: one notice, nothing changes.
    events, shown = [], []
    win.model.events.lod.connect(events.append)
    win.plugins.lodChanged.connect(shown.append)
    win.plugins.choose("no-such-lod")
    assert events == [] and shown == [] and win.model.lod == "distance-regions"
    assert panel.lod_combo.currentData() == "distance-regions"
    assert [m.text for m in win.errors.history if "no-such-lod" in m.text] == [
        m.text for m in win.errors.history[-1:]
    ]
    # Set on the model from code: the frame falls back to the built-in provider, once, and
    # the notice names the name it left.
    win.model.lod = "no-such-lod"
    wait_frame(win)
    assert events == ["no-such-lod", DEFAULT_LOD]
    assert win.model.lod == DEFAULT_LOD and panel.lod_combo.currentData() == DEFAULT_LOD
    assert (
        win.errors.history[-1].text
        == f"LOD provider no-such-lod is not available; using {DEFAULT_LOD}"
    )
    assert all("\n" not in m.text for m in win.errors.history)
    assert win.globe.last_stats.triangles > 0


def test_display_settings_set_on_the_model_move_the_controls(make_window, wait_frame) -> None:
    win = make_window()
    display = win.model.display
    display.exaggeration = 3.0  # the window subscribes to display.events
    assert win.view_bar.exag_slider.value() == 30 and win.view_bar.exag_label.text() == "3.0×"
    display.wireframe = True
    display.hillshade = True
    assert win.view_bar.wire_check.isChecked() and win.view_bar.hill_check.isChecked()
    # Beyond the slider: the label is exact and the model keeps its value.
    display.exaggeration = 80.0
    assert win.view_bar.exag_slider.value() == win.view_bar.exag_slider.maximum()
    assert win.view_bar.exag_label.text() == "80.0×" and display.exaggeration == 80.0
    # A NaN exaggeration from code is refused where it is set: nothing changes, no event,
    # the controls keep showing the model.
    with pytest.raises(ValueError, match="exaggeration"):
        display.exaggeration = float("nan")
    assert display.exaggeration == 80.0 and win.view_bar.exag_label.text() == "80.0×"
    win.view_bar.exag_slider.setValue(20)  # the user's slider drives the model again
    assert display.exaggeration == pytest.approx(2.0)
    wait_frame(win)
    assert win.globe.last_stats.triangles > 0


def test_camera_replaced_on_the_model_is_drawn_and_flown(make_window, qtbot, wait_frame) -> None:
    win = make_window()
    cam = Camera.from_lonlat(-122.0, 46.0, 3.0e5)
    win.model.camera = cam  # the status bar and the widget subscribe to model.events.camera
    assert win.status.altitude.text() == "alt 300.0 km"
    assert win.globe.camera is cam and win.globe.scene.camera is cam
    wait_frame(win)
    assert np.allclose(win.globe.scene.last.view.eye, cam.eye)  # drawn from the new camera
    # A flight moves the model's camera of now, not the one it was built with.
    assert win.view_bar.go_to("-121, 46, 200000")
    qtbot.waitUntil(lambda: not win.globe.flight.active, timeout=5000)
    assert cam.height == pytest.approx(2.0e5, rel=1e-3)
    assert win.status.altitude.text() == "alt 200.0 km"


def test_closed_window_leaves_the_model(make_window) -> None:
    win = make_window()
    model = win.model
    events = model.events
    signals = {
        "camera": events.camera,
        "lod": events.lod,
        "tau_px": events.tau_px,
        "terrain": events.terrain,
        "overlays": events.overlays,
        "tool": events.tool,
        **{f"display.{name}": getattr(model.display.events, name) for name in model.display.events},
    }
    assert all(len(sig) > 0 for name, sig in signals.items() if not name.startswith("display."))
    assert sum(len(sig) for name, sig in signals.items() if name.startswith("display.")) > 0
    win.close()
    # The window's listeners, and the released session's tool host, are all gone.
    assert {name: len(sig) for name, sig in signals.items() if len(sig)} == {}
    # The model outlives the window: changing it calls no closed widget.
    model.tau_px = 3.0
    model.display.exaggeration = 2.0
    model.camera_moved()
    model.lod = "wavelet"
    model.overlays_changed()
    model.terrain.set_visible(model.terrain.layers[0].name, False)


def test_an_overlay_the_gpu_refuses_at_a_frame_is_reported_in_one_line(
    make_window, qtbot, errors_shown, wait_frame
) -> None:
    win = make_window()
    (cities,) = win.files.open_overlays([str(DATA / "ne_cities.geojson")])
    wait_frame(win)
    assert errors_shown == []
    # Code writing the model's fields past set_style's check: the GPU side refuses the
    # style, and the frame drops the layer (one line).
    assert cities.kind == "points"
    with pytest.raises(ValueError, match="style"):
        cities.set_style(object_kind="bogus")
    cities.object_kind = "bogus"
    cities.style_version += 1
    win.model.overlays_changed()
    qtbot.waitUntil(lambda: bool(errors_shown), timeout=10000)
    text = errors_shown[-1].text
    assert "\n" not in text and "cannot draw" in text and cities.name in text
    assert win.overlay_layers() == [] and win.layer_panel.overlays.names() == []
    wait_frame(win)
    assert win.globe.last_stats.triangles > 0 and len(errors_shown) == 1


@pytest.mark.parametrize("bad", ["nan", "inf", "-3", "1e9", "abc", ""])
def test_hostile_saved_view_settings_open_with_the_defaults(make_window, tmp_path, bad) -> None:
    """A hand-edited settings file: a tau or exaggeration that is no number, or one outside
    what the controls show, opens the window with the defaults (a NaN exaggeration used to
    stop the window from opening)."""
    from PyQt6.QtCore import QSettings

    path = tmp_path / "hostile.ini"
    s = QSettings(str(path), QSettings.Format.IniFormat)
    s.setValue("view/tau", bad)
    s.setValue("view/exaggeration", bad)
    s.sync()
    win = make_window(settings_path=path)
    assert win.model.tau_px == 2.0 and win.plugin_panel.tau_label.text() == "2.0 px"
    assert win.model.display.exaggeration == 1.0 and win.view_bar.exag_label.text() == "1.0×"
    assert win.globe.last_stats.triangles > 0


def test_the_window_draws_with_the_pipelines_camera_speed(make_window, qtbot) -> None:
    """paintGL derives no speed: the frame pipeline does, from the model's camera history.
    During a flight the frames see a speed; once still, one more frame sees none."""
    win = make_window()
    g = win.globe
    assert g.scene.last.view.speed_mps == 0.0
    seen = []
    g.frameRendered.connect(lambda *_: seen.append(g.scene.last.view.speed_mps))
    assert win.view_bar.go_to("10, 45, 3000000")
    qtbot.waitUntil(lambda: any(v > 1000.0 for v in seen), timeout=10000)
    qtbot.waitUntil(lambda: not g.flight.active, timeout=10000)
    # The settle frame after the flight (the camera still) sees no speed.
    qtbot.waitUntil(lambda: seen[-1] == 0.0, timeout=10000)


BAD_GLSL_TOOL = """
name = "bad-glsl"
version = "0.1.0"
description = "A tool whose displacement hook does not compile."
kinds = ["tool"]
api_version = "1.0"

[[contributions]]
name = "bad-glsl"
kind = "tool"
target = "bad_glsl.tool:BadGlsl"
"""

BAD_GLSL_MODULE = """
from globeview.plugins.api import Tool


class BadGlsl(Tool):
    label = "Bad GLSL"

    def displacement_glsl(self):
        return "vec3 gv_displace(vec3 p) { return this is not GLSL; }"
"""


def test_a_tool_whose_hook_fails_at_the_next_frame_is_reported(
    plugin_site, make_window, wait_frame
) -> None:
    """Activation only sets the model; the hook compiles in the next frame. When it does not
    compile, the model's tool becomes None (an event) and the window names the tool's own
    failure in one line, unchecks it, and keeps drawing."""
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    plugin_site.add("bad_glsl", BAD_GLSL_TOOL, {"tool": BAD_GLSL_MODULE})
    win = make_window(registry=PluginRegistry(MemorySettings()).discover())
    assert win.tools.set_tool("bad-glsl")  # accepted: nothing compiled yet
    assert win.tools.actions["bad-glsl"].isChecked()
    wait_frame(win)
    assert win.model.tool is None and win.tools.options.tool_name is None
    assert "bad-glsl" not in win.tools.actions or not win.tools.actions["bad-glsl"].isChecked()
    texts = [m.text for m in win.errors.history]
    mine = [t for t in texts if "bad-glsl" in t]  # once: not again as a plugin failure
    assert len(mine) == 1 and "\n" not in mine[0], texts
    assert mine[0].startswith("tool bad-glsl could not be activated: "), texts
    wait_frame(win)
    assert win.globe.last_stats.triangles > 0
    assert win.tools.set_tool("measure")  # other tools still work


UNLOADABLE_LOD_MANIFEST = """
name = "unloadable-lod"
version = "0.1.0"
description = "An LOD provider whose module does not import."
kinds = ["lod"]
api_version = "1.0"

[[contributions]]
name = "unloadable-lod"
kind = "lod"
target = "unloadable_lod.provider:Provider"
"""


def test_choosing_a_provider_whose_plugin_does_not_load_keeps_the_model(
    plugin_site, make_window, wait_frame
) -> None:
    """The name is checked before the model changes: the model never takes a provider that
    cannot load (no lod event for it), the notice says why in one line, frames keep coming."""
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    plugin_site.add(
        "unloadable_lod", UNLOADABLE_LOD_MANIFEST, {"provider": "raise ImportError('no numpy 9')"}
    )
    win = make_window(registry=PluginRegistry(MemorySettings()).discover())
    events, shown = [], []
    win.model.events.lod.connect(events.append)
    win.plugins.lodChanged.connect(shown.append)
    win.plugins.choose("unloadable-lod")
    assert events == [] and shown == [] and win.model.lod == DEFAULT_LOD
    last = win.errors.history[-1].text
    assert last.startswith("LOD provider unloadable-lod failed: ") and "no numpy 9" in last
    assert last.endswith(f"; using {DEFAULT_LOD}") and "\n" not in last
    assert win.plugin_panel.lod_combo.currentData() == DEFAULT_LOD
    wait_frame(win)
    assert win.globe.last_stats.triangles > 0
