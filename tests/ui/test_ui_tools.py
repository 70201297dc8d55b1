"""Interactive tools in the window, with the terrain-collapse tool: the Tools toolbar, clicks
and keys forwarded to the tool, the animation timer, overlays and the status bar. A real
window under a display, the real renderer and the built-in collapse plugin; no mocks."""

from __future__ import annotations

import re

import numpy as np
import pytest
from PyQt6.QtCore import QPoint, Qt

from globeview.geodesy import lonlat_to_ecef
from globeview.model.camera import Camera

pytestmark = pytest.mark.gui

#: The Pacific Northwest from 900 km: Crater Lake (A) and the Salish Sea (B) both in view.
VIEW = (-122.3, 45.5, 9.0e5)
A = (-122.1, 42.94)
B = (-122.5, 48.0)
MARKER_RGB = np.array([255, 77, 26])  # the collapse tool's marker colour (1.0, 0.3, 0.1)


def make_pnw(make_window):
    return make_window(camera=Camera.from_lonlat(*VIEW))


def to_widget(win, points_ecef: np.ndarray) -> list[QPoint]:
    """Widget (logical) positions of ECEF points in the last frame."""
    g = win.globe
    px = g.scene.last.view.project(np.asarray(points_ecef, np.float64).reshape(-1, 3))
    r = g.devicePixelRatio()
    return [QPoint(round(x / r), round(y / r)) for x, y, _ in px]


def ground(lon: float, lat: float) -> np.ndarray:
    return np.asarray(lonlat_to_ecef(lon, lat, 0.0), np.float64).reshape(1, 3)


def marker_pixels(rgb: np.ndarray, x: float, y: float, radius: int = 9) -> int:
    """Marker-coloured pixels within ``radius`` of (x, y) (framebuffer pixels)."""
    h, w, _ = rgb.shape
    x0, x1 = max(int(x) - radius, 0), min(int(x) + radius + 1, w)
    y0, y1 = max(int(y) - radius, 0), min(int(y) + radius + 1, h)
    patch = rgb[y0:y1, x0:x1].astype(int)
    return int((np.abs(patch - MARKER_RGB).max(axis=2) < 40).sum())


