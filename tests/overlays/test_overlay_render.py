"""Overlays as a person sees them, in headless renders: the imagery drape lands where its
cells are and shows no seams, vector lines stay visible on the LOD terrain whatever the LOD,
and thousands of instanced objects draw (one GL context for the module)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from globeview.geodesy import WGS84, ecef_to_lonlat
from globeview.model.camera import Camera

pytestmark = pytest.mark.gl
SIZE = (320, 240)
#: Where the tests leave the renders a person can look at.
OUT = Path(os.environ.get("GLOBEVIEW_TEST_OUT", tempfile.gettempdir())) / "globeview-overlays"
OUT.mkdir(parents=True, exist_ok=True)


@pytest.fixture(scope="module")
def session(globeview_gl, globeview_terrain):
    # The plugin-author fixtures: one GL context (each test is checked for GL leaks) and
    # the embedded terrain in a temporary cache.
    from globeview.app.session import GlobeSession
    from globeview.render.offscreen import OffscreenTarget

    s = GlobeSession(globeview_gl, globeview_terrain, Camera.from_lonlat(0.0, 20.0, 2.0e7))
    s.settings.fog = False
    s.target = OffscreenTarget(globeview_gl, SIZE)
    yield s
    s.release_gl()
    s.target.release()


@pytest.fixture
def clean(session):
    """The session with no overlays before and after the test."""
    from globeview.terrain.imagery import ImageryStack

    ov = session.renderer.overlays
    yield session
    for layer in list(session.globe.overlays):
        session.remove_overlay(layer)
    ov.sync([])  # release the removed layers' GPU twins now
    ov.set_imagery(ImageryStack())
    for o in (*ov.vectors, *ov.points):
        o.release()
    ov.vectors.clear()
    ov.points.clear()
    session.tau_px = 2.0
    session.set_lod("chunked-sse")


def draw(session, camera: Camera):
    session.camera = camera
    result = session.render(session.target.fbo, SIZE)
    return session.target.read_rgb(), result


def globe_lonlat(view, min_incidence: float = 0.0):
    """Per pixel (row 0 at top): lon, lat (degrees) where the pixel's central ray meets the
    ellipsoid, and a hit mask (float64, independent of the renderer); with ``min_incidence``
    only hits where the ray meets the surface at cos(angle to the normal) >= it."""
    w, h = view.viewport
    xs = (np.arange(w) + 0.5) / w * 2.0 - 1.0
    ys = 1.0 - (np.arange(h) + 0.5) / h * 2.0
    t = np.tan(np.radians(view.fovy_deg) / 2.0)
    nx, ny = np.meshgrid(xs * t * w / h, ys * t)
    d = np.stack([nx, ny, -np.ones_like(nx)], axis=-1) @ view.rotation
    semi = np.array([WGS84.a, WGS84.a, WGS84.b])
    ds, o = d / semi, view.eye / semi
    qa, qb, qc = np.sum(ds * ds, -1), np.sum(ds * o, -1), float(o @ o) - 1.0
    disc = qb * qb - qa * qc
    hit = (disc > 0) & (qb < 0)
    tt = (-qb - np.sqrt(np.maximum(disc, 0))) / qa
    p = view.eye + d * tt[..., None]
    lon, lat, _ = ecef_to_lonlat(p)
    nrm = p / semi**2
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    dn = d / np.linalg.norm(d, axis=-1, keepdims=True)
    hit &= -np.sum(dn * nrm, axis=-1) >= min_incidence
    return np.asarray(lon), np.asarray(lat), hit


def write_raster(path, data: np.ndarray, res: float, colormap=None) -> None:
    bands = data[None] if data.ndim == 2 else data
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=bands.shape[2],
        height=bands.shape[1],
        count=bands.shape[0],
        dtype="uint8",
        crs="EPSG:4326",
        transform=Affine(res, 0, -180, 0, -res, 90),
    ) as ds:
        ds.write(bands)
        if colormap:
            ds.write_colormap(1, colormap)


def opened(result):
    """The host's overlay layer for a layer type's open() result (drawables)."""
    from globeview.model.overlay_layers import host_layer

    layer, problem = host_layer(result, "test")
    assert problem is None, problem
    return layer


# -- imagery drape ----------------------------------------------------------------------------
@pytest.mark.slow
def test_thematic_cells_land_where_they_are(clean, tmp_path) -> None:
    """A checkerboard of 15-degree classes (45 x 45 cells of the etopo20 DEM's 1/3-degree grid,
    so its boundaries are DEM cell boundaries, some of them tile edges) draws each class where
    a float64 ray cast says it is: every mismatching pixel lies within 1 px of a boundary.
    (Grazing pixels near the limb, where one pixel spans many texels and the mipmap blends
    both classes, are left out.)"""
    from globeview.plugins.builtin.layers.types import ImageryLayerType

    res = 1.0 / 3.0
    cols = (np.arange(1080) * res // 15).astype(int)
    rows = (np.arange(540) * res // 15).astype(int)
    classes = ((rows[:, None] + cols[None, :]) % 2).astype(np.uint8)
    path = tmp_path / "classes.tif"
    write_raster(path, classes, res, {0: (255, 0, 0, 255), 1: (0, 0, 255, 255)})
    layer = opened(ImageryLayerType().open(str(path)))
    assert layer.layer.source.mode == "palette"
    clean.globe.add_overlay(layer)  # a model: its GPU twin is made at the next frame
    rgb, result = draw(clean, Camera.from_lonlat(20.0, 10.0, 1.2e7))
    lon, lat, hit = globe_lonlat(result.view, min_incidence=0.3)
    expect_red = ((np.floor((lon + 180) / 15) + np.floor((90 - lat) / 15)) % 2) == 0
    r, b = rgb[..., 0].astype(int), rgb[..., 2].astype(int)
    red = r > b
    # A shifted drape paints saturated wrong colours; a purple pixel is the texture filter
    # blending both classes across a boundary (trilinear mipmaps), not a misplacement.
    confident = np.abs(r - b) > 0.5 * np.maximum(r, b)
    wrong = hit & confident & (red != expect_red)
    # Within one pixel of a boundary: some 3x3 neighbour has the other expected class.
    pad = np.pad(expect_red, 1, mode="edge")
    near = np.zeros_like(wrong)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near |= pad[1 + dy : 1 + dy + SIZE[1], 1 + dx : 1 + dx + SIZE[0]] != expect_red
    assert hit.sum() > 15000 and (hit & ~near).sum() > 12000
    assert not (wrong & ~near).any(), f"{int((wrong & ~near).sum())} pixels off by > 1 px"


@pytest.mark.parametrize(
    "cam",
    [(0.0, 0.0, 2.0e7, 0.0, -90.0), (180.0, 45.0, 1.5e6, 30.0, -70.0)],
    ids=["globe", "antimeridian-tile-corner"],
)
@pytest.mark.slow
def test_uniform_imagery_shows_no_seams(clean, tmp_path, cam) -> None:
    """A uniform-colour raster drapes uniformly: its colour ratio holds on every globe pixel,
    across tile borders (including the antimeridian and a level-1 tile corner), so no
    hypsometric colour or background bleeds through a texture tile's edge."""
    from globeview.plugins.builtin.layers.types import ImageryLayerType

    path = tmp_path / "uniform.tif"
    data = np.empty((3, 90, 180), np.uint8)
    data[0], data[1], data[2] = 200, 100, 50
    write_raster(path, data, 2.0)
    clean.globe.add_overlay(opened(ImageryLayerType().open(str(path))))
    clean.settings.background = (0.0, 0.0, 0.0)
    rgb, result = draw(clean, Camera.from_lonlat(*cam))
    _, _, hit = globe_lonlat(result.view)
    px = rgb[hit].astype(float)
    lit = px[:, 0] > 40
    assert lit.mean() > 0.9
    g_r = px[lit, 1] / px[lit, 0]
    b_r = px[lit, 2] / px[lit, 0]
    assert np.all(np.abs(g_r - 0.5) < 0.04) and np.all(np.abs(b_r - 0.25) < 0.04)


