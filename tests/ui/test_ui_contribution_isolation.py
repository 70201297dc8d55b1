"""Per-contribution isolation in the window (issue #15 item 9): a package's LOD provider
fails while drawing; the frame falls back, the plugin panel names the failed contribution
and its reason, and the same package's tool stays in the Tools toolbar and still activates.
A real window under a display; the package is a real distribution on sys.path."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.gui

MANIFEST = """
name = "pair"
version = "1.0.0"
description = "an LOD provider and a tool in one package"
kinds = ["lod", "tool"]
api_version = "1.0"

[[contributions]]
name = "pair-lod"
kind = "lod"
target = "gvt_pair_ui.lod:Provider"
label = "Pair LOD"

[[contributions]]
name = "pair-tool"
kind = "tool"
target = "gvt_pair_ui.tool:Clicker"
label = "Pair tool"
"""

LOD = """
from globeview.plugins.api import LodProvider

class Provider(LodProvider):
    def select(self, view, terrain):
        raise ZeroDivisionError("the provider's bug")
"""

TOOL = """
from globeview.plugins.api import Tool

class Clicker(Tool):
    def on_mouse(self, event):
        return False
"""


@pytest.fixture
def pair_registry(plugin_site):
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    plugin_site.add("gvt_pair_ui", MANIFEST, {"lod": LOD, "tool": TOOL})
    return PluginRegistry(MemorySettings()).discover()


def test_a_failed_provider_leaves_its_packages_tool_in_the_window(
    make_window, pair_registry, wait_frame
) -> None:
    win = make_window(registry=pair_registry)
    assert "pair-tool" in win.tools.actions
    panel = win.plugin_panel
    panel.lod_combo.setCurrentIndex(panel.lod_combo.findData("pair-lod"))  # as the user would
    wait_frame(win)  # select() raises: the frame falls back
    assert win.globe.scene.lod_name == "chunked-sse" and win.globe.last_stats.triangles > 0
    rec = pair_registry.get("pair")
    assert rec.status == "partial" and set(rec.failures) == {"pair-lod"}
    # The panel's row says which contribution failed and why (text and tooltip).
    rows = {
        panel.tree.topLevelItem(i).text(0): panel.tree.topLevelItem(i)
        for i in range(panel.tree.topLevelItemCount())
    }
    row = rows["pair"]
    assert "pair-lod" in row.text(3) and "ZeroDivisionError: the provider's bug" in row.text(3)
    assert row.text(3).startswith("partial: ")  # enabled: only one contribution failed
    assert "pair-lod" in row.toolTip(3)
    assert panel.lod_combo.findData("pair-lod") < 0
    # The tool of the same package is still offered and activates.
    win.tools.refresh()
    assert "pair-tool" in win.tools.actions
    win.tools.actions["pair-tool"].trigger()
    wait_frame(win)
    assert win.tools.active_tool_name() == "pair-tool"
    assert pair_registry.get("pair").status == "partial"
