"""The measure tool in the real window (issue #15): two clicks on the White Mountains measure,
the status bar says the distance, the Plot dock shows the terrain profile (drawn with
QPainter) and exports it as CSV; a failed export is one line in a dialog and writes nothing.
A real window under a display, the real renderer and picking, the built-in plugin."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from PyQt6.QtCore import QPoint, Qt

from globeview.geodesy import lonlat_to_ecef
from globeview.model.camera import Camera
from globeview.plugins.api import Plot, sample_terrain
from globeview.ui.plot_dock import CURVE_RGB

pytestmark = pytest.mark.gui

#: Over the Presidential Range from 60 km, looking down.
VIEW = (-71.34, 44.27, 6.0e4)
A = (-71.45, 44.23)
B = (-71.22, 44.31)


def to_widget(win, lon: float, lat: float) -> QPoint:
    """Widget (logical) position of the terrain at (lon, lat) in the last frame."""
    g = win.globe
    h = float(sample_terrain(win.terrain, lon, lat).ellipsoidal)
    p = np.asarray(lonlat_to_ecef(lon, lat, h), np.float64).reshape(1, 3)
    x, y, _ = g.scene.last.view.project(p)[0]
    r = g.devicePixelRatio()
    return QPoint(round(x / r), round(y / r))


def curve_pixels(dock) -> int:
    """Pixels of the curve's colour in the Plot dock's drawing."""
    img = dock.view.grab().toImage()
    ptr = img.constBits()
    ptr.setsize(img.sizeInBytes())
    arr = np.frombuffer(ptr, np.uint8).reshape(img.height(), img.bytesPerLine())
    bgra = arr[:, : img.width() * 4].reshape(img.height(), img.width(), 4)
    rgb = bgra[..., [2, 1, 0]].astype(int)
    return int((np.abs(rgb - np.array(CURVE_RGB)).max(axis=2) < 40).sum())


def measured_window(reused_window_at, qtbot, wait_frame):
    win = reused_window_at(Camera.from_lonlat(*VIEW))
    g = win.globe
    assert not win.plot_dock.isVisible() and win.plot_dock.plot is None
    win.tools.actions["measure"].trigger()
    assert g.scene.active_tool == "measure"
    for lon, lat in (A, B):
        qtbot.mouseClick(g, Qt.MouseButton.LeftButton, pos=to_widget(win, lon, lat))
        wait_frame(win)
    qtbot.waitUntil(win.plot_dock.isVisible, timeout=5000)
    return win


def test_two_clicks_show_the_profile_and_export_it(
    reused_window_at, qtbot, wait_frame, tmp_path: Path, errors_shown
) -> None:
    win = measured_window(reused_window_at, qtbot, wait_frame)
    tool = win.globe.active_tool()
    m = tool.measurement
    # The picks landed where clicked (a pixel at 60 km is tens of metres).
    assert np.allclose(m.a, A, atol=2e-3) and np.allclose(m.b, B, atol=2e-3)
    assert 15e3 < m.distance_m < 25e3
    assert "measure:" in win.status.currentMessage() and "geodesic" in win.status.currentMessage()
    # The dock shows the tool's plot, drawn: the curve's colour is on screen.
    plot = win.plot_dock.plot
    assert isinstance(plot, Plot) and plot is tool.plot()
    assert win.plot_dock.title.text() == plot.title
    assert curve_pixels(win.plot_dock) > 100
    # The profile is the window's terrain, orthometric (what `globeview height` prints).
    want = sample_terrain(win.terrain, m.profile_lon, m.profile_lat).orthometric
    np.testing.assert_allclose(m.profile_h_m, want, atol=1e-6)
    assert m.profile_h_m.max() > 1000.0
    # Export writes the table.
    out = tmp_path / "profile.csv"
    assert win.plot_dock.export_button.isEnabled()
    assert win.plot_dock.export_csv(str(out))
    with out.open(newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["distance_m", "lon", "lat", "height_m"] and len(rows) == 257
    assert np.array_equal(np.array(rows[1:], np.float64)[:, 3], m.profile_h_m)
    assert win.status.currentMessage() == f"wrote {out}"
    assert errors_shown == []
    # A frame with nothing new keeps the same plot; leaving the tool hides the dock.
    wait_frame(win)
    assert win.plot_dock.plot is plot
    win.tools.set_tool(None)
    wait_frame(win)
    assert not win.plot_dock.isVisible() and win.plot_dock.plot is None


def test_export_button_asks_for_a_file_and_writes_it(
    reused_window_at, qtbot, wait_frame, tmp_path: Path, errors_shown
) -> None:
    """The real path: the dock's button, Qt's save dialog (answered like a user), the file."""
    from PyQt6.QtCore import QTimer
    from PyQt6.QtWidgets import QApplication, QDialogButtonBox, QFileDialog, QLineEdit

    win = measured_window(reused_window_at, qtbot, wait_frame)
    target = tmp_path / "via-dialog.csv"
    seen: list[str] = []

    def answer() -> None:
        dlg = QApplication.activeModalWidget()
        if not isinstance(dlg, QFileDialog):
            QTimer.singleShot(50, answer)
            return
        seen.append(dlg.windowTitle())
        # As a user: type the path, press Save (accept() is not callable from Python here).
        dlg.findChild(QLineEdit, "fileNameEdit").setText(str(target))
        dlg.findChild(QDialogButtonBox).button(QDialogButtonBox.StandardButton.Save).click()

    QTimer.singleShot(50, answer)
    qtbot.mouseClick(win.plot_dock.export_button, Qt.MouseButton.LeftButton)
    assert seen == ["Export plot as CSV"]
    header = target.read_text().splitlines()[0]
    assert header == "distance_m,lon,lat,height_m" and errors_shown == []


def test_settings_in_the_tool_options_bar_redraw_the_plot(
    reused_window_at, qtbot, wait_frame
) -> None:
    """The measure tool's Settings become controls (the window's generic path); editing
    them changes the published plot, which the dock then shows."""
    win = measured_window(reused_window_at, qtbot, wait_frame)
    editors = win.tools.options.editors
    assert set(editors) == {"samples", "units", "show_chord"}
    first = win.plot_dock.plot
    editors["units"].setValue("mi")
    wait_frame(win)
    qtbot.waitUntil(lambda: win.plot_dock.plot is not first, timeout=5000)
    assert win.plot_dock.plot.x_label == "distance from A (mi)"
    assert " mi geodesic" in win.status.currentMessage()
    editors["samples"].setValue(32)
    wait_frame(win)
    qtbot.waitUntil(lambda: win.plot_dock.plot.x.size == 32, timeout=5000)
    assert win.globe.active_tool().values["samples"] == 32


def test_failed_export_is_a_one_line_dialog_and_writes_nothing(
    reused_window_at, qtbot, wait_frame, tmp_path: Path, errors_shown, monkeypatch
) -> None:
    win = measured_window(reused_window_at, qtbot, wait_frame)
    folder = tmp_path / "out"
    folder.mkdir()
    target = folder / "profile.csv"
    target.write_text("keep me\n")
    # A read-only file system (injected: the tests run as root, where chmod does not refuse).
    monkeypatch.setenv("GLOBEVIEW_FAULT_WRITE", "erofs")
    assert not win.plot_dock.export_csv(str(target))
    monkeypatch.delenv("GLOBEVIEW_FAULT_WRITE")
    # A folder where the file should be (a real failure).
    assert not win.plot_dock.export_csv(str(folder))
    texts = [m.text for m in errors_shown]
    assert len(texts) == 2 and all("\n" not in t for t in texts)
    assert "read-only" in texts[0] and str(target) in texts[0]
    assert "directory" in texts[1]
    assert target.read_text() == "keep me\n"
    assert sorted(p.name for p in folder.iterdir()) == ["profile.csv"]  # no temporaries
    assert win.plot_dock.isVisible()  # the window carries on


def test_a_tool_returning_garbage_for_its_plot_is_failed_not_fatal(
    make_window, qtbot, wait_frame, errors_shown
) -> None:
    # A window of its own: the failed plugin stays failed for the session.
    win = measured_window(lambda camera: make_window(camera=camera), qtbot, wait_frame)
    tool = win.globe.active_tool()
    tool.plot = lambda: "not a plot"  # a buggy tool (the instance's plot, not the class's)
    wait_frame(win)
    qtbot.waitUntil(lambda: not win.plot_dock.isVisible(), timeout=5000)
    rec = win.plugins.registry.get("measure")
    assert rec.status == "failed" and "not a Plot" in (rec.error or "")


@pytest.mark.parametrize(
    ("x", "y", "curve"),
    [
        ([0.0, 1.0, 2.0, 3.0], [np.nan] * 4, False),  # every value missing: a hint, no curve
        ([5.0], [7.0], True),  # one point: a dot
        ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], True),  # A = B: a flat, zero-length profile
        ([0.0, 1e-9, 2e-9], [1e12, -1e12, 3.0], True),  # extreme ranges
        (np.linspace(0, 1, 200_000), np.sin(np.linspace(0, 60, 200_000)), True),  # many points
        ([0.0, 1.0, 2.0, 3.0, 4.0], [1.0, np.nan, 2.0, np.nan, 1.5], True),  # gaps
    ],
)
def test_dock_draws_any_plot_without_failing(qtbot, x, y, curve) -> None:
    from globeview.ui.plot_dock import PlotDock

    dock = PlotDock()
    qtbot.addWidget(dock)
    dock.resize(480, 300)
    dock.show()
    dock.set_plot(Plot("hostile", x, y, "x (u)", "y (u)"))
    assert (curve_pixels(dock) > 0) == curve
    dock.set_plot(None)
    assert curve_pixels(dock) == 0 and not dock.export_button.isEnabled()


@pytest.mark.parametrize(
    ("lo", "hi", "labels"),
    [
        (0.0, 31.7, ["0", "10", "20", "30"]),
        (440.0, 1650.0, ["500", "1,000", "1,500"]),
        (-0.3, 0.7, ["-0.2", "0.0", "0.2", "0.4", "0.6"]),  # no '-0', no 5.55e-17
        (-1e12, 1e12, ["-1e+12", "-5e+11", "0", "5e+11", "1e+12"]),
        (-3e-9, 1e-9, ["-3e-09", "-2e-09", "-1e-09", "0", "1e-09"]),
    ],
)
def test_tick_labels(lo: float, hi: float, labels: list[str]) -> None:
    from globeview.ui.plot_dock import _tick_text, nice_ticks

    ticks = nice_ticks(lo, hi)
    assert [_tick_text(v, ticks[1] - ticks[0]) for v in ticks] == labels


def test_a_plot_whose_table_raises_is_a_one_line_export_error(
    reused_window_at, qtbot, wait_frame, tmp_path: Path, errors_shown
) -> None:
    # A plugin's Plot subclass may override table()/csv_text(): its bug must not reach the
    # window's internal-error handler.
    from globeview.plugins.api import Plot

    win = measured_window(reused_window_at, qtbot, wait_frame)

    class Broken(Plot):
        def csv_text(self) -> str:
            raise ZeroDivisionError("the plugin's table bug")

    shown = win.plot_dock.plot
    win.plot_dock.set_plot(Broken(**{f: getattr(shown, f) for f in shown.__dataclass_fields__}))
    out = tmp_path / "exports"
    out.mkdir()
    target = out / "profile.csv"
    assert not win.plot_dock.export_csv(str(target))
    texts = [m.text for m in errors_shown]
    assert len(texts) == 1 and "\n" not in texts[0] and "table bug" in texts[0]
    assert list(out.iterdir()) == []  # nothing written, no temporary left
