"""Overlay layers in the window: the embedded borders and Blue Marble, opening GeoJSON,
errors, and the overlay panel's controls, on a real window and renderer (no mocks)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PyQt6.QtGui import QColor

pytestmark = pytest.mark.gui

ROOT = Path(__file__).resolve().parents[2]
BORDERS = "ne_110m_countries.geojson"
BLUE_MARBLE = "bluemarble_2048x1024.tif"


def border_pixels(rgb: np.ndarray) -> int:
    """Pixels of the borders' yellow (1.0, 0.92, 0.35): bright red+green, little blue."""
    r, g, b = (rgb[..., k].astype(int) for k in range(3))
    return int(((r > 200) & (g > 170) & (b < 150) & (r - b > 90)).sum())


def placemark_pixels(rgb: np.ndarray) -> int:
    """Pixels of the placemarks' red (1.0, 0.25, 0.15)."""
    r, g, b = (rgb[..., k].astype(int) for k in range(3))
    return int(((r > 180) & (g < 110) & (b < 100)).sum())


@pytest.fixture
def redraw(qtbot):
    """A function: window -> None, drawing a frame once the terrain tiles have streamed in
    (imagery composes inside the frame: slow)."""

    def draw(window) -> None:
        g = window.globe
        qtbot.waitUntil(lambda: g.last_stats.tiles_loading == 0, timeout=30000)
        n = g.frames
        g.request_frame()
        qtbot.waitUntil(lambda: g.frames > n and g.last_stats.tiles_loading == 0, timeout=30000)

    return draw


def test_embedded_borders_drawn_at_start_and_hidden(make_window, frame_rgb, redraw):
    win = make_window(embedded_overlays=True)
    panel = win.layer_panel.overlays
    assert panel.names() == [BORDERS, BLUE_MARBLE]  # topmost first
    assert [ly.kind for ly in win.overlay_layers()] == ["imagery", "vector"]
    blue = panel.find(BLUE_MARBLE)
    assert not blue.layer.visible, "Blue Marble is listed but hidden at start"
    assert panel.list.item(1).checkState().value == 0
    redraw(win)
    shown = border_pixels(frame_rgb(win))
    assert shown > 30, f"country borders should be drawn at start ({shown} px)"
    panel.set_visible(panel.find(BORDERS), False)
    redraw(win)
    assert border_pixels(frame_rgb(win)) == 0
    panel.set_visible(panel.find(BORDERS), True)
    redraw(win)
    assert border_pixels(frame_rgb(win)) > 30


def test_blue_marble_shows_and_opacity_blends(reused_window, frame_rgb, redraw):
    win = reused_window
    win.files.open_embedded_overlays()  # as embedded_overlays=True opens them
    panel = win.layer_panel.overlays
    panel.set_visible(panel.find(BORDERS), False)
    redraw(win)
    relief = frame_rgb(win).astype(int)
    bg = np.array(win.globe.settings.background) * 255
    globe = np.abs(relief - bg).sum(axis=2) > 30
    blue = panel.find(BLUE_MARBLE)
    panel.set_visible(blue, True)
    redraw(win)
    imagery = frame_rgb(win).astype(int)
    changed = np.abs(imagery - relief).sum(axis=2) > 30
    assert changed[globe].mean() > 0.3, "the imagery should recolour ocean and land"
    # The opacity slider of the selected drape blends it with the relief.
    panel.select(blue)
    assert panel.opacity_slider.isVisibleTo(panel) and panel.opacity_slider.value() == 100
    panel.opacity_slider.setValue(30)
    assert blue.layer.opacity == pytest.approx(0.3)
    redraw(win)
    half = frame_rgb(win).astype(int)
    to_relief = np.abs(half - relief).sum(axis=2)[globe].mean()
    full_to_relief = np.abs(imagery - relief).sum(axis=2)[globe].mean()
    assert 0.05 * full_to_relief < to_relief < 0.6 * full_to_relief


