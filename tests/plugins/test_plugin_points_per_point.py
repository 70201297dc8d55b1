"""`Points` with a size and a colour per point (plugin API 1.2, issue #29 item 11): a layer
plugin hands arrays of length N, the host checks them (garbage fails the layer type in one
line) and draws each point in its own size and colour, placemarks and 3-D objects alike.
A restyle from the overlay panel gives the whole layer one value again.

Real GL (EGL), a real plugin distribution on sys.path; oracle: where the points project
(`view.project`) and the colours and sizes the plugin asked for.
"""

from __future__ import annotations

import numpy as np
import pytest

from globeview.app.testing import PluginSite
from globeview.errors import GlobeviewError
from globeview.geodesy import lonlat_to_ecef
from globeview.model.camera import Camera
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings

pytestmark = pytest.mark.gl
SIZE = (480, 360)

MANIFEST = """
    name = "gvt-dots"
    version = "0.1.0"
    description = "points with a size and colour each"
    kinds = ["layer"]
    api_version = "1.2"

    [[contributions]]
    name = "gvt-dots"
    kind = "layer"
    target = "gvt_dots.impl:Dots"
    extensions = [".dots"]
    """

#: A .dots file: a first line "placemark|box|cone", then "LON LAT SIZE R G B" per point; a
#: first line "bad-colours" / "bad-sizes" / "nan-sizes" gives garbage instead.
IMPL = """
    import numpy as np

    from globeview.plugins.api import LayerType, Points


    class Dots(LayerType):
        extensions = (".dots",)

        def open(self, path):
            lines = open(path, encoding="utf-8").read().split("\\n")
            kind = lines[0].strip()
            rows = np.array([[float(v) for v in ln.split()] for ln in lines[1:] if ln.strip()])
            lon, lat, size, rgb = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3:6]
            if kind == "bad-colours":
                return Points(lon, lat, color=rgb[:1])
            if kind == "bad-sizes":
                return Points(lon, lat, size_px=size[:1])
            if kind == "nan-sizes":
                return Points(lon, lat, size_px=np.full(len(lon), np.nan))
            if kind == "placemark":
                return Points(lon, lat, size_px=size, color=rgb)
            return Points(lon, lat, kind=kind, scale_m=size, color=np.c_[rgb, np.ones(len(lon))])
    """


@pytest.fixture(scope="module")
def gl(globeview_gl, globeview_terrain):
    from globeview.render.offscreen import OffscreenTarget

    target = OffscreenTarget(globeview_gl, SIZE)
    yield globeview_gl, globeview_terrain, target
    target.release()


@pytest.fixture
def session(gl, plugin_site: PluginSite):
    from globeview.app.session import GlobeSession

    plugin_site.add("gvt_dots", MANIFEST, {"impl": IMPL})
    ctx, terrain, target = gl
    reg = PluginRegistry(MemorySettings()).discover()
    s = GlobeSession(ctx, terrain, Camera.from_lonlat(0.0, 10.0, 1.2e7), registry=reg)
    s.settings.fog = False
    s.target = target
    yield s
    s.release_gl()


def _render(s):
    s.render(s.target.fbo, SIZE)
    result = s.render(s.target.fbo, SIZE)
    return s.target.read_rgb().astype(int), result.view


def _at(view, lon: float, lat: float) -> tuple[int, int]:
    """(row, col) of the pixel showing (lon, lat) on the ellipsoid."""
    p = np.asarray(lonlat_to_ecef(lon, lat, 0.0), np.float64).reshape(1, 3)
    x, y, _ = view.project(p)[0]
    return round(float(y)), round(float(x))


def _count(mask: np.ndarray, view, lon: float, lat: float, r: int = 40) -> int:
    row, col = _at(view, lon, lat)
    return int(mask[max(row - r, 0) : row + r + 1, max(col - r, 0) : col + r + 1].sum())


def _red(rgb):
    return (rgb[..., 0] > 200) & (rgb[..., 1] < 60) & (rgb[..., 2] < 60)


def _blue(rgb):
    return (rgb[..., 2] > 200) & (rgb[..., 0] < 60) & (rgb[..., 1] < 60)


@pytest.mark.slow
def test_placemarks_in_their_own_size_and_colour(session, tmp_path) -> None:
    f = tmp_path / "two.dots"
    f.write_text("placemark\n-25 10 8 1 0 0\n25 10 30 0 0 1\n")
    layer = session.add_overlay(str(f))
    rgb, view = _render(session)
    red, blue = _red(rgb), _blue(rgb)
    small_red, big_blue = _count(red, view, -25, 10), _count(blue, view, 25, 10)
    assert small_red > 5 and big_blue > 5
    assert _count(blue, view, -25, 10) == 0 and _count(red, view, 25, 10) == 0
    # Disc areas go with the square of the size: 30 px against 8 px.
    assert big_blue > 6 * small_red
    # A restyle from the overlay panel: one colour and one size for the whole layer again.
    assert layer.set_style(color=(1.0, 0.0, 0.0, 1.0), size_px=16.0)
    rgb, view = _render(session)
    red = _red(rgb)
    assert not _blue(rgb).any()
    left, right = _count(red, view, -25, 10), _count(red, view, 25, 10)
    assert left > 5 and abs(left - right) <= 0.2 * max(left, right)


@pytest.mark.slow
def test_boxes_in_their_own_colour_and_scale(session, tmp_path) -> None:
    f = tmp_path / "boxes.dots"
    f.write_text("box\n-25 10 400000 0 1 0\n25 10 150000 1 1 0\n")
    session.add_overlay(str(f))
    rgb, view = _render(session)
    green = (rgb[..., 1] > 100) & (rgb[..., 0] < 40) & (rgb[..., 2] < 40)
    yellow = (rgb[..., 0] > 100) & (rgb[..., 1] > 100) & (rgb[..., 2] < 40)
    big_green, small_yellow = _count(green, view, -25, 10, 60), _count(yellow, view, 25, 10, 60)
    assert small_yellow > 3 and big_green > 3 * small_yellow
    assert _count(yellow, view, -25, 10, 60) == 0 and _count(green, view, 25, 10, 60) == 0


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "needle"),
    [
        ("bad-colours", "Points color of 1 rows for 2 points"),
        ("bad-sizes", "Points size_px of 1 values for 2 points"),
        ("nan-sizes", "Points size_px values not in (0, 500]"),
    ],
)
def test_per_point_garbage_fails_the_layer_type_in_one_line(session, tmp_path, kind, needle):
    f = tmp_path / "bad.dots"
    f.write_text(f"{kind}\n-25 10 8 1 0 0\n25 10 30 0 0 1\n")
    with pytest.raises(GlobeviewError) as info:
        session.add_overlay(str(f))
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("layer type gvt-dots could not open bad.dots")
    assert needle in msg
    assert session.overlay_layers == [] and session.registry.get("gvt-dots").status == "failed"
