"""Fixtures for the Qt shell tests: a real window under a display (Xvfb in CI:
``xvfb-run -a -s "-screen 0 1920x1080x24" pytest tests/ui`` with ``QT_QPA_PLATFORM=xcb``)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

HAVE_DISPLAY = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def pytest_collection_modifyitems(config, items):
    if HAVE_DISPLAY and os.environ.get("QT_QPA_PLATFORM", "xcb") != "offscreen":
        return
    if os.environ.get("GLOBEVIEW_REQUIRE_DISPLAY") == "1":
        # ./test starts Xvfb: a missing display there is a broken set-up, not a reason to skip.
        raise pytest.UsageError("the window tests need a display (./test runs them under Xvfb)")
    skip = pytest.mark.skip(reason="needs a display with OpenGL (run under xvfb-run)")
    for item in items:
        if "gui" in item.keywords and "tests/ui" in str(item.fspath).replace(os.sep, "/"):
            item.add_marker(skip)


@pytest.fixture(scope="session")
def embedded():
    """The embedded tile stores (ingested into the user cache once)."""
    from globeview.terrain.embedded import embedded_stores

    return embedded_stores()


@pytest.fixture
def errors_shown() -> list:
    """Modal error messages the window would have shown (recorded instead of a dialog)."""
    return []


@pytest.fixture
def make_window(qtbot, tmp_path, embedded, errors_shown, monkeypatch):
    """Build a shown `MainWindow` on the embedded data with settings in tmp_path; waits for
    its first frame. Returns a function taking MainWindow keyword arguments."""
    from PyQt6.QtCore import QSettings

    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.ui.app import embedded_stack
    from globeview.ui.main_window import MainWindow

    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    windows = []

    def make(registry=None, settings_path: Path | None = None, **kw):
        settings = QSettings(
            str(settings_path or tmp_path / "globeview.ini"), QSettings.Format.IniFormat
        )
        if registry is None:
            registry = PluginRegistry(MemorySettings()).discover()
        terrain = embedded_stack(embedded)  # the stack the app opens with
        win = MainWindow(terrain, settings, registry, show_error=errors_shown.append, **kw)
        qtbot.addWidget(win)
        win.resize(1000, 700)
        win.show()
        qtbot.waitExposed(win)
        qtbot.waitUntil(lambda: win.globe.frames > 0, timeout=20000)
        # Tiles stream in on worker threads: wait until the view is complete.
        qtbot.waitUntil(
            lambda: win.globe.last_stats is not None and win.globe.last_stats.tiles_loading == 0,
            timeout=30000,
        )
        windows.append(win)
        return win

    yield make
    for win in windows:
        win.files.loader.shutdown()


def _frame_rgb(window) -> np.ndarray:
    from PyQt6.QtGui import QImage

    img = window.globe.grab_image().convertToFormat(QImage.Format.Format_RGB888)
    w, h, bpl = img.width(), img.height(), img.bytesPerLine()
    data = np.frombuffer(img.constBits().asstring(bpl * h), np.uint8).reshape(h, bpl)
    return data[:, : w * 3].reshape(h, w, 3).copy()


@pytest.fixture
def frame_rgb():
    """A function: window -> the globe view's current frame as (h, w, 3) uint8."""
    return _frame_rgb


@pytest.fixture
def wait_frame(qtbot):
    """A function: window -> None, requesting a frame and waiting until it is drawn."""

    def wait(window) -> None:
        n = window.globe.frames
        window.globe.request_frame()
        qtbot.waitUntil(lambda: window.globe.frames > n, timeout=10000)
        qtbot.waitUntil(lambda: window.globe.last_stats.tiles_loading == 0, timeout=30000)

    return wait


@pytest.fixture
def small_dem(tmp_path) -> Path:
    """A 64x64 GeoTIFF (EPSG:4326) of a 1500 m hill at 10..11°E, 45..46°N."""
    import rasterio
    from affine import Affine

    n = 64
    yy, xx = np.mgrid[0:n, 0:n]
    z = 1500.0 * np.exp(-(((xx - n / 2) ** 2 + (yy - n / 2) ** 2) / (2 * (n / 6) ** 2)))
    path = tmp_path / "hill.tif"
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=n,
        height=n,
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=Affine(1.0 / n, 0.0, 10.0, 0.0, -1.0 / n, 46.0),
    ) as ds:
        ds.write(z.astype(np.float32), 1)
    return path
