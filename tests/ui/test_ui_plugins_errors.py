"""Plugin manager panel, failure isolation, the exception hook and `globeview gui` without a
display."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from globeview.errors import DemError

pytestmark = pytest.mark.gui

BROKEN_MANIFEST = """
name = "broken-lod"
version = "0.3.0"
description = "An LOD provider that raises on its second frame."
kinds = ["lod"]
api_version = "1.0"

[[contributions]]
name = "broken-lod"
kind = "lod"
target = "broken_lod.provider:BrokenProvider"
label = "Broken"
"""

BROKEN_MODULE = """
from globeview.plugins.api import LodProvider, Setting
from globeview.plugins.builtin.chunked.provider import ChunkedSseProvider


class BrokenProvider(LodProvider):
    name = "broken-lod"
    settings = (Setting("fail_after", "int", 0, min=0, max=10, label="fail after"),)

    def __init__(self, context=None):
        super().__init__(context)
        self.frames = 0
        self.inner = ChunkedSseProvider(context)

    def select(self, view, terrain):
        self.frames += 1
        if self.frames > self.values["fail_after"]:
            raise RuntimeError("boom in select")
        return self.inner.select(view, terrain)
"""


@pytest.fixture
def broken_registry(plugin_site):
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    plugin_site.add("broken_lod", BROKEN_MANIFEST, {"provider": BROKEN_MODULE})
    return PluginRegistry(MemorySettings()).discover()


def test_plugin_panel_lists_plugins_and_switches_provider(make_window, wait_frame):
    win = make_window()
    panel = win.plugin_panel
    rows = {
        panel.tree.topLevelItem(i).text(0): panel.tree.topLevelItem(i)
        for i in range(panel.tree.topLevelItemCount())
    }
    assert "chunked-sse" in rows
    item = rows["chunked-sse"]
    assert item.text(1) == "1.0.0" and item.text(2) == "lod" and item.text(3) == "ok"
    assert item.checkState(0) == item.checkState(0).Checked
    assert panel.lod_combo.currentData() == "chunked-sse"
    assert "max_tiles" in panel.setting_widgets
    # a provider setting edited live
    panel.setting_widgets["max_tiles"].setValue(100)
    provider = win.plugins.provider()
    assert provider.values["max_tiles"] == 100
    wait_frame(win)
    assert win.globe.last_stats.tiles_drawn <= 100


def test_failing_provider_falls_back_and_is_reported(make_window, broken_registry, wait_frame):
    win = make_window(registry=broken_registry)
    panel = win.plugin_panel
    idx = panel.lod_combo.findData("broken-lod")
    assert idx >= 0
    panel.lod_combo.setCurrentIndex(idx)  # as the user would
    wait_frame(win)  # select() raises: the frame falls back to chunked-sse
    assert win.globe.last_stats.triangles > 0
    assert win.globe.scene.lod_name == "chunked-sse"
    assert win.plugins.active == "chunked-sse"
    rec = broken_registry.get("broken-lod")
    assert rec.status == "failed" and "boom in select" in rec.error
    assert any("broken-lod" in m.text for m in win.errors.history)
    assert panel.lod_combo.currentData() == "chunked-sse"
    assert panel.lod_combo.findData("broken-lod") < 0
    # re-enabling through the panel's switch makes it selectable again
    win.plugins.set_enabled("broken-lod", True)
    assert panel.lod_combo.findData("broken-lod") >= 0


def test_excepthook_shows_errors_instead_of_aborting(make_window, errors_shown):
    from globeview.ui.errors import install_excepthook

    win = make_window()
    previous = install_excepthook(win.errors)
    try:
        try:
            raise DemError("x.tif has no CRS")
        except DemError as exc:
            sys.excepthook(type(exc), exc, exc.__traceback__)
        try:
            raise ZeroDivisionError("division by zero")
        except ZeroDivisionError as exc:
            sys.excepthook(type(exc), exc, exc.__traceback__)
    finally:
        sys.excepthook = previous
    assert errors_shown[0].text == "x.tif has no CRS" and not errors_shown[0].details
    # A bug: one line naming the log file; the traceback goes there, never into the dialog.
    bug = errors_shown[1]
    assert bug.text.startswith("Unexpected error (ZeroDivisionError: division by zero)")
    assert "\n" not in bug.text and "Traceback" not in bug.text and not bug.details
    log_file = win.errors.log_file
    assert f"details in {log_file}" in bug.text
    logged = log_file.read_text()
    assert "Traceback" in logged and "ZeroDivisionError: division by zero" in logged
    assert "x.tif has no CRS" in logged and logged.count("Traceback") == 1
    assert win.isVisible()


def test_excepthook_in_a_qt_slot_reaches_the_reporter_not_stderr(make_window, errors_shown, capfd):
    """An exception escaping a real Qt slot (a timer callback) goes through the hook: one
    dialog line, the traceback in the log file, nothing on stderr."""
    from PyQt6.QtCore import QTimer
    from PyQt6.QtWidgets import QApplication

    from globeview.ui.errors import install_excepthook

    win = make_window()
    capfd.readouterr()
    previous = install_excepthook(win.errors)

    def slot() -> None:
        {}["missing key"]

    try:
        QTimer.singleShot(0, slot)
        for _ in range(20):
            QApplication.processEvents()
            if errors_shown:
                break
    finally:
        sys.excepthook = previous
    assert len(errors_shown) == 1
    assert errors_shown[0].text.startswith("Unexpected error (KeyError")
    assert "details in" in errors_shown[0].text and not errors_shown[0].details
    assert "missing key" in win.errors.log_file.read_text()
    assert "Traceback" not in capfd.readouterr().err


def test_gui_without_display_prints_one_line(tmp_path):
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM")
    }
    code = (
        "import argparse, sys\n"
        "from globeview.cli import gui\n"
        "p = argparse.ArgumentParser(); gui.add_arguments(p)\n"
        "rc = gui.run(p.parse_args([]))\n"
        "assert 'PyQt6' not in sys.modules\n"
        "sys.exit(rc)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 1, proc.stderr
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
    assert len(lines) == 1
    assert "display" in lines[0] and "globeview render" in lines[0]


FAULTY_MANIFEST = """
name = "{name}"
version = "0.1.0"
description = "An LOD provider that misbehaves on its first frame."
kinds = ["lod"]
api_version = "1.0"

