"""The host's checks and conversions of drawables (no GL): garbage is named in one line,
hostile sizes are bounded, an in-memory drape samples where its pixels lie."""

from __future__ import annotations

import re

import numpy as np
import pytest

from globeview.model.drawables import Lines, Points, RasterDrape, RasterFile
from globeview.model.overlay_layers import (
    MAX_LINE_VERTICES,
    ArrayImagery,
    drawables_problem,
    host_layer,
    vector_layer,
)
from globeview.terrain.imagery import texel_grid

LINE = np.array([[0.0, 0.0], [10.0, 10.0]])


@pytest.mark.parametrize(
    ("drawable", "needle"),
    [
        (Lines(np.array([[0.0, 0.0]])), "not (N >= 2, 2)"),
        (Lines(np.array([[0.0, 0.0], [0.0, 95.0]])), "outside lon"),
        (Lines(LINE, color=(1.0, "x", 0.0)), "color"),
        (Lines(LINE, width_px=float("inf")), "width_px"),
        (Lines(LINE, segment_m=0.0), "segment_m"),
        (Lines([]), "without a path"),
        (Points([0.0, 1.0], [0.0]), "2 lon and 1 lat"),
        (Points([0.0], [0.0], ["a", "b"]), "2 labels for 1 points"),
        (Points([0.0], [0.0], [3]), "not strings"),
        (Points([0.0], [0.0], kind="sphere"), "kind 'sphere'"),
        (Points(np.arange(3000.0) % 90, np.zeros(3000), [str(i) for i in range(3000)]), "3000"),
        (RasterDrape(np.zeros((2, 2, 4), np.float32), (0, 0, 1, 1)), "uint8"),
        (RasterDrape(np.zeros((2, 2, 2), np.uint8), (0, 0, 1, 1)), "(H, W, 3 or 4)"),
        (RasterDrape(np.zeros((2, 2, 4), np.uint8), (1, 0, 0, 1)), "west < east"),
        (RasterDrape(np.zeros((20000, 1, 4), np.uint8), (0, 0, 1, 1)), "at most 16384"),
        (RasterFile(42), "RasterFile path of int"),
        (object(), "not a drawable"),
    ],
)
def test_garbage_is_named_in_one_line(drawable, needle) -> None:
    problem = drawables_problem([drawable])
    assert problem is not None and needle in problem and "\n" not in problem


def test_layer_objects_and_junk_results() -> None:
    class Old:
        def attach(self, renderer): ...

        def detach(self, renderer): ...

    old = Old()
    assert host_layer(old, "x") == (old, None)
    layer, problem = host_layer(42, "x")
    assert layer is None and problem == "open() returned int, not a layer or drawables"
    layer, problem = host_layer([Lines(LINE), Points([1.0], [2.0], ["p"])], "two.xyz")
    assert problem is None and layer.kind == "drawing" and layer.name == "two.xyz"
    assert [p.kind for p in layer.parts] == ["vector", "points"]


@pytest.mark.slow
def test_a_tiny_segment_length_is_coarsened_not_obeyed() -> None:
    """A plugin asking for 1 mm pieces round the equator would ask for 40 billion vertices."""
    ring = np.array([[-180.0, 0.0], [-60.0, 0.0], [60.0, 0.0], [180.0, 0.0]])
    layer = vector_layer(Lines(ring, segment_m=0.001), "ring")
    assert 1_000_000 < len(layer.lines.lon) <= MAX_LINE_VERTICES + 10
    assert all(len(c.lon) < len(layer.lines.lon) for _, c in layer.coarser)


def test_long_labels_are_cut() -> None:
    layer, _ = host_layer(Points([0.0], [0.0], ["x" * 500]), "p")
    assert len(layer.names[0]) == 64 and layer.names[0].endswith("...")


def test_array_drape_samples_where_its_pixels_lie() -> None:
    """A 2 x 2 image over lon 0..20, lat 0..20: each quadrant's colour at its centre."""
    img = np.zeros((2, 2, 4), np.uint8)
    img[0, 0] = (255, 0, 0, 255)  # north-west
    img[0, 1] = (0, 255, 0, 255)  # north-east
    img[1, 0] = (0, 0, 255, 255)  # south-west
    img[1, 1] = (255, 255, 0, 255)  # south-east
    src = ArrayImagery(img, (0.0, 0.0, 20.0, 20.0), tex_size=64)
    key = (2, 4, 1)  # the level-2 tile covering lon 0..45, lat 0..45
    rgba = src.tile_rgba(key)
    tr, _ = texel_grid(key, 64)

    def at(lon: float, lat: float) -> np.ndarray:
        col = int((lon - tr.c) / tr.a)
        row = int((lat - tr.f) / tr.e)
        return rgba[row, col]

    assert tuple(at(3.0, 17.0)) == (255, 0, 0, 255)
    assert tuple(at(17.0, 17.0)) == (0, 255, 0, 255)
    assert tuple(at(3.0, 3.0)) == (0, 0, 255, 255)
    assert tuple(at(17.0, 3.0)) == (255, 255, 0, 255)
    assert at(30.0, 10.0)[3] == 0 and at(10.0, 30.0)[3] == 0  # outside: transparent
    assert src.tile_rgba((2, 0, 0)) is None  # a tile it does not reach


# -- live style edits (issue #14: refused where set, nothing changes) --------------------------
@pytest.mark.parametrize(
    ("style", "reason"),
    [
        ({"width_px": float("nan")}, "width_px"),
        ({"width_px": "wide"}, "not a number"),
        ({"width_px": 0.0}, "not in (0, 200]"),
        ({"color": (1.0, 0.0)}, "3 or 4"),
        ({"color": (1.0, float("inf"), 0.0)}, "finite"),
        ({"color": "red"}, "color"),
        ({"dash_px": -3.0}, "dash_px"),
        ({"lines": None}, "no style 'lines'"),
        ({"color": (0.0, 1.0, 1.0), "width_px": -1.0}, "width_px"),
    ],
)
def test_bad_live_style_is_refused_and_changes_nothing(style, reason) -> None:
    from globeview.model.overlay_layers import vector_layer

    layer = vector_layer(Lines([[(0.0, 0.0), (10.0, 10.0)]], color=(1, 1, 0)), "lines")
    before = (layer.color, layer.width_px, layer.dash_px, layer.style_version)
    with pytest.raises(ValueError, match=re.escape(reason)) as info:
        layer.set_style(**style)
    assert "\n" not in str(info.value)
    assert (layer.color, layer.width_px, layer.dash_px, layer.style_version) == before


def test_good_live_style_is_normalised_and_counted() -> None:
    from globeview.model.overlay_layers import build_layer

    drawing = build_layer(
        [Lines([[(0.0, 0.0), (10.0, 10.0)]]), Points([1.0], [2.0], labels=["a"])], "both"
    )
    with pytest.raises(ValueError, match="size_px"):
        drawing.set_style(color=(0, 1, 1), size_px=float("nan"))
    assert [p.style_version for p in drawing.parts] == [0, 0]  # nothing changed
    drawing.set_style(color=(0, 1, 1), size_px=12)
    lines, points = drawing.parts
    assert lines.color == points.color == (0.0, 1.0, 1.0, 1.0)
    assert points.size_px == 12.0 and (lines.style_version, points.style_version) == (1, 1)
