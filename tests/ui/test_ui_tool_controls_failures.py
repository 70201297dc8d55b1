"""A plugin failure's real reason stays visible in the window (issue #15 item 9): the
fallback notice carries it instead of a bare "not available", the plugin panel keeps it
under the provider choice, the LOD field's tooltip holds it, and a tool that cannot be
activated names *its own* failure, not that of whichever plugin failed first. External
plugins (real distributions through their entry points), a real window under a display."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.gui

BROKEN_LOD = """
name = "broken-lod"
version = "0.1.0"
description = "An LOD provider that raises."
kinds = ["lod"]
api_version = "1.0"

[[contributions]]
name = "broken-lod"
kind = "lod"
target = "broken_lod2.provider:BrokenProvider"
"""

BROKEN_LOD_MODULE = """
from globeview.plugins.api import LodProvider


class BrokenProvider(LodProvider):
    def select(self, view, terrain):
        raise RuntimeError("boom in select")
"""

BAD_TOOL = """
name = "bad-tool"
version = "0.1.0"
description = "A tool whose displacement hook raises."
kinds = ["tool"]
api_version = "1.0"

[[contributions]]
name = "bad-tool"
kind = "tool"
target = "bad_tool.tool:BadTool"
"""

BAD_TOOL_MODULE = """
from globeview.plugins.api import Tool


class BadTool(Tool):
    def displacement_glsl(self):
        raise ValueError("no shader for you")
"""


@pytest.fixture
def broken(plugin_site):
    plugin_site.add("broken_lod2", BROKEN_LOD, {"provider": BROKEN_LOD_MODULE})
    plugin_site.add("bad_tool", BAD_TOOL, {"tool": BAD_TOOL_MODULE})
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    return PluginRegistry(MemorySettings()).discover()


def test_provider_fallback_keeps_the_reason_visible(broken, make_window, wait_frame):
    win = make_window(registry=broken)
    panel = win.plugin_panel
    assert not panel.fallback_label.isVisibleTo(panel)
    panel.lod_combo.setCurrentIndex(panel.lod_combo.findData("broken-lod"))
    wait_frame(win)
    assert win.plugins.active == "chunked-sse"
    # The last notice (what the status bar shows now) says why, in one line.
    last = win.errors.history[-1].text
    assert last == (
        "LOD provider broken-lod failed: RuntimeError: boom in select; using chunked-sse"
    ), [m.text for m in win.errors.history]
    assert not any("not available" in m.text for m in win.errors.history)
    # It stays: in the plugin panel under the provider choice, and in the LOD field's tooltip.
    assert panel.fallback_label.isVisibleTo(panel)
    assert "boom in select" in panel.fallback_label.text()
    wait_frame(win)  # later frames and notices do not wipe it
    win.errors.notify("something else")
    assert "boom in select" in win.status.lod.toolTip()
    assert "boom in select" in panel.fallback_label.text()
    # Choosing a provider again clears it.
    win.plugins.set_enabled("broken-lod", True)
    panel.lod_combo.setCurrentIndex(panel.lod_combo.findData("chunked-sse"))
    panel.lod_combo.setCurrentIndex(panel.lod_combo.findData("broken-lod"))
    assert win.plugins.fallback_reason == ""


def test_tool_activation_failure_names_its_own_reason(broken, make_window, wait_frame):
    win = make_window(registry=broken)
    # Another plugin failed first: its reason must not be reported for the tool.
    panel = win.plugin_panel
    panel.lod_combo.setCurrentIndex(panel.lod_combo.findData("broken-lod"))
    wait_frame(win)
    assert broken.get("broken-lod").status == "failed"
    assert not win.tools.set_tool("bad-tool")
    texts = [m.text for m in win.errors.history]
    assert "tool bad-tool could not be activated: ValueError: no shader for you" in texts
    assert not any("could not be activated" in t and "boom" in t for t in texts)
    assert win.globe.scene.active_tool is None and win.tools.options.tool_name is None