def test_open_cities_adds_points_layer_with_placemarks(reused_window, frame_rgb, redraw):
    win = reused_window
    redraw(win)
    before = placemark_pixels(frame_rgb(win))
    added = win.files.open_overlays([str(ROOT / "data" / "ne_cities.geojson")])  # the dialog's path
    assert [ly.kind for ly in added] == ["points"]
    assert win.layer_panel.overlays.names() == ["ne_cities.geojson"]
    redraw(win)
    after = placemark_pixels(frame_rgb(win))
    assert after > before + 100, f"placemarks expected ({before} -> {after} red pixels)"
    # Live style: the width/size spin box resizes the placemarks on the next frame.
    panel = win.layer_panel.overlays
    panel.select(added[0])
    panel.width_spin.setValue(20.0)
    assert added[0].size_px == 20.0
    redraw(win)
    assert placemark_pixels(frame_rgb(win)) > after * 1.5


def test_broken_geojson_reports_and_changes_nothing(reused_window, errors_shown, tmp_path):
    win = reused_window
    win.files.open_embedded_overlays()  # as embedded_overlays=True opens them
    names = win.layer_panel.overlays.names()
    layers = list(win.overlay_layers())
    bad = tmp_path / "broken.geojson"
    bad.write_text('{"type": "FeatureCollection", "features": [', encoding="utf-8")
    assert win.files.open_overlays([str(bad)]) == []
    assert errors_shown, "an error message should be shown"
    text = errors_shown[-1].text
    assert "broken.geojson" in text and "\n" not in text and "Unexpected" not in text
    assert win.layer_panel.overlays.names() == names
    assert win.overlay_layers() == layers
    # Drag and drop takes the same way (decided by content) and reports the same error.
    shown = len(errors_shown)
    win.files.open_paths([str(bad)])
    assert len(errors_shown) == shown + 1 and win.overlay_layers() == layers
    assert win.globe.frames > 0 and win.last_error() is not None


def test_vector_style_order_and_remove(reused_window, frame_rgb, redraw):
    win = reused_window
    win.files.open_embedded_overlays()  # as embedded_overlays=True opens them
    panel = win.layer_panel.overlays
    borders = panel.find(BORDERS)
    panel.select(borders)
    panel.set_color(borders, QColor(0, 255, 255))
    assert borders.color[:3] == (0.0, 1.0, 1.0)
    panel.width_spin.setValue(3.0)
    assert borders.width_px == 3.0
    redraw(win)
    rgb = frame_rgb(win).astype(int)
    assert border_pixels(rgb) == 0
    cyan = ((rgb[..., 0] < 90) & (rgb[..., 1] > 200) & (rgb[..., 2] > 200)).sum()
    assert cyan > 50
    # Move the borders below the imagery: the session order follows, style and state kept.
    panel.select(borders)
    panel.move_selected(+1)
    assert [ly.name for ly in win.overlay_layers()] == [BORDERS, BLUE_MARBLE]
    assert panel.names() == [BLUE_MARBLE, BORDERS]
    assert not panel.find(BLUE_MARBLE).layer.visible and borders.width_px == 3.0
    redraw(win)
    assert ((frame_rgb(win)[..., 1] > 200) & (frame_rgb(win)[..., 0] < 90)).sum() > 50
    panel.select(borders)
    panel.remove_selected()
    assert panel.names() == [BLUE_MARBLE] and win.overlay_layers() == [panel.find(BLUE_MARBLE)]
    redraw(win)  # the GPU twin of a removed layer is released at the next frame
    assert win.globe.scene.renderer.overlays.vectors == []


def test_drop_decides_by_content(tmp_path):
    from globeview.errors import GlobeviewError
    from globeview.ui.file_opening import classify_path

    data = ROOT / "data"
    assert classify_path(data / "bluemarble_2048x1024.tif") == "overlay"  # RGB imagery
    assert classify_path(data / "craterlake-imagery-30m.tif") == "overlay"  # RGBA
    assert classify_path(data / "ne_cities.geojson") == "overlay"
    assert classify_path(data / "etopo20.tif") == "dem"  # single-band numeric
    assert classify_path(data / "N44W072.hgt") == "dem"
    assert classify_path(tmp_path) == "dem"  # a folder: a tile store
    junk = tmp_path / "notes.txt"
    junk.write_text("hello", encoding="utf-8")
    with pytest.raises(GlobeviewError):
        classify_path(junk)
