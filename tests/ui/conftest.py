"""Fixtures for the Qt shell tests: a real window under a display (Xvfb in CI:
``xvfb-run -a -s "-screen 0 1920x1080x24" pytest tests/ui`` with ``QT_QPA_PLATFORM=xcb``)."""

from __future__ import annotations

import copy
import dataclasses
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


def _view_state(win) -> dict:
    """What the window tests look at, as plain values: a reused window must equal a fresh one
    in all of it before the next test (`reused_window`)."""
    from PyQt6.QtWidgets import QDockWidget

    model = win.model
    return {
        "layers": [(ly.name, ly.visible) for ly in win.terrain.layers],
        "overlays": [(type(o).__name__, getattr(o, "name", "")) for o in model.overlays],
        "tool": model.tool,
        "lod": model.lod,
        "tau_px": model.tau_px,
        "camera": tuple(round(v, 6) for v in model.camera.lonlat_hpr()),
        "display": repr(model.display),
        "docks": sorted((d.objectName(), d.isVisible()) for d in win.findChildren(QDockWidget)),
        "plot": win.plot_dock.plot,
        "tour": (repr(win.tour_panel.tour), win.tour_panel.seconds.value()),
        "tour_playing": win.tour_panel.playing,
        "bookmarks": model.bookmarks.names,
        "plugins": [(r.name, r.enabled, r.status, r.error) for r in win.plugins.records()],
        "errors": len(win.errors.history),
        "settings": {k: win.qsettings.value(k) for k in win.qsettings.allKeys()},
        "status": win.statusBar().currentMessage(),
        "busy": win.files.loader.busy,
        "flying": win.globe.flight.active,
        "size": (win.width(), win.height()),
    }


class _ReusedWindow:
    """One shown `MainWindow` on the embedded data and default plugins, for the tests that
    look at it but need no window of their own (`reused_window`): building a window, its GL
    context and first frame costs ~0.5 CPU-s and a few event-loop round trips a test. Each
    test gets it reset to its fresh `_view_state` and its own error recorder and cache."""

    def __init__(self, build) -> None:
        self._build = build
        self.errors: list = []  # the current test's `errors_shown`
        self.win = None
        self.fresh: dict = {}

    def get(self):
        """The window (built at the first call: `settled` must follow once it drew)."""
        if self.win is None:
            self.win = self._build(lambda msg: self.errors.append(msg))
            self.fresh = {}
        return self.win

    def settled(self) -> None:
        """The first view of a new window is complete: what every reset must come back to."""
        if not self.fresh:
            self.fresh = _view_state(self.win)
            self._fresh_camera = copy.deepcopy(self.win.model.camera)
            display = self.win.model.display
            fields = dataclasses.fields(display)
            self._fresh_display = {f.name: getattr(display, f.name) for f in fields}

    def reset(self, qtbot) -> None:
        """Puts back what a test changed: tool, layers, overlays, camera, LOD, tau, display,
        docks, error history and settings; then waits for a complete frame."""
        from PyQt6.QtWidgets import QApplication, QDockWidget

        from globeview.model.tour import Tour

        win, fresh = self.win, self.fresh
        qtbot.waitUntil(lambda: not win.files.loader.busy, timeout=60000)
        win.globe.flight.stop()
        win.model.tool = fresh["tool"]
        win.tour_panel.stop()
        win.tour_panel.tour = Tour()
        win.tour_panel.refresh()
        win.tour_panel.seconds.setValue(fresh["tour"][1])
        names = [name for name, _ in fresh["layers"]]
        for ly in list(win.terrain.layers):
            if ly.name not in names:
                win.terrain.remove(ly.name)
        for i, (name, visible) in enumerate(fresh["layers"]):
            win.terrain.move(name, i)
            win.terrain.set_visible(name, visible)
        for overlay in list(win.model.overlays):
            win.model.remove_overlay(overlay)
        for key, value in self._fresh_display.items():
            if getattr(win.model.display, key) != value:
                setattr(win.model.display, key, value)
        win.model.lod = fresh["lod"]
        win.model.tau_px = fresh["tau_px"]
        win.model.camera = copy.deepcopy(self._fresh_camera)
        for dock_name, visible in fresh["docks"]:
            dock = win.findChild(QDockWidget, dock_name)
            if dock is not None and dock.isVisible() != visible:
                dock.setVisible(visible)
        del win.errors.history[fresh["errors"] :]
        win.qsettings.clear()
        for key, value in fresh["settings"].items():
            win.qsettings.setValue(key, value)
        win.files._update_recent_menu()  # the recent list as the settings now say
        win.statusBar().showMessage(fresh["status"])

        # Docks shrink back once their contents went (a legend, a plot): then the window can.
        def resized() -> bool:
            QApplication.processEvents()
            win.resize(*fresh["size"])
            return (win.width(), win.height()) == fresh["size"]

        qtbot.waitUntil(resized, timeout=5000)
        win.activateWindow()
        win.globe.setFocus()
        n = win.globe.frames
        win.globe.request_frame()
        qtbot.waitUntil(lambda: win.globe.frames > n, timeout=10000)
        qtbot.waitUntil(
            lambda: win.globe.last_stats is not None and win.globe.last_stats.tiles_loading == 0,
            timeout=30000,
        )

    def discard(self) -> None:
        if self.win is not None:
            self.win.files.loader.shutdown()
            self.win.close()
            self.win.deleteLater()
        self.win = None