[[contributions]]
name = "{name}"
kind = "lod"
target = "{module}.provider:Provider"
label = "Faulty"
"""

FAULTY_MODULE = """
import numpy as np

from globeview.plugins.api import LodProvider
from globeview.plugins.builtin.chunked.provider import ChunkedSseProvider

CALLS = []


class Provider(LodProvider):
    name = "{name}"

    def __init__(self, context=None):
        super().__init__(context)
        self.inner = ChunkedSseProvider(context)

    def select(self, view, terrain):
        CALLS.append(1)
        {body}
"""

#: name -> (select body, words the plugin's recorded reason must contain)
FAULTS = {
    "sysexit-lod": ("raise SystemExit(3)", "SystemExit"),
    # A RenderSet whose variant ids point past its variants (and a level-40 key): it passes
    # isinstance, so only the host's validation stands between it and the renderer.
    "garbage-lod": (
        "rs = self.inner.select(view, terrain)\n"
        "        rs.variant_ids = np.full(len(rs.keys), 999, dtype=np.int64)\n"
        "        rs.keys = rs.keys.copy(); rs.keys[0, 0] = 40\n"
        "        return rs",
        "InvalidRenderSet",
    ),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_faulty_provider_is_failed_in_the_panel_and_frames_keep_coming(
    fault, make_window, plugin_site, wait_frame, capfd
):
    """A provider raising SystemExit, or returning a garbage render set, in the window: its
    plugin shows as failed with the reason in the plugins panel, the LOD falls back to
    chunked-sse, it is not called again (frames do not keep paying for it), the globe keeps
    drawing, and nothing reaches stderr."""
    import importlib

    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    body, words = FAULTS[fault]
    module = fault.replace("-", "_")
    plugin_site.add(
        module,
        FAULTY_MANIFEST.format(name=fault, module=module),
        {"provider": FAULTY_MODULE.format(name=fault, body=body)},
    )
    registry = PluginRegistry(MemorySettings()).discover()
    win = make_window(registry=registry)
    capfd.readouterr()
    panel = win.plugin_panel
    idx = panel.lod_combo.findData(fault)
    assert idx >= 0
    panel.lod_combo.setCurrentIndex(idx)  # as the user would
    wait_frame(win)
    calls = importlib.import_module(f"{module}.provider").CALLS
    assert len(calls) == 1

    rec = registry.get(fault)
    assert rec.status == "failed" and words in rec.error and rec.error
    row = next(
        panel.tree.topLevelItem(i)
        for i in range(panel.tree.topLevelItemCount())
        if panel.tree.topLevelItem(i).text(0) == fault
    )
    assert row.text(3).startswith("failed") and rec.error in row.text(3)
    assert win.globe.scene.lod_name == "chunked-sse"
    assert panel.lod_combo.currentData() == "chunked-sse"
    assert any(fault in m.text for m in win.errors.history)
    assert not any("Unexpected error" in m.text for m in win.errors.history)

    n = win.globe.frames
    for _ in range(3):
        win.globe.camera.fly_yaw(0.01)
        wait_frame(win)
    assert win.globe.frames >= n + 3
    assert win.globe.last_stats.triangles > 0
    assert len(calls) == 1  # failed once, never asked again
    assert "Traceback" not in capfd.readouterr().err
