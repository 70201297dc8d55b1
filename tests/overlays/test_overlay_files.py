"""Layer files the user opens: content detection, geodesic densification, and one-line errors
for bad input (no GL needed)."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from affine import Affine

from globeview.errors import GlobeviewError
from globeview.model.overlay_layers import host_layer
from globeview.plugins.builtin.layers.types import (
    ImageryLayerType,
    PointsLayerType,
    VectorLayerType,
    detect_layer_type,
)
from globeview.terrain.dem.data import EMBEDDED_DATA_DIR
from globeview.terrain.imagery import ImageryError, RasterImagery, texel_grid
from globeview.terrain.vectors import GEOD, VectorError, densify, read_geojson_lines


def test_detects_layer_type_by_content(tmp_path) -> None:
    assert detect_layer_type(EMBEDDED_DATA_DIR / "bluemarble_2048x1024.tif") == "imagery"
    assert detect_layer_type(EMBEDDED_DATA_DIR / "etopo20.tif") == "thematic"
    assert detect_layer_type(EMBEDDED_DATA_DIR / "ne_110m_countries.geojson") == "vector"
    assert detect_layer_type(EMBEDDED_DATA_DIR / "ne_cities.geojson") == "points"
    # The extension does not decide: GeoJSON saved as .txt is still a vector layer.
    p = tmp_path / "line.txt"
    p.write_text('{"type": "LineString", "coordinates": [[0, 0], [10, 10]]}')
    assert detect_layer_type(p) == "vector"


def test_densified_lines_follow_the_geodesic() -> None:
    lines = densify(read_geojson_lines(EMBEDDED_DATA_DIR / "ne_110m_countries.geojson"), 20_000)
    a, b = lines.segments()
    _, _, d = GEOD.inv(lines.lon[a], lines.lat[a], lines.lon[b], lines.lat[b])
    assert len(lines) > 177 and np.max(d) <= 20_000.0 * 1.001
    # Every inserted point lies on its original segment's geodesic: total length unchanged.
    orig = read_geojson_lines(EMBEDDED_DATA_DIR / "ne_110m_countries.geojson")
    oa, ob = orig.segments()
    _, _, od = GEOD.inv(orig.lon[oa], orig.lat[oa], orig.lon[ob], orig.lat[ob])
    assert np.sum(d) == pytest.approx(np.sum(od), rel=1e-9)


def _one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert "\n" not in msg and msg
    return msg


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ("", "empty"),
        ('{"type": "FeatureCollection", "features": [', "not valid GeoJSON"),
        (
            '{"type": "FeatureCollection", "crs": {"type": "name", "properties": {"name": '
            '"urn:ogc:def:crs:EPSG::32633"}}, "features": []}',
            "unsupported CRS",
        ),
        ('{"type": "FeatureCollection", "features": []}', "no LineString or Polygon"),
        ('{"type": "LineString", "coordinates": [[500000, 4000000], [1, 2]]}', "not WGS84"),
    ],
)
def test_bad_geojson_gives_one_line_errors(tmp_path, content, needle) -> None:
    p = tmp_path / "bad.geojson"
    p.write_text(content)
    with pytest.raises(VectorError) as err:
        VectorLayerType().open(str(p))
    assert needle in _one_line(err.value) and "bad.geojson" in str(err.value)


def test_points_file_without_points_is_refused(tmp_path) -> None:
    p = tmp_path / "lines.geojson"
    p.write_text('{"type": "LineString", "coordinates": [[0, 0], [1, 1]]}')
    with pytest.raises(GlobeviewError, match="no Point geometry"):
        PointsLayerType().open(str(p))


def test_bad_rasters_give_one_line_errors(tmp_path) -> None:
    nocrs = tmp_path / "nocrs.tif"
    with rasterio.open(
        nocrs,
        "w",
        driver="GTiff",
        width=4,
        height=4,
        count=3,
        dtype="uint8",
        transform=Affine(1, 0, 0, 0, -1, 4),
    ) as ds:
        ds.write(np.zeros((3, 4, 4), np.uint8))
    with pytest.raises(ImageryError) as err:
        host_layer(ImageryLayerType().open(str(nocrs)), "nocrs.tif")
    assert "no coordinate reference system" in _one_line(err.value)
    with pytest.raises(ImageryError, match="unknown CRS"):
        RasterImagery(nocrs, crs="EPSG:999999")
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"not a tiff at all")
    with pytest.raises(ImageryError) as err:
        host_layer(ImageryLayerType().open(str(junk)), "junk.tif")
    assert "cannot read as a raster" in _one_line(err.value)
    with pytest.raises(GlobeviewError, match="neither a raster"):
        detect_layer_type(junk)


def test_texture_tiles_carry_a_one_texel_border() -> None:
    # Neighbouring tiles' textures overlap by one texel each side: the east border column of
    # one tile holds what the west interior column of its east neighbour holds.
    img = RasterImagery(EMBEDDED_DATA_DIR / "bluemarble_2048x1024.tif", tex_size=64)
    west = img.tile_rgba((2, 3, 1))
    east = img.tile_rgba((2, 4, 1))
    assert np.abs(west[:, -1].astype(int) - east[:, 1].astype(int)).max() <= 1
    assert np.abs(west[:, -2].astype(int) - east[:, 0].astype(int)).max() <= 1
    t, (w, _s, e, _n) = texel_grid((2, 3, 1), 64)
    assert t.c + t.a == pytest.approx(w) and t.c + 63 * t.a == pytest.approx(e)


def test_opening_a_thematic_raster_writes_nothing_beside_it(tmp_path) -> None:
    """A single-band raster's grey ramp comes from its band statistics; GDAL would save them
    as NAME.aux.xml in the user's folder. Nothing may appear there."""
    import shutil

    src = tmp_path / "relief.tif"
    shutil.copyfile(EMBEDDED_DATA_DIR / "etopo20.tif", src)
    img = RasterImagery(src, tex_size=64)
    assert img.mode == "ramp" and img.ramp[0][0] < img.ramp[-1][0]
    img.ds.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["relief.tif"]


def test_raster_info_statistics_write_nothing_beside_the_file(tmp_path) -> None:
    # The layer types' raster_info(stats=True) reads band statistics the same way.
    import shutil

    from globeview.plugins.api import raster_info

    src = tmp_path / "relief.tif"
    shutil.copyfile(EMBEDDED_DATA_DIR / "etopo20.tif", src)
    info = raster_info(src, stats=True)
    assert info.bands == 1 and info.minimum < 0.0 < info.maximum
    assert sorted(p.name for p in tmp_path.iterdir()) == ["relief.tif"]