@pytest.fixture(scope="session")
def shared_window(qapp, embedded, blend_work, tmp_path_factory):
    from PyQt6.QtCore import QSettings

    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.ui.app import embedded_stack
    from globeview.ui.main_window import MainWindow

    folder = tmp_path_factory.mktemp("reused-window")

    def build(show_error):
        settings = QSettings(str(folder / "globeview.ini"), QSettings.Format.IniFormat)
        registry = PluginRegistry(MemorySettings()).discover()
        terrain = embedded_stack(embedded)
        blend_work.prime(terrain)
        win = MainWindow(terrain, settings, registry, show_error=show_error)
        win.resize(1000, 700)
        win.show()
        return win

    reused = _ReusedWindow(build)
    yield reused
    reused.discard()


@pytest.fixture
def reused_window(shared_window, qtbot, tmp_path, errors_shown, monkeypatch):
    """The shared `MainWindow` (see `_ReusedWindow`), as `make_window()` builds one: embedded
    data, default plugins, 1000 x 700, first view complete; the test's own `errors_shown` and
    GLOBEVIEW_CACHE_DIR. After the test it is reset, and must then equal a fresh window in
    everything `_view_state` lists, or the test errors and the window is built anew. For tests
    that change what a reset cannot put back (settings read at start, plugins failed, the
    window closed), use `make_window`."""
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    shared_window.errors = errors_shown
    fresh = shared_window.win is None
    win = shared_window.get()
    if fresh:
        qtbot.waitExposed(win)
    qtbot.waitUntil(lambda: win.globe.frames > 0, timeout=20000)
    qtbot.waitUntil(
        lambda: win.globe.last_stats is not None and win.globe.last_stats.tiles_loading == 0,
        timeout=30000,
    )
    shared_window.settled()
    yield win
    try:
        shared_window.reset(qtbot)
        left = {k: v for k, v in _view_state(win).items() if v != shared_window.fresh[k]}
    except Exception:
        shared_window.discard()
        raise
    if left:
        want = {k: shared_window.fresh[k] for k in left}
        shared_window.discard()
        pytest.fail(f"the reused window differs from a fresh one after the reset: {left} != {want}")


@pytest.fixture
def reused_window_at(reused_window, wait_frame):
    """A function: camera -> the reused window (`reused_window`) looking through it, its view
    complete (as `make_window(camera=...)` starts)."""

    def at(camera):
        reused_window.model.camera = camera
        wait_frame(reused_window)
        return reused_window

    return at


@pytest.fixture
def view_state():
    """A function: window -> what the window tests look at (`_view_state`)."""
    return _view_state


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
