"""Closing a window releases what it opened: its session and renderer become garbage, its
worker threads stop, and a DEM it opened leaves no open dataset behind. Structural facts (no
timings): what makes open-render-close flat in the window."""

from __future__ import annotations

import gc
import threading
import weakref

import pytest

pytestmark = pytest.mark.gui

#: Thread name prefixes of the window's workers (tile builders, the DEM loader, prefetch).
WORKER_PREFIXES = ("gv-tiles", "globeview-load", "tileload")


def _workers() -> set[int]:
    return {t.ident for t in threading.enumerate() if t.name.startswith(WORKER_PREFIXES)}


def test_closing_a_window_releases_its_session_threads_and_datasets(make_window, small_dem, qtbot):
    import rasterio

    before = _workers()
    win = make_window()
    win.files.open_paths([str(small_dem)])
    qtbot.waitUntil(lambda: "hill" in [ly.name for ly in win.terrain.layers], timeout=60000)
    qtbot.waitUntil(lambda: not win.files.loader.busy, timeout=60000)
    hill = next(ly.store for ly in win.terrain.layers if ly.name == "hill")
    session = weakref.ref(win.globe.scene)
    renderer = weakref.ref(win.globe.scene.renderer)
    assert _workers() - before  # the window did start workers

    win.close()
    win.terrain.remove("hill")
    hill.close()
    del hill
    for _ in range(3):
        gc.collect()
        qtbot.wait(50)
    assert session() is None and renderer() is None
    qtbot.waitUntil(lambda: not (_workers() - before), timeout=10000)
    open_hill = [
        o.name
        for o in gc.get_objects()
        if isinstance(o, rasterio.io.DatasetReader) and not o.closed and "hill" in o.name
    ]
    assert open_hill == []
