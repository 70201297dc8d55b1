"""The window shows an LOD provider's own stats (issue #15 item 7): the status bar's LOD
field names the provider that drew, the tiles per quadtree level and the provider's counters
(cleaned: garbage dropped), for an installed provider (a real distribution)."""

from __future__ import annotations

import pytest

from globeview.app.testing import PluginSite, plugin_manifest
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings

pytestmark = pytest.mark.gui

STATS_PROVIDER = """
import numpy as np
from globeview.plugins.api import IndexVariant, LodProvider, RenderSet

class Provider(LodProvider):
    frames = 0

    def select(self, view, terrain):
        type(self).frames += 1
        keys = np.array([(1, x, y) for x in range(4) for y in range(2)], np.int64)
        stats = {"gvt_frames": type(self).frames, "gvt_mode": "every level-1 tile",
                 "gvt_garbage": object()}
        return RenderSet(keys, np.zeros(8, np.int64), [IndexVariant()], stats=stats)
"""


def test_status_bar_shows_provider_stats_and_levels(
    make_window, plugin_site: PluginSite, qtbot
) -> None:
    plugin_site.add("gvt_uistats", plugin_manifest("gvt-uistats", "gvt_uistats"),
                    {"impl": STATS_PROVIDER})  # fmt: skip
    win = make_window(registry=PluginRegistry(MemorySettings()).discover())
    default_tip = win.status.lod.toolTip()
    assert "Active LOD provider: chunked-sse" in default_tip and "Tiles per level: L" in default_tip
    win.plugins.choose("gvt-uistats")
    win.globe.request_frame()
    # Tiles stream in on worker threads: the first frames draw fewer than the set's 8.
    qtbot.waitUntil(lambda: "L1: 8" in win.status.lod.toolTip(), timeout=20000)
    tip = win.status.lod.toolTip()
    assert win.status.lod.text() == "LOD gvt-uistats"
    assert "Active LOD provider: gvt-uistats" in tip
    assert "Tiles per level: L1: 8" in tip
    assert "gvt_mode = every level-1 tile" in tip
    assert "gvt_garbage" not in tip and "1 entries dropped" in tip
