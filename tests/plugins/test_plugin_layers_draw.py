"""A layer plugin returns data, the host draws it (issue #15 item 2): an external plugin (a
real distribution on sys.path) opens its own file format and returns drawable primitives —
rhumb and geodesic `Lines`, labelled `Points`, a `RasterDrape` — and a headless render shows
them where they lie. Garbage drawables fail only that layer type, in one line."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Geod

from globeview.app.testing import PluginSite
from globeview.errors import GlobeviewError
from globeview.geodesy import lonlat_to_ecef
from globeview.model.camera import Camera
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings

pytestmark = pytest.mark.gl
SIZE = (480, 360)
GEOD = Geod(ellps="WGS84")

STRIPES_MANIFEST = """
    name = "stripes"
    version = "0.1.0"
    description = "draws what a .stripes file lists"
    kinds = ["layer"]
    api_version = "1.0"

    [[contributions]]
    name = "stripes"
    kind = "layer"
    target = "gvt_stripes.impl:StripesType"
    label = "Stripes"
    extensions = [".stripes"]
    """

#: A .stripes file: "rhumb|geodesic LON1 LAT1 LON2 LAT2 R G B", "point LON LAT LABEL",
#: "drape W S E N R G B", "garbage" (returns something that is not a drawable).
STRIPES_IMPL = """
    from pathlib import Path

    import numpy as np

    from globeview.plugins.api import GlobeviewError, Lines, Points, RasterDrape

    class Stripes:
        def __init__(self, items, name):
            self.items = items
            self.name = name

        def drawables(self):
            return self.items

    class Legacy:
        # The API 1.0 contract: an object with attach/detach (and a broken set_visible).

        name = "old style"
        attached = 0

        def attach(self, renderer):
            Legacy.attached += 1

        def detach(self, renderer):
            Legacy.attached -= 1

        def set_visible(self, renderer, visible):
            raise RuntimeError("nope")

    class Weird:
        def __getattr__(self, name):
            raise RuntimeError("boom")

    class StripesType:
        name = "stripes"
        label = "Stripes"
        extensions = (".stripes",)

        def __init__(self, context=None):
            self.context = context

        def open(self, path):
            items = []
            for n, line in enumerate(Path(path).read_text().splitlines(), 1):
                w = line.split()
                if not w:
                    continue
                if w[0] in ("rhumb", "geodesic"):
                    x1, y1, x2, y2, r, g, b = (float(v) for v in w[1:8])
                    items.append(Lines(np.array([[x1, y1], [x2, y2]]), interpolation=w[0],
                                       color=(r, g, b, 1.0), width_px=3.0))
                elif w[0] == "point":
                    items.append(Points([float(w[1])], [float(w[2])], [w[3]], size_px=12.0))
                elif w[0] == "drape":
                    west, south, east, north, r, g, b = (float(v) for v in w[1:8])
                    img = np.zeros((4, 8, 4), np.uint8)
                    img[...] = (r, g, b, 255)
                    items.append(RasterDrape(img, (west, south, east, north)))
                elif w[0] == "nan":
                    items.append(Lines(np.array([[0.0, 0.0], [np.nan, 1.0]])))
                elif w[0] == "evil":
                    class Evil(Lines):
                        def __getattribute__(self, name):
                            if name == "color":
                                raise RuntimeError("gotcha")
                            return object.__getattribute__(self, name)
                    items.append(Evil(np.array([[0.0, 0.0], [1.0, 1.0]])))
                elif w[0] == "legacy":
                    return Legacy()
                elif w[0] == "weird":
                    return Weird()
                elif w[0] == "garbage":
                    items.append("a string is not a drawable")
                elif w[0] == "interp":
                    items.append(Lines(np.array([[0.0, 0.0], [1.0, 1.0]]), interpolation="spline"))
                else:
                    raise GlobeviewError(f"{Path(path).name}:{n}: unknown item {w[0]!r}")
            return Stripes(items, "my stripes")
    """


@pytest.fixture(scope="module")
def gl(globeview_gl, globeview_terrain):
    """The plugin test fixtures' GL context and embedded terrain, and a target."""
    from globeview.render.offscreen import OffscreenTarget

    target = OffscreenTarget(globeview_gl, SIZE)
    yield globeview_gl, globeview_terrain, target
    target.release()


@pytest.fixture
def session(gl, plugin_site: PluginSite):
    from globeview.app.session import GlobeSession

    plugin_site.add("gvt_stripes", STRIPES_MANIFEST, {"impl": STRIPES_IMPL})
    ctx, terrain, target = gl
    reg = PluginRegistry(MemorySettings()).discover()
    s = GlobeSession(ctx, terrain, Camera.from_lonlat(0.0, 20.0, 1.2e7), registry=reg)
    s.settings.fog = False
    s.target = target
    yield s
    s.release_gl()


def _render(s):
    s.render(s.target.fbo, SIZE)
    result = s.render(s.target.fbo, SIZE)
    return s.target.read_rgb(), result.view


def _pixel(view, lon: float, lat: float) -> tuple[int, int]:
    """(row, col) of the pixel showing (lon, lat) on the ellipsoid."""
    p = np.asarray(lonlat_to_ecef(lon, lat, 0.0), np.float64).reshape(3)
    c = view.rotation @ (p - np.asarray(view.eye, np.float64))
    w, h = view.viewport
    t = np.tan(np.radians(view.fovy_deg) / 2.0)
    x = c[0] / -c[2] / (t * w / h)
    y = c[1] / -c[2] / t
    return round(float((1 - y) / 2 * h - 0.5)), round(float((x + 1) / 2 * w - 0.5))


