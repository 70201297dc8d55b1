"""Fixtures for the Qt shell tests: a real window under a display (Xvfb in CI:
``xvfb-run -a -s "-screen 0 1920x1080x24" pytest tests/ui`` with ``QT_QPA_PLATFORM=xcb``)."""

from __future__ import annotations

import os
import shutil
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


class _BlendWork:
    """The embedded stack's blend work, done once a session instead of once a window: each
    window's stack gets the embedded stores' blend masks (`BlendMask`, a function of the
    store alone, ~0.9 CPU-s at the first frame) and its fresh cache gets the band tables the
    first window wrote (``band-tables/*.npz``, ~0.5 CPU-s to measure). Both are what the
    window would compute itself; each test still has a cache folder of its own."""

    def __init__(self, stores: list, folder: Path) -> None:
        self._stores = set(stores)
        self._masks: dict = {}
        self._tables = folder  # band-tables/*.npz as the first windows wrote them

    def prime(self, terrain) -> None:
        """Before a window: hand its stack the masks and its cache the tables kept so far."""
        terrain._masks.update(self._masks)  # a private dict: a test-only short cut
        cache = Path(os.environ["GLOBEVIEW_CACHE_DIR"]) / "band-tables"
        try:
            cache.mkdir(parents=True, exist_ok=True)
            for src in self._tables.iterdir():
                if not (cache / src.name).exists():
                    shutil.copyfile(src, cache / src.name)
        except OSError:
            pass  # a test's unusable cache stays unusable: the window measures the tables

    def keep(self, terrain) -> None:
        """After a window's first complete view: keep its embedded masks and tables."""
        masks = dict(terrain._masks)
        self._masks.update({st: m for st, m in masks.items() if st in self._stores})
        cache = Path(os.environ["GLOBEVIEW_CACHE_DIR"]) / "band-tables"
        if not cache.is_dir():
            return
        for src in cache.glob("*.npz"):
            if not (self._tables / src.name).exists():
                shutil.copyfile(src, self._tables / src.name)


@pytest.fixture(scope="session")
def blend_work(embedded, tmp_path_factory) -> _BlendWork:
    """The embedded stack's blend masks and band tables, shared by every window (`_BlendWork`)."""
    return _BlendWork(embedded, tmp_path_factory.mktemp("band-tables"))


@pytest.fixture
def errors_shown() -> list:
    """Modal error messages the window would have shown (recorded instead of a dialog)."""
    return []


@pytest.fixture
def make_window(qtbot, tmp_path, embedded, blend_work, errors_shown, monkeypatch):
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
        blend_work.prime(terrain)
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
        blend_work.keep(terrain)
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
