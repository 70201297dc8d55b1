"""GIS vector files in the window (issue #26 item 3): a GeoPackage of two layers written by
GDAL (UTM 19N) opened as File > Open Overlay… does, its layer chosen in the dialog, drawn over
the White Mountains where the file says; coloured by a field, the Layers dock shows the
legend and its width spin box sets the lines' width. A real window under a display."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from pyogrio.raw import write
from pyproj import Transformer

from globeview.model.camera import Camera

pytestmark = pytest.mark.gui

#: Straight down over the cross's centre (lon, lat, height m).
VIEW = (-71.30, 44.27, 4.0e4)


def _line(lonlat: np.ndarray) -> bytes:
    x, y = Transformer.from_crs(4326, 32619, always_xy=True).transform(lonlat[:, 0], lonlat[:, 1])
    return struct.pack("<BII", 1, 2, len(x)) + np.c_[x, y].astype("<f8").tobytes()


def _gpkg(path) -> str:
    """roads: the east-west line along 44.27 N in two halves ("highway" west, "road" east);
    trails: north-south along 71.30 W ("trail"), in field ``kind``."""
    n = 40
    west = np.c_[np.linspace(-71.5, -71.3, n), np.full(n, 44.27)]
    east = np.c_[np.linspace(-71.3, -71.1, n), np.full(n, 44.27)]
    ns = np.c_[np.full(n, -71.30), np.linspace(44.12, 44.42, n)]
    layers = (("roads", [west, east], ["highway", "road"]), ("trails", [ns], ["trail"]))
    for i, (layer, lines, kinds) in enumerate(layers):
        write(
            str(path),
            np.array([_line(xy) for xy in lines], dtype=object),
            [np.array(kinds, dtype=object)],
            ["kind"],
            layer=layer,
            crs="EPSG:32619",
            geometry_type="LineString",
            driver="GPKG",
            append=i > 0,
        )
    return str(path)


def _yellow(rgb: np.ndarray) -> np.ndarray:
    r, g, b = (rgb[..., k].astype(int) for k in range(3))
    return (r > 200) & (g > 170) & (b < 110)


def _bands(mask: np.ndarray, half: int = 8) -> tuple[int, int]:
    h, w = mask.shape
    rows = np.abs(np.arange(h) - h / 2)[:, None] <= half
    cols = np.abs(np.arange(w) - w / 2)[None, :] <= half
    return int((mask & rows & ~cols).sum()), int((mask & cols & ~rows).sum())


def test_geopackage_layer_chosen_in_the_dialog_is_drawn(
    reused_window_at, frame_rgb, wait_frame, tmp_path
):
    path = _gpkg(tmp_path / "wm.gpkg")
    win = reused_window_at(Camera.from_lonlat(*VIEW))
    asked = []

    def ask(parent, name, layers):
        asked.append((name, layers))
        return "trails"

    win.files.ask_layer = ask
    added = win.files.open_overlays([path])
    assert asked == [("wm.gpkg", [("roads", "LineString"), ("trails", "LineString")])]
    assert [ly.name for ly in added] == ["wm.gpkg::trails"]
    assert win.layer_panel.overlays.names() == ["wm.gpkg::trails"]
    wait_frame(win)
    row, col = _bands(_yellow(frame_rgb(win)))
    assert col > 100 and row < 10, f"the trail runs north-south through the middle ({row}, {col})"
    # Cancelling the dialog opens nothing.
    win.files.ask_layer = lambda *_: None
    assert win.files.open_overlays([path]) == []
    assert win.layer_panel.overlays.names() == ["wm.gpkg::trails"]


def test_colour_by_field_legend_and_width_in_the_layers_dock(reused_window_at, tmp_path):
    path = _gpkg(tmp_path / "wm.gpkg")
    win = reused_window_at(Camera.from_lonlat(*VIEW))
    # The model is the window's: what the API adds (FILE::LAYER, colour by a field) is listed.
    layer = win.files.overlay_host.open(f"{path}::roads", "gis", color_by="kind")
    panel = win.layer_panel.overlays
    panel.select(layer)
    assert layer.kind == "drawing" and [e.label for e in layer.legend] == ["highway", "road"]
    assert panel.legend_label.isVisibleTo(panel)
    text = panel.legend_label.text()
    assert text.count("&#9632;") == 2 and text.index("highway") < text.index("road")
    assert panel.width_spin.isVisibleTo(panel) and not panel.color_button.isVisibleTo(panel)
    panel.width_spin.setValue(4.0)
    assert [p.width_px for p in layer.parts] == [4.0, 4.0]
    # A layer without classes shows no legend.
    plain = win.files.overlay_host.open(f"{path}::trails")
    panel.select(plain)
    assert not panel.legend_label.isVisibleTo(panel) and panel.color_button.isVisibleTo(panel)


def test_colour_by_and_label_chosen_in_the_dock_reopen_the_layer_in_its_row(
    reused_window_at, tmp_path
):
    path = _gpkg(tmp_path / "wm.gpkg")
    win = reused_window_at(Camera.from_lonlat(*VIEW))
    host = win.files.overlay_host
    below = host.open(f"{path}::trails")
    roads = host.open(f"{path}::roads")
    above = host.open(f"{path}::trails", name="top")
    panel = win.layer_panel.overlays
    panel.select(roads)
    combo = panel.color_by_combo
    assert combo.isVisibleTo(panel) and panel.label_combo.isVisibleTo(panel)
    assert [combo.itemText(i) for i in range(combo.count())] == ["(none)", "kind"]
    assert not panel.legend_label.isVisibleTo(panel)
    roads.set_visible(False)
    # As a user picks "kind" in the combo box.
    combo.setCurrentIndex(1)
    combo.activated.emit(1)
    new = panel.selected_layer()
    assert new is not roads and [e.label for e in new.legend] == ["highway", "road"]
    assert win.overlay_layers() == [below, new, above]  # the same row
    assert not new.visible  # its visibility kept
    assert panel.legend_label.isVisibleTo(panel) and panel.color_by_combo.currentText() == "kind"
    labelled = panel.set_field(new, "label", "kind")
    assert sorted(p.kind for p in labelled.parts) == ["points", "vector", "vector"]
    assert panel.label_combo.currentText() == "kind"
    plain = panel.set_field(labelled, "color_by", "(none)")
    assert plain.legend == [] and win.overlay_layers() == [below, plain, above]
    # A GeoJSON layer (the built-in vector type, not read through OGR) has no field choices.
    geojson = tmp_path / "line.geojson"
    geojson.write_text('{"type": "LineString", "coordinates": [[-71.4, 44.2], [-71.2, 44.3]]}')
    panel.select(host.open(str(geojson)))
    assert not panel.color_by_combo.isVisibleTo(panel)