def _near(mask: np.ndarray, view, lon: float, lat: float, r: int = 2) -> bool:
    row, col = _pixel(view, lon, lat)
    return bool(mask[max(row - r, 0) : row + r + 1, max(col - r, 0) : col + r + 1].any())


@pytest.mark.slow
def test_external_plugin_drawables_land_where_they_lie(session, tmp_path) -> None:
    f = tmp_path / "world.stripes"
    f.write_text(
        "rhumb -40 30 40 30 1 0 1\n"  # magenta along the parallel 30 N
        "geodesic -40 10 40 10 0 1 1\n"  # cyan along the geodesic (bulges north)
        "drape -20 -15 -5 -5 0 255 0\n"  # a green box
        "point 20 -10 HELLO\n"
    )
    layer = session.add_overlay(str(f))
    assert layer.name == "my stripes" and layer.kind == "drawing"
    assert session.overlay_layers == [layer]
    rgb, view = _render(session)
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    magenta = (r > 200) & (g < 80) & (b > 200)
    cyan = (r < 80) & (g > 200) & (b > 200)
    # Rhumb: the line follows the parallel all along, though the plugin gave only its ends.
    lons = np.arange(-35.0, 36.0, 5.0)
    assert all(_near(magenta, view, lon, 30.0) for lon in lons)
    _, mid_lat_rhumb_geodesic = GEOD.npts(-40, 30, 40, 30, 1)[0]
    assert mid_lat_rhumb_geodesic > 34.0  # where a geodesic would have gone instead
    assert not _near(magenta, view, 0.0, mid_lat_rhumb_geodesic)
    # Geodesic: through the geodesic's vertex, not along the parallel 10 N.
    _, mid_lat = GEOD.npts(-40, 10, 40, 10, 1)[0]
    assert mid_lat > 12.0
    assert _near(cyan, view, 0.0, mid_lat) and not _near(cyan, view, 0.0, 10.0, r=1)
    # The drape: green inside its box, not outside.
    green = (g > r + 60) & (g > b + 60)
    row, col = _pixel(view, -12.5, -10.0)
    assert green[row - 3 : row + 4, col - 3 : col + 4].all()
    row, col = _pixel(view, 5.0, -10.0)
    assert not green[row - 3 : row + 4, col - 3 : col + 4].any()
    # The point's label: white text beside it.
    white = np.all(rgb > 235, axis=-1)
    row, col = _pixel(view, 20.0, -10.0)
    assert white[row - 12 : row + 13, col : col + 60].sum() > 15
    # Toggling the layer hides every part.
    layer.set_visible(False)
    rgb2, _ = _render(session)
    assert not ((rgb2[..., 0] > 200) & (rgb2[..., 1] < 80) & (rgb2[..., 2] > 200)).any()
    session.remove_overlay(layer)
    assert session.overlay_layers == []


@pytest.mark.slow
@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ("garbage\n", "a str, not a drawable"),
        ("nan\n", "NaN or infinite"),
        ("interp\n", "interpolation 'spline'"),
        ("", "an empty list of drawables"),
        ("evil\n", "cannot read (RuntimeError: gotcha)"),
        ("weird\n", "cannot read (RuntimeError: boom)"),
    ],
)
def test_garbage_drawables_fail_the_layer_type_in_one_line(session, tmp_path, content, needle):
    f = tmp_path / "bad.stripes"
    f.write_text(content)
    with pytest.raises(GlobeviewError) as info:
        session.add_overlay(str(f))
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("layer type stripes could not open bad.stripes")
    assert needle in msg
    assert session.overlay_layers == [] and session.renderer.overlays.vectors == []
    assert session.registry.get("stripes").status == "failed"


@pytest.mark.slow
def test_bad_user_file_keeps_the_plugin(session, tmp_path) -> None:
    f = tmp_path / "typo.stripes"
    f.write_text("rhumbb 0 0 1 1 1 1 1\n")
    with pytest.raises(GlobeviewError, match=r"typo\.stripes:1: unknown item 'rhumbb'"):
        session.add_overlay(str(f))
    assert session.registry.get("stripes").status == "ok" and session.overlay_layers == []


@pytest.mark.slow
def test_builtins_go_the_same_path(session) -> None:
    """The embedded borders come through the built-in vector type's drawables."""
    from globeview.model.overlay_layers import VectorLayer

    layers = session.add_embedded_overlays(imagery=False)
    assert [type(ly) for ly in layers] == [VectorLayer]
    assert layers[0].name == "ne_110m_countries.geojson" and layers[0].color[:3] == (
        1.0,
        0.92,
        0.35,
    )


@pytest.mark.slow
def test_an_api_1_0_layer_object_is_called_only_under_isolation(session, tmp_path) -> None:
    f = tmp_path / "old.stripes"
    f.write_text("legacy\n")
    layer = session.add_overlay(str(f))
    assert layer.name == "old style" and layer.kind == "plugin"
    legacy = type(layer.layer_object)
    # Its methods take the GL renderer: the host calls them at frame time only.
    assert legacy.attached == 0 and session.overlay_layers == [layer]
    session.render(session.target.fbo, SIZE)
    assert legacy.attached == 1
    layer.set_visible(False)  # the model's wish; the object is told at the frame
    rec = session.registry.get("stripes")
    assert rec.status == "ok"
    session.render(session.target.fbo, SIZE)  # set_visible raises inside: the type fails
    assert rec.status == "failed" and "RuntimeError: nope" in rec.error
    session.remove_overlay(layer)  # no exception; the failed plugin is not called again
    session.render(session.target.fbo, SIZE)
    assert session.overlay_layers == [] and legacy.attached == 1
