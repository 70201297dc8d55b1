"""The installed example plugin (examples/globeview-fixedlevel, a real distribution found
through its entry point) in a real window: all three of its kinds reach the user the way a
built-in's do. Its `.graticule` layer type is in the Open Overlay filter and draws; its
marker tool gets controls built from its settings; its capped-sse provider, which wraps
chunked-sse, can be chosen and draws the frame."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.gui


def magenta_pixels(rgb: np.ndarray) -> int:
    r, g, b = (rgb[..., k].astype(int) for k in range(3))
    return int(((r > 200) & (g < 90) & (b > 200)).sum())


def test_graticule_file_in_the_filter_and_drawn(reused_window, frame_rgb, wait_frame, tmp_path):
    from globeview.app.layer_dispatch import overlay_file_filter

    win = reused_window
    assert "*.graticule" in overlay_file_filter(win.plugins.registry)
    wait_frame(win)
    before = magenta_pixels(frame_rgb(win))
    grid = tmp_path / "grid.graticule"
    grid.write_text("step_deg = 10\ncolor = 1 0 1 1\nwidth_px = 3\n", encoding="utf-8")
    added = win.files.open_overlays([str(grid)])  # the dialog's path
    assert len(added) == 1 and "grid.graticule" in win.layer_panel.overlays.names()
    wait_frame(win)
    assert before == 0 and magenta_pixels(frame_rgb(win)) > 2000


def test_marker_settings_are_window_controls(make_window) -> None:
    win = make_window()
    win.tools.actions["marker"].trigger()
    tool = win.globe.active_tool()
    bar = win.tools.options
    assert bar.tool_name == "marker" and list(bar.editors) == ["size_px", "color", "numbered"]
    bar.editors["color"].combo.setCurrentText("cyan")
    bar.editors["numbered"].check.setChecked(False)
    assert tool.values["color"] == "cyan" and tool.values["numbered"] is False


def test_capped_provider_chosen_in_the_panel_draws(reused_window, wait_frame) -> None:
    win = reused_window
    panel = win.plugin_panel
    idx = panel.lod_combo.findData("capped-sse")
    assert idx >= 0
    panel.lod_combo.setCurrentIndex(idx)  # as the user would
    wait_frame(win)
    wait_frame(win)
    assert win.globe.scene.lod_name == "capped-sse"
    assert win.globe.last_stats.lod_provider == "capped-sse"
    assert win.globe.last_stats.triangles > 0
