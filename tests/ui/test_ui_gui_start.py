"""`globeview gui --camera ... --lod ... --tool ... --set ...` starts a real window on that
view, with that LOD provider drawing, that tool active and those settings in effect for the
session (issue #29 item 12). The command line goes through the real parser and the checks
`globeview gui` runs (`cli.gui.check_start`); the window is a real `MainWindow` under Xvfb,
made and started in `ui.app.run`'s order: made on ``start.camera_object()``, `apply_start`
before it is shown (no GL, no session yet: the tool waits for the session), then shown."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.gui


def _start(monkeypatch, tmp_path, *argv: str):
    """The `WindowStart` of ``globeview gui ARGV``: parsed and checked as the command does."""
    from globeview.cli import build_parser, join_negative_values
    from globeview.cli.gui import check_start

    monkeypatch.setenv("GLOBEVIEW_CONFIG_DIR", str(tmp_path / "config"))
    args = build_parser().parse_args(join_negative_values(["gui", *argv]))
    return check_start(args)


@pytest.fixture
def started_window(qtbot, tmp_path, embedded, errors_shown, monkeypatch):
    """A function: WindowStart -> a shown `MainWindow` started as `ui.app.run` starts one,
    after its first complete frame."""
    from PyQt6.QtCore import QSettings

    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.ui.app import embedded_stack
    from globeview.ui.main_window import MainWindow
    from globeview.ui.start import apply_start

    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    windows = []

    def make(start):
        settings = QSettings(str(tmp_path / "globeview.ini"), QSettings.Format.IniFormat)
        registry = PluginRegistry(MemorySettings()).discover()
        win = MainWindow(
            embedded_stack(embedded),
            settings,
            registry,
            show_error=errors_shown.append,
            camera=start.camera_object(),
        )
        windows.append(win)
        qtbot.addWidget(win)
        apply_start(win, start)  # as app.run: before show, so before the GL session exists
        assert win.globe.scene is None
        win.resize(1000, 700)
        win.show()
        qtbot.waitExposed(win)
        qtbot.waitUntil(lambda: win.globe.frames > 0, timeout=20000)
        qtbot.waitUntil(
            lambda: win.globe.last_stats is not None and win.globe.last_stats.tiles_loading == 0,
            timeout=30000,
        )
        return win

    yield make
    for win in windows:
        win.files.loader.shutdown()


def test_camera_lod_tool_and_settings_are_applied(
    started_window, monkeypatch, tmp_path, errors_shown
) -> None:
    start = _start(
        monkeypatch, tmp_path,
        "--camera", "-71.3,44.27,30000,10,-60", "--lod", "distance-regions",
        "--tool", "measure", "--set", "measure.samples=64", "--set", "distance-regions.c=250",
    )  # fmt: skip
    win = started_window(start)
    assert errors_shown == []
    lon, lat, height, heading, pitch, _ = win.model.camera.lonlat_hpr()
    assert (lon, lat, heading, pitch) == pytest.approx((-71.3, 44.27, 10.0, -60.0), abs=1e-6)
    assert height == pytest.approx(30000.0, rel=1e-6)
    assert win.model.lod == "distance-regions"
    assert win.globe.last_stats.lod_provider == "distance-regions"
    assert win.plugins.provider().values["c"] == 250.0
    assert win.tools.active_tool_name() == "measure"
    tool = win.globe.active_tool()
    assert tool.values["samples"] == 64
    assert win.tools.options.editors["samples"].value() == 64
    # For this session only: nothing was stored.
    stored = win.plugins.registry.settings.get("plugins/measure/contributions/measure")
    assert not stored or "samples" not in stored


def test_no_options_leave_the_window_as_it_was(started_window, monkeypatch, tmp_path) -> None:
    from globeview.model.globe import DEFAULT_LOD

    start = _start(monkeypatch, tmp_path)
    win = started_window(start)
    assert win.model.lod == DEFAULT_LOD and win.tools.active_tool_name() is None
