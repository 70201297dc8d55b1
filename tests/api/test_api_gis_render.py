"""GIS vector files drawn headless (issue #26 item 3): a GeoPackage (two layers, UTM 19N),
a Shapefile (NAD83 / UTM 19N), a KML, a GPX track and a FlatGeobuf (web Mercator), all
written by GDAL, opened through `Globe.add_overlay` / `Globe.add_vectors` and the CLI's
``render --layer``: the cross they hold is drawn where it is over the White Mountains (real
EGL, the real SRTM DEM), looking straight down at its centre."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zygote
from PIL import Image

from globeview.errors import GlobeviewError

from .gis_samples import COLUMN_LON, ROW_LAT, write_cross, write_gpkg, write_gpx

pytestmark = pytest.mark.gl
SIZE = (240, 240)
#: Straight down over the cross's centre: its east-west line is the middle row, its
#: north-south line the middle column (north up); 40 km up, the cross spans most of the view.
HEIGHT_M = 40_000.0
MAGENTA = (1.0, 0.0, 1.0, 1.0)


def magenta(rgb: np.ndarray) -> np.ndarray:
    r, g, b = (rgb[..., k].astype(int) for k in range(3))
    return (r > 180) & (g < 90) & (b > 180)


def bands(mask: np.ndarray, half: int = 6) -> tuple[int, int, int]:
    """Magenta pixels in the middle row band, the middle column band, and elsewhere."""
    h, w = mask.shape
    rows = np.abs(np.arange(h) - h / 2)[:, None] <= half
    cols = np.abs(np.arange(w) - w / 2)[None, :] <= half
    return int((mask & rows).sum()), int((mask & cols).sum()), int((mask & ~rows & ~cols).sum())


@pytest.fixture
def down(wm_globe):
    """The module's globe looking straight down at the cross; overlays removed after."""
    before = wm_globe.camera
    wm_globe.fly_to(COLUMN_LON, ROW_LAT, HEIGHT_M, heading=0.0, pitch=-90.0)
    yield wm_globe
    for layer in wm_globe.overlays:
        wm_globe.remove_overlay(layer)
    wm_globe.camera = before


def _cross_drawn(globe, expect_row: bool = True, expect_column: bool = True) -> None:
    row, col, elsewhere = bands(magenta(globe.render(SIZE)))
    if expect_row:
        assert row > 150, f"the east-west line should cross the view ({row} px)"
    if expect_column:
        assert col > 150, f"the north-south line should cross the view ({col} px)"
    assert elsewhere < 0.05 * max(row, col, 1), f"lines drawn off the cross ({elsewhere} px)"
    if not expect_row:
        assert row < 40  # only where the column crosses the row band
    if not expect_column:
        assert col < 40


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "driver", "epsg"),
    [
        ("cross.shp", "ESRI Shapefile", 26919),
        ("cross.kml", "KML", 4326),
        ("cross.fgb", "FlatGeobuf", 3857),
    ],
)
def test_formats_draw_the_cross_where_it_is(down, tmp_path, name, driver, epsg):
    assert bands(magenta(down.render(SIZE)))[:2] == (0, 0)  # nothing magenta without it
    path = write_cross(tmp_path / name, driver, epsg)
    layer = down.add_overlay(path, color=MAGENTA, width_px=3.0)  # dispatch by extension
    assert layer.name == name
    _cross_drawn(down)


@pytest.mark.slow
def test_gpx_track_draws(down, tmp_path):
    down.add_overlay(write_gpx(tmp_path / "cross.gpx"), color=MAGENTA, width_px=3.0)
    _cross_drawn(down)


@pytest.mark.slow
def test_geopackage_layers_by_name_in_utm(down, tmp_path, monkeypatch):
    path = write_gpkg(tmp_path / "wm.gpkg")
    roads = down.add_vectors(path, color=MAGENTA, width_px=3.0)  # the first layer: roads
    _cross_drawn(down, expect_column=False)
    down.remove_overlay(roads)
    monkeypatch.chdir(tmp_path)  # FILE::LAYER with a relative FILE, as the README writes it
    trails = down.add_overlay("wm.gpkg::trails", color=MAGENTA, width_px=3.0)
    assert trails.name == "wm.gpkg::trails"
    _cross_drawn(down, expect_row=False)


@pytest.mark.slow
def test_colour_by_field_draws_each_class_in_its_colour(down, tmp_path):
    path = write_cross(tmp_path / "cross.fgb", "FlatGeobuf", 32619)
    layer = down.add_vectors(path, color_by="kind", width_px=3.0)
    assert [(e.label, e.color[:3]) for e in layer.legend] == [
        ("road", (0.12, 0.47, 0.71)),
        ("trail", (1.0, 0.5, 0.05)),
    ]
    rgb = down.render(SIZE)[..., :3].astype(int)
    orange = (rgb[..., 0] > 200) & (rgb[..., 1] > 90) & (rgb[..., 1] < 160) & (rgb[..., 2] < 60)
    blue = (rgb[..., 0] < 80) & (rgb[..., 1] > 90) & (rgb[..., 1] < 150) & (rgb[..., 2] > 150)
    # The road (east-west) is blue along the middle row; the trail orange down the middle.
    assert bands(blue)[0] > 150 and bands(blue)[1] < 40
    assert bands(orange)[1] > 150 and bands(orange)[0] < 40