@pytest.mark.slow
def test_hillshade_drape_from_the_dem(clean) -> None:
    """The hillshade layer computed from the DEM shades Crater Lake's caldera (30 m DEM) in
    grey: lit north-west slopes bright, south-east slopes dark."""
    from globeview.model.overlay_layers import hillshade_layer

    cam = Camera.from_lonlat(-122.108, 42.94, 3.0e4)
    plain, _ = draw(clean, cam)
    clean.globe.add_overlay(hillshade_layer(clean.terrain, opacity=1.0))
    shaded, _ = draw(clean, cam)
    from PIL import Image

    Image.fromarray(shaded).save(OUT / "hillshade_craterlake.png")
    grey = np.ptp(shaded.astype(int), axis=-1) <= 6
    assert grey.mean() > 0.95 and not (np.ptp(plain.astype(int), axis=-1) <= 6).mean() > 0.5
    assert shaded[..., 0].std() > 10  # relief shows: lit and shaded slopes


# -- vectors -----------------------------------------------------------------------------------
MAGENTA = (1.0, 0.0, 1.0, 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("lod", ["chunked-sse", "quadtree-clod"])
def test_borders_stay_visible_on_the_alps_at_every_lod(clean, lod) -> None:
    """Country borders across the Alps, seen obliquely: the line pixels neither vanish into
    the terrain nor change much as tau (and so the drawn mesh) changes, for two providers."""
    from globeview.plugins.builtin.layers.types import VectorLayerType

    layer = opened(
        VectorLayerType().open(
            "data/ne_110m_countries.geojson", densify_m=2000.0, color=MAGENTA, width_px=3.0
        )
    )
    clean.globe.add_overlay(layer)  # a model: its GPU twin is made at the next frame
    clean.set_lod(lod)
    cam = Camera.from_lonlat(8.5, 44.8, 6.0e4, 10.0, -35.0)
    counts = {}
    for tau in (1.0, 4.0, 16.0):
        clean.tau_px = tau
        rgb, result = draw(clean, cam)
        counts[tau] = int(((rgb[..., 0] > 230) & (rgb[..., 1] < 30) & (rgb[..., 2] > 230)).sum())
        assert result.stats.extra["vector_segments"] > 0
    assert min(counts.values()) > 400, counts
    assert min(counts.values()) > 0.8 * max(counts.values()), counts


# -- point objects -----------------------------------------------------------------------------
@pytest.mark.slow
def test_ten_thousand_instanced_boxes(clean, capsys) -> None:
    """10 000 boxes in one instanced draw; only those in drawn tiles are resident."""
    from globeview.render.overlay_points import PointOverlay, PointStyle

    rng = np.random.default_rng(7)
    lon = rng.uniform(-5.0, 25.0, 10_000)
    lat = rng.uniform(36.0, 56.0, 10_000)
    cam = Camera.from_lonlat(10.0, 46.0, 4.0e6)
    draw(clean, cam)
    _, res0 = draw(clean, cam)
    ov = PointOverlay(
        clean.ctx,
        lon,
        lat,
        None,
        PointStyle("box", scale_m=6000.0, color=(0.0, 1.0, 0.0, 1.0)),
        heading_deg=rng.uniform(0, 90, 10_000),
    )
    clean.renderer.overlays.points.append(ov)
    draw(clean, cam)
    rgb, res = draw(clean, cam)
    from PIL import Image

    Image.fromarray(rgb).save(OUT / "boxes_10k.png")
    green = (rgb[..., 1] > 100) & (rgb[..., 0] < 20) & (rgb[..., 2] < 20)
    assert res.stats.extra["objects"] == 10_000
    assert green.sum() > 2000
    # Far-away objects (other hemisphere) are not resident: their tiles are not drawn.
    ov2 = PointOverlay(clean.ctx, lon + 180.0, -lat, None, PointStyle("cone"))
    clean.renderer.overlays.points.append(ov2)
    _, res2 = draw(clean, cam)
    assert res2.stats.extra["objects"] == 10_000 and ov2.resident == 0
    with capsys.disabled():
        print(  # noqa: T201  the figure beside the count is this test's report
            f"\n10k boxes: frame_ms {res.stats.frame_ms:.1f} (without: {res0.stats.frame_ms:.1f})"
        )


@pytest.mark.slow
def test_labelled_placemarks(clean) -> None:
    """City placemarks with labels: red discs and white label text appear over Europe."""
    from globeview.plugins.builtin.layers.types import PointsLayerType

    layer = opened(PointsLayerType().open("data/ne_cities.geojson"))
    clean.globe.add_overlay(layer)  # a model: its GPU twin is made at the next frame
    rgb, res = draw(clean, Camera.from_lonlat(10.0, 46.0, 3.0e6))
    red = (rgb[..., 0] > 230) & (rgb[..., 1] < 90) & (rgb[..., 2] < 60)
    white = np.all(rgb > 235, axis=-1)
    assert 20 < res.stats.extra["objects"] < 243
    assert red.sum() > 20 * 30 and white.sum() > 200
