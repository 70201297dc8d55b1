"""What the window leaves until after its first view (issue #27: launch to the globe drawn):
the embedded overlays open once the first complete view is drawn, below any overlay the user
opened meanwhile, as if opened first; a project opened meanwhile replaces them."""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.gui

ROOT = Path(__file__).resolve().parents[2]
BORDERS = "ne_110m_countries.geojson"
BLUE_MARBLE = "bluemarble_2048x1024.tif"
CITIES = ROOT / "data" / "ne_cities.geojson"


@pytest.fixture
def unshown_window(qtbot, tmp_path, embedded, blend_work, errors_shown, monkeypatch):
    """A function: -> a `MainWindow` on the embedded data with ``embedded_overlays=True``,
    built as `globeview.ui.app.run` builds it but not shown yet (`make_window` shows it and
    waits for its complete view)."""
    from PyQt6.QtCore import QSettings

    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.ui.app import embedded_stack
    from globeview.ui.main_window import MainWindow

    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    windows = []

    def make():
        settings = QSettings(str(tmp_path / "globeview.ini"), QSettings.Format.IniFormat)
        terrain = embedded_stack(embedded)
        blend_work.prime(terrain)
        registry = PluginRegistry(MemorySettings()).discover()
        win = MainWindow(
            terrain, settings, registry, show_error=errors_shown.append, embedded_overlays=True
        )
        qtbot.addWidget(win)
        win.resize(1000, 700)
        windows.append(win)
        return win

    yield make
    for win in windows:
        win.files.loader.shutdown()


def _show_until_complete(win, qtbot) -> None:
    win.show()
    qtbot.waitExposed(win)
    qtbot.waitUntil(
        lambda: win.globe.last_stats is not None and win.globe.last_stats.tiles_loading == 0,
        timeout=30000,
    )


def test_embedded_overlays_open_after_the_first_complete_view(unshown_window, qtbot):
    win = unshown_window()
    assert win.files.embedded_overlays_pending
    assert list(win.model.overlays) == [], "the embedded overlays wait for the first view"
    mine = win.files.open_overlay(str(CITIES))  # before the first view, e.g. from the CLI
    assert mine is not None
    _show_until_complete(win, qtbot)
    qtbot.waitUntil(lambda: not win.files.embedded_overlays_pending, timeout=10000)
    panel = win.layer_panel.overlays
    # Topmost first: the user's file stays on top, as when the borders opened first.
    assert panel.names() == [CITIES.name, BORDERS, BLUE_MARBLE]
    assert [ly.kind for ly in win.overlay_layers()][:2] == ["imagery", "vector"]
    # Bottom first: Blue Marble listed but hidden, the borders and the user's file shown.
    assert [ly.visible for ly in win.model.overlays] == [False, True, True]


def test_cancelled_embedded_overlays_never_open(unshown_window, qtbot):
    """What a project opened before the first view does (its overlays replace them)."""
    win = unshown_window()
    win.files.cancel_embedded_overlays()
    _show_until_complete(win, qtbot)
    n = win.globe.frames
    win.globe.request_frame()
    qtbot.waitUntil(lambda: win.globe.frames > n, timeout=10000)
    assert not win.files.embedded_overlays_pending
    assert list(win.model.overlays) == []