def test_bad_layer_name_and_style_are_one_line_and_change_nothing(down, tmp_path):
    path = write_gpkg(tmp_path / "wm.gpkg")
    with pytest.raises(
        GlobeviewError, match=r"^wm.gpkg: no layer 'rivers' \(layers: roads, trails\)$"
    ):
        down.add_overlay(f"{path}::rivers")
    with pytest.raises(GlobeviewError, match=r"^no vector style 'dash'"):
        down.add_vectors(path, dash=3)
    assert down.overlays == []


# -- the command line ------------------------------------------------------------------------
GLOBEVIEW = Path(sys.executable).parent / "globeview"
HGT = Path(__file__).resolve().parents[2] / "data" / "N44W072.hgt"


def _render(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "GLOBEVIEW_CONFIG_DIR": str(tmp_path / "config")}
    env.pop("GLOBEVIEW_DEBUG", None)
    camera = f"{COLUMN_LON},{ROW_LAT},{HEIGHT_M},0,-90"
    cmd = [str(GLOBEVIEW), "render", str(HGT), "--size", "240x240", "--camera", camera]
    # A process of its own (exit status, stderr as the user sees it), forked from `zygote`'s
    # server: without the interpreter start and imports (~1.3 CPU-s a command).
    return zygote.run(
        [*cmd, "--no-borders", *args], capture_output=True, text=True, env=env, timeout=600
    )


@pytest.mark.slow
def test_cli_renders_a_geopackage_layer_and_refuses_a_crs_less_projected_file(tmp_path):
    path = write_gpkg(tmp_path / "wm.gpkg")
    out = tmp_path / "trails.png"
    proc = _render(tmp_path, "--out", str(out), "--layer", f"{path}::trails")
    assert proc.returncode == 0, proc.stderr
    mask = (np.asarray(Image.open(out).convert("RGB")).astype(int)[..., 2] < 100) & (
        np.asarray(Image.open(out).convert("RGB")).astype(int)[..., 0] > 200
    )  # the default yellow lines
    row, col, elsewhere = bands(mask)
    assert col > 150 and row < 40 and elsewhere < 0.05 * col
    # The roads layer: the broken geometry is one warning line, the picture is written.
    out2 = tmp_path / "roads.png"
    proc = _render(tmp_path, "--out", str(out2), "--layer", str(path))
    assert proc.returncode == 0 and out2.exists(), proc.stderr
    assert proc.stderr.splitlines()[0] == (
        "globeview: warning: wm.gpkg: 1 features with broken geometry skipped (1 drawn)"
    )
    # A file without a CRS in metres: one line, exit 2, nothing written.
    from pyogrio.raw import write

    from .gis_samples import east_west, line_wkb, projected

    bad = tmp_path / "metres.fgb"
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        write(
            str(bad),
            np.array([line_wkb(projected(east_west(), 32619))], dtype=object),
            [np.array(["x"], dtype=object)],
            ["name"],
            geometry_type="LineString",
            driver="FlatGeobuf",
        )
    out3 = tmp_path / "bad.png"
    proc = _render(tmp_path, "--out", str(out3), "--layer", str(bad))
    assert proc.returncode == 2 and not out3.exists()
    assert proc.stderr.strip().splitlines() == [
        "globeview: error: metres.fgb: no CRS, and the coordinates are not lon/lat degrees "
        "(give the file its CRS, e.g. a .prj beside a Shapefile)"
    ]


@pytest.mark.slow
def test_a_dense_layer_draws_far_segments_from_coarse_levels(wm_globe, tmp_path):
    """100 000 vertices 15 m apart on the 9 km oblique view: the near part from the finest
    level, the far part from thinned ones (distance bands), so far fewer segments are drawn
    than the layer has, and lines show both near and far."""
    from pyogrio.raw import write

    rng = np.random.default_rng(5)
    lines, per = 200, 500
    start = rng.uniform([-71.6, 44.0], [-71.0, 44.5], (lines, 2))
    walks = start[:, None, :] + rng.normal(0.0, 1.5e-4, (lines, per, 2)).cumsum(axis=1)
    from .gis_samples import line_wkb

    path = tmp_path / "walks.fgb"
    write(
        str(path),
        np.array([line_wkb(w) for w in walks], dtype=object),
        [np.arange(lines, dtype=np.float64)],
        ["id"],
        crs="EPSG:4326",
        geometry_type="LineString",
        driver="FlatGeobuf",
    )
    before = wm_globe.camera
    try:
        wm_globe.fly_to(-71.3, 44.0, 9000.0, heading=0.0, pitch=-30.0)
        layer = wm_globe.add_vectors(path, color=MAGENTA, width_px=2.0)
        rgb = wm_globe.render((320, 200))
        drawn = wm_globe.session.last.stats.extra["vector_segments"]
        # 5 462 of 99 800 here (one level for the whole view, from the eye's height: 19 139).
        assert 0 < drawn < 0.1 * lines * (per - 1), drawn
        mask = magenta(rgb)
        assert mask[130:].sum() > 50 and mask[60:100].sum() > 50  # near and far
        wm_globe.remove_overlay(layer)
    finally:
        wm_globe.camera = before
