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


#: Modules the launch must not import before the first frame (pyproj: the embedded borders'
#: geodesics come after the first complete view) and, but pyproj, before the first complete
#: view (the ingest and the DEM reader: the embedded stores open as stamped,
#: `globeview.terrain.embedded`).
LAZY = ("globeview.terrain.ingest.driver", "globeview.terrain.dem.reader", "pyproj")

CHILD = """
import sys
from PyQt6.QtCore import QSettings, QTemporaryDir, QTimer
import globeview.ui.app as app

qapp = app.create_application()
tmp = QTemporaryDir()
qs = QSettings(tmp.filePath("w.ini"), QSettings.Format.IniFormat)
win = app.MainWindow(app.embedded_terrain(), qs, app.plugin_registry(qs), embedded_overlays=True)
done = []

def rendered(stats, fps):
    if done:
        return
    imported = " ".join(m for m in sys.argv[1:] if m in sys.modules)
    if win.globe.frames == 1:
        print("first frame:", imported, flush=True)
    if stats.tiles_loading == 0:
        done.append(True)
        print("complete view:", imported, flush=True)
        print("overlays:", len(win.model.overlays), flush=True)
        QTimer.singleShot(0, finish)

def finish():
    win.close()
    qapp.quit()

win.globe.frameRendered.connect(rendered)
win.show()
QTimer.singleShot(60_000, qapp.quit)
qapp.exec()
sys.exit(0 if done else 1)
"""


def test_launch_imports_no_ingest_and_no_pyproj(embedded_cache, tmp_path):
    """A window launched as `globeview gui` launches it (a process of its own: this one has
    imported everything), on a cache whose embedded stores were stamped: none of `LAZY` is
    imported by its first frame, neither the ingest nor the DEM reader by its first complete
    view, and the embedded overlays are open then."""
    import os
    import subprocess
    import sys

    from globeview.terrain.embedded import embedded_stores

    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(embedded_cache)}
    env["GLOBEVIEW_CONFIG_DIR"] = str(tmp_path / "config")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GLOBEVIEW_CACHE_DIR", str(embedded_cache))
        for store in embedded_stores():  # stamps them (as a first launch does)
            store.close()
    out = subprocess.run(
        [sys.executable, "-c", CHILD, *LAZY],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    lines = dict(line.split(":", 1) for line in out.stdout.splitlines() if ":" in line)
    assert lines["first frame"].split() == [], out.stdout
    assert lines["complete view"].split() in ([], ["pyproj"]), out.stdout
    assert lines["overlays"].strip() == "2", out.stdout