def test_toolbar_action_activates_collapse_and_drag_still_navigates(make_window, qtbot, wait_frame):
    win = make_pnw(make_window)
    g = win.globe
    act = win.tools.actions["collapse"]
    assert act.isCheckable()
    # C is the collapse manifest's command: it activates the tool from anywhere.
    assert win.tools.command_actions["collapse.collapse"].shortcut().toString() == "C"
    assert "C: Collapse" in act.toolTip()
    assert act in win.tools.toolbar.actions() and act in win.tools.menu.actions()
    assert "marker" in win.tools.actions  # the example plugin's tool is listed too
    # The toolbar button activates the tool in the session, a second click leaves it.
    button = win.tools.toolbar.widgetForAction(act)
    qtbot.mouseClick(button, Qt.MouseButton.LeftButton)
    assert act.isChecked() and g.scene.active_tool == "collapse"
    wait_frame(win)  # activation sets the model; the frame compiles the displacement hook
    assert g.scene.renderer.displacement_hook is not None
    qtbot.mouseClick(button, Qt.MouseButton.LeftButton)
    assert not act.isChecked() and g.scene.active_tool is None
    wait_frame(win)
    assert g.scene.renderer.displacement_hook is None
    # The shortcut C (a window shortcut: the window must be the active one).
    win.activateWindow()
    qtbot.waitUntil(win.isActiveWindow, timeout=5000)
    qtbot.keyClick(g, Qt.Key.Key_C)
    assert act.isChecked() and g.scene.active_tool == "collapse"
    # A left drag with the tool active moves the camera and sets no point.
    eye0 = g.camera.eye.copy()
    start = QPoint(g.width() // 2, g.height() // 2)
    qtbot.mousePress(g, Qt.MouseButton.LeftButton, pos=start)
    for k in range(1, 5):
        qtbot.mouseMove(g, start + QPoint(20 * k, 10 * k))
    qtbot.mouseRelease(g, Qt.MouseButton.LeftButton, pos=start + QPoint(80, 40))
    assert np.linalg.norm(g.camera.eye - eye0) > 1000.0
    assert g.active_tool().state == "idle"
    # Disabling its plugin while active leaves the tool and removes the action.
    win.plugins.set_enabled("collapse", False)
    assert "collapse" not in win.tools.actions and win.tools.options.tool_name is None
    assert not any(k.startswith("collapse.") for k in win.tools.command_actions)
    assert g.scene.active_tool is None
    wait_frame(win)
    assert g.overlay_drawn == 0 and g.scene.renderer.displacement_hook is None
    win.plugins.set_enabled("collapse", True)
    assert "collapse" in win.tools.actions


def test_clicks_collapse_animate_overlay_and_escape(make_window, qtbot, frame_rgb, wait_frame):
    win = make_pnw(make_window)
    g = win.globe
    before = frame_rgb(win)
    pa, pb = to_widget(win, np.concatenate([ground(*A), ground(*B)]))
    r = g.devicePixelRatio()
    assert marker_pixels(before, pa.x() * r, pa.y() * r) < 5
    win.tools.actions["collapse"].trigger()
    tool = g.active_tool()
    qtbot.mouseClick(g, Qt.MouseButton.LeftButton, pos=pa)
    assert tool.state == "a_set"
    assert abs(tool.a[0] - A[0]) < 0.1 and abs(tool.a[1] - A[1]) < 0.1  # true coordinates
    qtbot.mouseClick(g, Qt.MouseButton.LeftButton, pos=pb)
    assert tool.b is not None and abs(tool.b[1] - B[1]) < 0.1
    # The animation runs on its timer and stops by itself, fully collapsed.
    qtbot.waitUntil(lambda: g.animating, timeout=5000)
    qtbot.waitUntil(lambda: not g.animating, timeout=10000)
    assert tool.state == "collapsed" and tool.progress == 1.0
    wait_frame(win)
    after = frame_rgb(win)
    changed = np.abs(after.astype(int) - before.astype(int)).sum(axis=2) > 30
    assert changed.mean() > 0.1, "the collapse should change the image"
    # Markers at A and B, where the collapsed terrain draws them; fold lines drawn too.
    assert g.overlay_drawn > 2
    shown = tool.displacement_numpy(ground(*A))
    (qa,) = to_widget(win, shown)
    assert marker_pixels(after, qa.x() * r, qa.y() * r) > 15
    # Escape cancels the collapse and leaves the tool.
    qtbot.keyClick(g, Qt.Key.Key_Escape)
    assert tool.state == "idle" and g.scene.active_tool is None
    assert not win.tools.actions["collapse"].isChecked()
    wait_frame(win)
    again = frame_rgb(win)
    assert (np.abs(again.astype(int) - before.astype(int)).sum(axis=2) > 30).mean() < 0.02


def test_ratio_slider_and_expand_button(make_window, qtbot):
    """The Ratio control and the Expand / Collapse buttons are built from the tool's Setting
    and its manifest commands (the window holds no collapse code)."""
    win = make_pnw(make_window)
    g = win.globe
    win.tools.actions["collapse"].trigger()
    tool = g.active_tool()
    bar = win.tools.options
    assert bar.tool_name == "collapse" and set(bar.editors) == {"ratio", "animate"}
    ratio = bar.editors["ratio"]
    ratio.slider.setValue(ratio.slider.maximum() // 2)  # as a drag would
    assert tool.ratio == pytest.approx(0.505, abs=1e-3)
    ratio.spin.setValue(0.5)  # an exact value typed in the box
    assert tool.ratio == pytest.approx(0.5) and tool.values["ratio"] == pytest.approx(0.5)
    stored = win.plugins.registry.settings.get("plugins/collapse/contributions/collapse")
    assert stored["ratio"] == pytest.approx(0.5)  # persisted as provider settings are
    tool.set_points(*A, *B)  # the tool's documented API
    assert tool.frame().ratio == pytest.approx(0.5)
    expand = bar.widgetForAction(win.tools.command_actions["collapse.expand"])
    collapse = bar.widgetForAction(win.tools.command_actions["collapse.collapse"])
    qtbot.waitUntil(lambda: expand.isVisible() and collapse.isVisible(), timeout=5000)
    qtbot.mouseClick(expand, Qt.MouseButton.LeftButton)
    assert tool.state == "expanding"
    qtbot.waitUntil(lambda: tool.state == "expanded" and not g.animating, timeout=10000)
    # 'c' collapses again (the tool's key, not the window's tool shortcut).
    qtbot.keyClick(g, Qt.Key.Key_C)
    qtbot.waitUntil(lambda: tool.state == "collapsed", timeout=10000)
    assert g.scene.active_tool == "collapse"


def _status_lonlat(text: str) -> tuple[float, float]:
    m = re.match(r"\s*([\d.]+)°([NS]) ([\d.]+)°([EW])", text)
    assert m, text
    lat = float(m.group(1)) * (1 if m.group(2) == "N" else -1)
    lon = float(m.group(3)) * (1 if m.group(4) == "E" else -1)
    return lon, lat


def test_status_bar_shows_true_lonlat_with_collapse(make_window, qtbot, wait_frame):
    win = make_pnw(make_window)
    g = win.globe
    win.tools.actions["collapse"].trigger()
    tool = g.active_tool()
    tool.set_points(*A, *B, ratio=0.2)
    wait_frame(win)
    true = (-122.2, 48.6)  # beyond B: drawn about 225 km south of where it is
    drawn = tool.displacement_numpy(ground(*true))
    (p,) = to_widget(win, drawn)
    assert 0 < p.x() < g.width() and 0 < p.y() < g.height()
    qtbot.mouseMove(g, p)
    qtbot.waitUntil(lambda: win.status.cursor.text() != "—", timeout=5000)
    lon, lat = _status_lonlat(win.status.cursor.text())
    assert abs(lon - true[0]) < 0.05 and abs(lat - true[1]) < 0.05
