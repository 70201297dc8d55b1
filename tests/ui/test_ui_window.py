"""The Qt shell end to end: a real window under a display, the real renderer, no mocks."""

from __future__ import annotations

import numpy as np
import pytest
from PyQt6.QtCore import QPoint, Qt

pytestmark = pytest.mark.gui


def centre(window) -> QPoint:
    g = window.globe
    return QPoint(g.width() // 2, g.height() // 2)


def test_window_opens_with_embedded_globe(make_window, frame_rgb):
    win = make_window()
    rgb = frame_rgb(win).astype(int)
    bg = np.array(win.globe.settings.background) * 255
    drawn = np.abs(rgb - bg).sum(axis=2) > 30
    assert drawn.mean() > 0.15, "the globe should cover a good part of the view"
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    ocean = (b > r + 40) & (b > g + 10)
    assert ocean.sum() > 2000, "blue ocean expected on the whole-globe view"
    assert win.terrain.layers[0].name == "etopo20"
    assert win.layer_panel.names()[-1] == "etopo20"  # bottom layer listed last
    st = win.globe.last_stats
    assert st.triangles > 0 and st.tiles_drawn > 0
    assert "chunked-sse" in win.status.lod.text()
    assert "tris" in win.status.triangles.text() and win.status.triangles.text() != "0 tris"


def test_hiding_a_layer_changes_stack_and_image(reused_window, frame_rgb, wait_frame):
    win = reused_window
    before = frame_rgb(win)
    win.layer_panel.set_visible("etopo20", False)
    assert not next(ly for ly in win.terrain.layers if ly.name == "etopo20").visible
    wait_frame(win)
    after = frame_rgb(win)
    assert np.abs(after.astype(int) - before.astype(int)).sum(axis=2).astype(bool).mean() > 0.05
    win.layer_panel.set_visible("etopo20", True)
    assert next(ly for ly in win.terrain.layers if ly.name == "etopo20").visible


def test_layer_order_buttons_move_layers(reused_window):
    win = reused_window
    panel = win.layer_panel
    panel.select("etopo20")
    panel.move_selected(-1)  # up one row: drawn after N44W072
    names = [ly.name for ly in win.terrain.layers]
    assert names.index("etopo20") == 1
    assert panel.names()[-2] == "etopo20"


def test_opening_a_file_adds_a_layer_and_flies_there(reused_window, small_dem, qtbot):
    win = reused_window
    win.files.open_paths([str(small_dem)])  # the path File > Open and drag-and-drop take
    qtbot.waitUntil(lambda: "hill" in [ly.name for ly in win.terrain.layers], timeout=60000)
    assert win.layer_panel.names()[0] == "hill"  # new layers go on top
    qtbot.waitUntil(lambda: not win.globe.flight.active, timeout=5000)
    lon, lat, h, *_ = win.globe.camera.lonlat_hpr()
    assert abs(lon - 10.5) < 0.05 and abs(lat - 45.5) < 0.05
    assert h < 1.0e6
    assert win.files.recent_files()[0].endswith("hill.tif")
    qtbot.waitUntil(lambda: win.files.load_bar.isHidden(), timeout=5000)


def test_left_drag_keeps_the_grabbed_point_under_the_cursor(reused_window, qtbot, wait_frame):
    win = reused_window
    g = win.globe
    start = centre(win)
    end = start + QPoint(80, 40)
    grabbed = g.pick(start.x(), start.y())
    assert grabbed is not None
    eye0 = g.camera.eye.copy()
    qtbot.mousePress(g, Qt.MouseButton.LeftButton, pos=start)
    for k in range(1, 5):
        qtbot.mouseMove(g, start + (end - start) * k / 4)
    qtbot.mouseRelease(g, Qt.MouseButton.LeftButton, pos=end)
    assert np.linalg.norm(g.camera.eye - eye0) > 1e5
    wait_frame(win)
    now = g.pick(end.x(), end.y())
    assert now is not None
    assert abs(now.lon - grabbed.lon) < 0.5 and abs(now.lat - grabbed.lat) < 0.5


def test_wheel_zooms_and_keys_fly(reused_window, qtbot):
    win = reused_window
    g = win.globe
    h0 = g.camera.height
    qtbot.wait(1)
    g.navigator.wheel(g.width() / 2, g.height() / 2, 2.0)
    assert g.camera.height < h0
    rot0 = g.camera.rotation.copy()
    qtbot.keyClick(g, Qt.Key.Key_Left)
    assert not np.allclose(g.camera.rotation, rot0)
    eye0 = g.camera.eye.copy()
    qtbot.keyClick(g, Qt.Key.Key_W)
    assert np.linalg.norm(g.camera.eye) < np.linalg.norm(eye0)


def test_status_bar_shows_lonlat_under_the_cursor(make_window, qtbot, frame_rgb, wait_frame):
    win = make_window()
    assert win.status.cursor.text() == "—"
    qtbot.mouseMove(win.globe, centre(win) + QPoint(3, 2))
    qtbot.waitUntil(lambda: "°" in win.status.cursor.text(), timeout=3000)
    text = win.status.cursor.text()
    assert ("N" in text or "S" in text) and ("E" in text or "W" in text)
    assert "alt" in win.status.altitude.text() and "km" in win.status.altitude.text()
    # Picking reads the depth buffer outside paintGL; later frames must still read back.
    wait_frame(win)
    rgb = frame_rgb(win).astype(int)
    assert ((rgb[..., 2] > rgb[..., 0] + 40) & (rgb[..., 2] > rgb[..., 1] + 10)).sum() > 2000


def test_go_to_flies_the_camera(reused_window, qtbot):
    win = reused_window
    assert not win.view_bar.go_to("not a place")
    assert "go to" in win.statusBar().currentMessage()
    assert win.view_bar.go_to("-123.1, 49.3, 80000")
    assert win.globe.flight.active
    qtbot.waitUntil(lambda: not win.globe.flight.active, timeout=5000)
    lon, lat, h, *_ = win.globe.camera.lonlat_hpr()
    assert abs(lon + 123.1) < 1e-6 and abs(lat - 49.3) < 1e-6 and abs(h - 80000) < 1.0


def test_go_to_takes_a_heading_and_pitch_and_refuses_bad_ones(reused_window, qtbot):
    win = reused_window
    for bad in ("-71.3, 44.15, 9000, 0", "-71.3, 44.15, 9000, 0, -95", "1, 2, nan", "1, 2, 1e12"):
        assert not win.view_bar.go_to(bad), bad
        assert "go to" in win.statusBar().currentMessage()
        assert not win.globe.flight.active
    assert win.view_bar.go_to("-71.3, 44.15, 9000, 370, -30")
    qtbot.waitUntil(lambda: not win.globe.flight.active, timeout=5000)
    lon, lat, h, heading, pitch, _ = win.globe.camera.lonlat_hpr()
    assert abs(lon + 71.3) < 1e-6 and abs(lat - 44.15) < 1e-6 and abs(h - 9000) < 1.0
    assert abs(heading - 10.0) < 1e-6 and abs(pitch + 30.0) < 1e-6


def test_a_flight_loads_its_destination_first_until_it_is_cut_short(make_window, qtbot):
    """Go to queues the destination view's tiles as the flight starts (ahead of the frames
    on the way); stopping the flight (the user took the camera) drops what is still
    queued of them."""
    win = make_window()
    g = win.globe
    queued = g.prefetch_pose((-71.3, 44.15, 9000.0, 0.0, -30.0))
    assert queued > 50  # the White Mountains view: hundreds of tiles, none resident yet
    assert g.prefetch_pose((float("nan"), 0.0, 1.0, 0.0, -90.0)) == 0  # not a camera: none
    assert win.view_bar.go_to(
        "-121.7, 46.85, 8000, 90, -25"
    )  # another place: replaces the prefetch
    loader = g.scene.renderer.loader
    assert loader.prefetching > 0
    g.flight.stop()
    assert not g.flight.active and loader.prefetching == 0


def test_status_bar_says_loading_n_tiles_while_tiles_load_then_clears(make_window, qtbot):
    """Go to a place whose tiles are not resident: frames say "loading N tiles" (N > 0)
    while the tiles stream in, and the field is empty once the view is complete (every tile
    drawn, no stand-ins)."""
    win = make_window()
    assert win.status.loading.text() == ""  # the start view is complete
    shown: list[str] = []
    complete: list[bool] = []  # per frame drawn after go_to: flight over, nothing loading

    def on_frame(*_: object) -> None:
        shown.append(win.status.loading.text())
        stats = win.globe.last_stats
        complete.append(
            not win.globe.flight.active
            and stats.tiles_loading == 0
            and stats.extra.get("tiles_missing") == 0
        )

    win.globe.frameRendered.connect(on_frame)
    assert win.view_bar.go_to("-71.3, 44.15, 9000, 0, -30")
    # Judge frames drawn after go_to only: on a loaded machine the flight's wall-clock time
    # can end before its first frame, when last_stats still describe the start view.
    qtbot.waitUntil(lambda: bool(complete) and complete[-1], timeout=60000)
    loading = [t for t in shown if t.startswith("loading ")]
    assert loading, shown
    assert all(int(t.split()[1]) > 0 and t.split()[2].startswith("tile") for t in loading)
    assert win.status.loading.text() == ""
    assert win.status.tiles.text() == f"{win.globe.last_stats.tiles_drawn} tiles"


def test_bad_file_shows_an_error_and_the_window_keeps_working(
    reused_window, tmp_path, qtbot, errors_shown, wait_frame
):
    win = reused_window
    bad = tmp_path / "broken.tif"
    bad.write_bytes(b"this is not a GeoTIFF")
    n_layers = len(win.terrain.layers)
    win.files.open_paths([str(bad), str(tmp_path / "missing.tif")])
    qtbot.waitUntil(lambda: len(errors_shown) >= 2, timeout=30000)
    assert "broken.tif" in errors_shown[0].text
    assert "Traceback" not in errors_shown[0].text
    assert "missing.tif" in errors_shown[1].text
    assert len(win.terrain.layers) == n_layers
    wait_frame(win)  # still drawing
    assert win.globe.last_stats.triangles > 0


def test_display_toggles_and_export(reused_window, tmp_path, frame_rgb, wait_frame):
    win = reused_window
    before = frame_rgb(win)
    win.view_bar.wire_check.setChecked(True)
    assert win.globe.settings.wireframe
    win.view_bar.exag_slider.setValue(50)
    assert win.globe.settings.exaggeration == pytest.approx(5.0)
    wait_frame(win)
    assert (frame_rgb(win) != before).any()
    out = tmp_path / "globe.png"
    assert win.export_image(str(out))
    from PIL import Image

    with Image.open(out) as im:
        assert im.size == (win.globe.width(), win.globe.height())


def test_settings_persist_between_windows(make_window, tmp_path):
    path = tmp_path / "persist.ini"
    win = make_window(settings_path=path)
    win.plugin_panel.set_tau(6.5)
    assert win.globe.scene.tau_px == pytest.approx(6.5)
    win.view_bar.hill_check.setChecked(True)
    win.files.add_recent(str(tmp_path / "a.tif"))
    win.close()
    win2 = make_window(settings_path=path)
    assert win2.plugin_panel.tau() == pytest.approx(6.5)
    assert win2.globe.settings.hillshade
    assert win2.files.recent_files()[0].endswith("a.tif")
    assert win2.files.recent_menu.actions()[0].text().endswith("a.tif")


def test_tiles_that_cannot_be_built_are_counted_and_do_not_keep_it_loading(make_window, qtbot):
    """Tiles whose heights cannot be read (here: every tile below level 9 over the White
    Mountains raises, as an unreadable store would) end as "N tiles failed" in the status
    bar, stood in by coarser tiles; the field does not stay at "loading"."""
    win = make_window()
    terrain = win.globe.scene.renderer.terrain
    real_heights = terrain.heights

    def heights(key, *args, **kwargs):
        if int(key[0]) >= 9:
            raise OSError(f"unreadable window for {tuple(key)}")
        return real_heights(key, *args, **kwargs)

    terrain.heights = heights
    try:
        assert win.view_bar.go_to("-71.3, 44.15, 9000, 0, -30")
        qtbot.waitUntil(
            lambda: (
                not win.globe.flight.active
                and win.globe.last_stats.tiles_loading == 0
                and win.globe.last_stats.extra.get("tiles_failed", 0) > 0
            ),
            timeout=60000,
        )
        stats = win.globe.last_stats
        failed = int(stats.extra["tiles_failed"])
        assert win.status.loading.text() == f"{failed} tiles failed"
        assert stats.extra["tiles_standin"] > 0 and stats.tiles_drawn > 0
    finally:
        del terrain.heights


def test_loading_text_counts_loading_and_failed_tiles():
    from globeview.lod.render_set import FrameStats
    from globeview.ui.status import loading_text

    assert loading_text(FrameStats()) == ""
    assert loading_text(FrameStats(tiles_loading=1)) == "loading 1 tile"
    assert loading_text(FrameStats(tiles_loading=3, extra={"tiles_failed": 2})) == (
        "loading 3 tiles, 2 failed"
    )
    assert loading_text(FrameStats(extra={"tiles_failed": 1})) == "1 tile failed"
