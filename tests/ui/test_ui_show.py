"""`globeview.show(globe)`: the window on a `globeview.Globe`'s own model (issue #26). A
change made from the script (camera, DEM, LOD provider, display) is drawn by the window, and
one made in the window (navigation, a tool, the LOD panel) is what the script reads. A real
window under Xvfb, as the other window tests."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.gui

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture
def shown(qtbot, tmp_path, monkeypatch):
    """(globe, window): a `globeview.Globe` with a small DEM, shown; settings in tmp_path."""
    from PyQt6.QtCore import QSettings

    import globeview
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    globe = globeview.Globe(registry=PluginRegistry(MemorySettings()).discover())
    heights = np.add.outer(np.arange(64.0), np.arange(64.0)) * 20.0
    from affine import Affine

    globe.add_dem(heights, transform=Affine(1 / 64, 0, 10, 0, -1 / 64, 46), crs="EPSG:4326")
    globe.fly_to(10.5, 45.5, 200_000.0)
    settings = QSettings(str(tmp_path / "globeview.ini"), QSettings.Format.IniFormat)
    window = globeview.show(globe, settings=settings)
    qtbot.addWidget(window)
    qtbot.waitExposed(window)
    qtbot.waitUntil(lambda: window.globe.frames > 0, timeout=20000)
    yield globe, window
    window.files.loader.shutdown()


def test_the_window_shows_the_globes_own_model(shown):
    globe, window = shown
    assert window.model is globe.model
    assert window.globe.scene.globe is globe.model
    assert window.plugins.registry is globe.registry
    assert window.overlay_host is globe.overlay_host


def test_script_changes_show_in_the_window(shown, qtbot, wait_frame):
    globe, window = shown
    frames = window.globe.frames
    globe.fly_to(10.2, 45.2, 80_000.0, heading=30.0, pitch=-60.0)  # a frame is scheduled
    qtbot.waitUntil(lambda: window.globe.frames > frames, timeout=10000)
    assert window.model.camera.lonlat_hpr()[0] == pytest.approx(10.2, abs=1e-9)
    globe.set_lod("distance-regions")
    wait_frame(window)
    assert window.globe.last_stats.lod_provider == "distance-regions"
    assert window.status.lod.text() == "LOD distance-regions"
    globe.display.wireframe = True
    assert window.view_bar.wire_check.isChecked()
    globe.add_dem(DATA / "N44W072.hgt")
    assert [ly.name for ly in window.model.terrain.layers] == globe.dems
    wait_frame(window)
    assert window.globe.last_stats.triangles > 0


def test_window_changes_are_what_the_script_reads(shown, wait_frame):
    globe, window = shown
    window.globe.go_home()  # the window's View > Whole Globe
    window.globe.flight.stop()  # jump to the flight's end
    wait_frame(window)
    assert globe.camera == pytest.approx(globe.camera)  # a pose, read through the model
    lon, lat, height, *_ = window.model.camera.lonlat_hpr()
    assert (globe.camera.lon, globe.camera.lat) == pytest.approx((lon, lat))
    assert globe.camera.height == pytest.approx(height)
    window.plugins.choose("wavelet")
    assert globe.lod == "wavelet"
    window.model.tool = "measure"
    assert window.tools.actions["measure"].isChecked()
    assert globe.model.tool == "measure"


def test_show_after_a_headless_render(tmp_path):
    """A globe rendered headless, then shown, then rendered again: the window draws (its GLX
    context on this thread: the API draws with EGL on a thread of its own, since a thread
    that had an EGL context current cannot make a GLX one current), and the headless
    picture is the same before and after. In a process of its own, as a user's script."""
    script = f"""
import numpy as np
from affine import Affine
from PyQt6.QtCore import QSettings
import globeview
g = globeview.Globe()
g.add_dem(np.add.outer(np.arange(64.0), np.arange(64.0)) * 20.0,
          transform=Affine(1 / 64, 0, 10, 0, -1 / 64, 46), crs="EPSG:4326")
g.fly_to(10.5, 45.5, 200_000.0)
before = g.render((96, 64))
w = globeview.show(g, settings=QSettings({str(tmp_path / "w.ini")!r}, QSettings.Format.IniFormat))
from PyQt6.QtWidgets import QApplication
import time
t0 = time.monotonic()
while w.globe.frames < 2 and time.monotonic() - t0 < 60:
    QApplication.processEvents()
    time.sleep(0.01)
after = g.render((96, 64))
print("frames", w.globe.frames, "same", bool((before == after).all()))
w.close()
"""
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=180
    )
    assert out.returncode == 0, out.stderr[-2000:]
    frames, same = out.stdout.split()[1::2]
    assert int(frames) >= 2 and same == "True", out.stdout


def test_show_from_an_ipython_kernel_with_gui_qt(tmp_path, monkeypatch):
    """The use in IPython: ``%gui qt`` (IPython makes the QApplication), then
    ``globeview.show(globe)`` on a real kernel: the window draws, a ``fly_to`` redraws it,
    and the globe still renders headless. One cell, waiting on Qt's events in it: ipykernel
    7's Qt loop now and then misses the wake-up for the next cell (its edge-triggered zmq
    notifier; the kernel then sits idle in ``loop_qt``), which is not what this tests."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    from nbformat.v4 import new_code_cell, new_notebook

    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    code = f"""
get_ipython().run_line_magic("gui", "qt")
import time
import numpy as np
from affine import Affine
from PyQt6.QtCore import QSettings
from PyQt6.QtWidgets import QApplication
import globeview

made_by_ipython = QApplication.instance() is not None
g = globeview.Globe()
g.add_dem(np.add.outer(np.arange(64.0), np.arange(64.0)) * 20.0,
          transform=Affine(1 / 64, 0, 10, 0, -1 / 64, 46), crs="EPSG:4326")
g.fly_to(10.5, 45.5, 200_000.0)
w = globeview.show(g, settings=QSettings({str(tmp_path / "k.ini")!r}, QSettings.Format.IniFormat))

def wait(more_than, limit=60.0):
    t0 = time.monotonic()
    while w.globe.frames <= more_than and time.monotonic() - t0 < limit:
        QApplication.processEvents()
        time.sleep(0.01)
    return w.globe.frames > more_than

print("drawn", made_by_ipython, wait(0), w.isVisible())
n = w.globe.frames
g.fly_to(10.2, 45.2, 100_000.0)
print("redrawn", wait(n), w.model is g.model)
print("headless", g.render((64, 48)).shape)
"""
    nb = new_notebook(cells=[new_code_cell(code)])
    nbclient.NotebookClient(nb, kernel_name="python3", timeout=240).execute()
    text = "".join(o.get("text", "") for c in nb.cells for o in c.outputs)
    assert "drawn True True True" in text, text
    assert "redrawn True True" in text, text
    assert "headless (48, 64, 4)" in text, text
    del nbformat
