"""File > Open Overlay… in a real window reaches installed layer plugins (issue #15 item 1):
the dialog's filter lists every layer type's patterns, a plugin's own format opens and draws
through its drawables, drag and drop dispatches the same way, and an unknown file reports one
line naming the installed layer types. The plugin is a real distribution on sys.path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.gui

MANIFEST = """
    name = "stripes"
    version = "0.1.0"
    description = "draws rhumb lines a .stripes file lists"
    kinds = ["layer"]
    api_version = "1.0"

    [[contributions]]
    name = "stripes"
    kind = "layer"
    target = "gvt_uistripes.impl:StripesType"
    label = "Stripes"
    extensions = [".stripes"]
    """

IMPL = """
    from pathlib import Path

    import numpy as np

    from globeview.plugins.api import Lines, Points

    class StripesType:
        name = "stripes"
        label = "Stripes"
        extensions = (".stripes",)

        def __init__(self, context=None):
            self.context = context

        def open(self, path):
            paths, points = [], []
            for line in Path(path).read_text().splitlines():
                if line.startswith("point "):  # "point LON LAT": a labelled placemark
                    points.append([float(v) for v in line.split()[1:3]])
                    continue
                lat = float(line)
                paths.append(np.array([[-170.0, lat], [0.0, lat], [170.0, lat]]))
            lines = Lines(paths, interpolation="rhumb", color=(1.0, 0.0, 1.0, 1.0), width_px=4.0)
            if not points:
                return lines
            lon, lat = zip(*points)
            return [lines, Points(lon, lat, [f"P{i}" for i in range(len(lon))])]
    """


def magenta(rgb: np.ndarray) -> int:
    r, g, b = (rgb[..., k].astype(int) for k in range(3))
    return int(((r > 200) & (g < 80) & (b > 200)).sum())


@pytest.fixture
def stripes(plugin_site, tmp_path) -> Path:
    plugin_site.add("gvt_uistripes", MANIFEST, {"impl": IMPL})
    f = tmp_path / "bands.stripes"
    f.write_text("0\n20\n40\n")
    return f


def test_open_overlay_dialog_lists_and_opens_a_plugin_format(
    make_window, stripes, frame_rgb, wait_frame, monkeypatch
) -> None:
    from PyQt6.QtWidgets import QFileDialog

    win = make_window()
    asked = {}

    def fake_dialog(parent, caption, start, name_filter):
        asked["filter"] = name_filter
        return [str(stripes)], name_filter.split(";;")[0]

    monkeypatch.setattr(QFileDialog, "getOpenFileNames", staticmethod(fake_dialog))
    assert magenta(frame_rgb(win)) == 0
    win.files.open_overlay_dialog()
    entries = asked["filter"].split(";;")
    assert "*.stripes" in entries[0] and "*.geojson" in entries[0] and "*.tif" in entries[0]
    assert "Stripes (*.stripes)" in entries and entries[-1] == "All files (*)"
    layers = win.overlay_layers()
    assert [ly.name for ly in layers] == ["bands.stripes"] and layers[0].kind == "vector"
    wait_frame(win)
    assert magenta(frame_rgb(win)) > 200


def test_dropped_plugin_file_opens_as_an_overlay(make_window, stripes, frame_rgb, wait_frame):
    win = make_window()
    win.files.open_paths([str(stripes)])  # the drag-and-drop / command-line path
    assert [ly.name for ly in win.overlay_layers()] == ["bands.stripes"]
    wait_frame(win)
    assert magenta(frame_rgb(win)) > 200


def test_unknown_file_reports_one_line_naming_the_layer_types(
    make_window, stripes, errors_shown, tmp_path
) -> None:
    win = make_window()
    junk = tmp_path / "notes.xyz"
    junk.write_bytes(b"\x00\x01 nothing anyone reads")
    assert win.files.open_overlays([str(junk)]) == []
    text = errors_shown[-1].text
    assert "\n" not in text and "notes.xyz: no layer type opens this file" in text
    assert "stripes (.stripes)" in text and "vector (.geojson .json)" in text
    win.files.open_paths([str(junk)])  # dropped: the same line
    assert "no layer type opens this file" in errors_shown[-1].text
    assert win.overlay_layers() == []


def test_a_drawing_of_several_drawables_is_one_row(make_window, stripes, frame_rgb, wait_frame):
    """Lines and points from one file: one overlay row; unticking it hides both parts."""
    both = stripes.with_name("both.stripes")
    both.write_text("20\npoint 0 0\n")
    win = make_window()
    (layer,) = win.files.open_overlays([str(both)])
    panel = win.layer_panel.overlays
    assert layer.kind == "drawing" and panel.names() == ["both.stripes"]
    wait_frame(win)
    assert magenta(frame_rgb(win)) > 100
    assert win.globe.scene.renderer.overlays.points  # the placemark part is attached
    panel.set_visible(layer, False)
    wait_frame(win)
    assert magenta(frame_rgb(win)) == 0
    assert not any(ov.visible for ov in win.globe.scene.renderer.overlays.points)
    panel.select(layer)
    panel.remove_selected()
    assert win.overlay_layers() == [] and panel.names() == []
    wait_frame(win)  # the GPU twins of a removed layer are released at the next frame
    assert win.globe.scene.renderer.overlays.vectors == []
    assert win.globe.scene.renderer.overlays.points == []
