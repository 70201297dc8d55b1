"""The reused window of the window tests (tests/ui/conftest.py `reused_window`): after a test
changed it, its reset makes it read and draw as a freshly built window does, so no test sees
what the one before it did."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.model.camera import Camera

pytestmark = pytest.mark.gui


def test_a_reset_window_reads_and_draws_as_a_fresh_one(
    reused_window, shared_window, make_window, view_state, frame_rgb, wait_frame, qtbot, small_dem
) -> None:
    win = reused_window
    # What tests change: a tool, tau, display, a layer's visibility and order, a new layer,
    # overlays, recent files, the camera, a tour, a dock, the error history.
    win.model.tool = "measure"
    win.model.tau_px = 9.0
    win.model.display.wireframe = True
    win.model.display.exaggeration = 3.0
    win.layer_panel.set_visible("etopo20", False)
    win.layer_panel.select("etopo20")
    win.layer_panel.move_selected(-1)
    win.files.open_paths([str(small_dem)])
    qtbot.waitUntil(lambda: "hill" in [ly.name for ly in win.terrain.layers], timeout=60000)
    win.globe.scene.add_embedded_overlays(imagery=True)
    win.model.camera = Camera.from_lonlat(-71.3, 44.15, 9000.0)
    win.tour_panel.add_view()
    win.tour_panel.seconds.setValue(2.5)
    win.plugin_dock.hide()
    win.errors.notify("a notice")
    wait_frame(win)
    changed = view_state(win)
    shared_window.reset(qtbot)

    fresh = make_window()
    state, want = view_state(win), view_state(fresh)
    assert changed != want  # the changes above were seen...
    assert state == want  # ...and put back: nothing of them is left
    ours, theirs = frame_rgb(win).astype(int), frame_rgb(fresh).astype(int)
    assert ours.shape == theirs.shape
    differs = np.abs(ours - theirs).sum(axis=2) > 30
    assert differs.mean() < 0.001, differs.mean()
