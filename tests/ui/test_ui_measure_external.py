"""The Plot dock is generic (issue #15): an installed tool plugin — a real distribution on
sys.path, importing only the facade — publishes its own plot and the window shows and exports
it as it does the built-in measure tool's; a tool whose ``plot()`` raises is failed alone and
the window carries on. A real window under a display."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from PyQt6.QtCore import QPoint, Qt

pytestmark = pytest.mark.gui

MANIFEST = """
name = "clicklog"
version = "1.0.0"
description = "logs the latitude of each click as a plot"
kinds = ["tool"]
api_version = "1.1"

[[contributions]]
name = "clicklog"
kind = "tool"
target = "gvt_clicklog.impl:ClickLog"
label = "Click log"

[[contributions]]
name = "badplot"
kind = "tool"
target = "gvt_clicklog.impl:BadPlot"
label = "Bad plot"
"""

IMPL = """
from globeview.plugins.api import Plot, Tool


class ClickLog(Tool):
    name = "clicklog"

    def __init__(self, context=None):
        super().__init__(context)
        self.lats = []
        self._plot = None

    def on_mouse(self, event):
        if event.kind != "press" or event.lonlat is None:
            return False
        self.lats.append(event.lonlat[1])
        n = len(self.lats)
        self._plot = Plot("clicks", list(range(n)), self.lats, "click", "latitude (deg)",
                          columns={"click": list(range(n)), "lat": self.lats})
        self.context.renderer.request_redraw()
        return True

    def plot(self):
        return self._plot


class BadPlot(Tool):
    name = "badplot"

    def plot(self):
        raise RuntimeError("the plot's bug")
"""


@pytest.fixture
def registry(plugin_site):
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    plugin_site.add("gvt_clicklog", MANIFEST, {"impl": IMPL})
    return PluginRegistry(MemorySettings()).discover()


def test_an_installed_tools_plot_is_shown_and_exported(
    make_window, registry, qtbot, wait_frame, tmp_path: Path, errors_shown
) -> None:
    win = make_window(registry=registry)
    g = win.globe
    win.tools.actions["clicklog"].trigger()
    assert not win.plot_dock.isVisible()
    for dx in (0, 30):  # the centre now: the dock takes room once the first plot shows
        centre = QPoint(g.width() // 2, g.height() // 2)
        qtbot.mouseClick(g, Qt.MouseButton.LeftButton, pos=centre + QPoint(dx, 0))
        wait_frame(win)
    qtbot.waitUntil(lambda: win.plot_dock.plot is not None and win.plot_dock.plot.x.size == 2)
    assert win.plot_dock.isVisible() and win.plot_dock.title.text() == "clicks"
    out = tmp_path / "clicks.csv"
    assert win.plot_dock.export_csv(str(out))
    with out.open(newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["click", "lat"] and len(rows) == 3
    assert errors_shown == []


def test_a_plot_that_raises_fails_only_its_tool(make_window, registry, wait_frame) -> None:
    win = make_window(registry=registry)
    win.tools.actions["badplot"].trigger()
    wait_frame(win)
    wait_frame(win)
    rec = registry.get("clicklog")
    assert set(rec.failures) == {"badplot"} and "the plot's bug" in rec.failures["badplot"].error
    assert rec.status == "partial" and not win.plot_dock.isVisible()
    win.tools.refresh()
    assert "clicklog" in win.tools.actions  # the same package's other tool stays
