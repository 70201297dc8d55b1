"""GeoParquet through pyarrow (issue #26 item 3; pyogrio's wheel GDAL has no Parquet driver):
a file pyarrow writes here, with its 'geo' metadata (WKB, a PROJJSON CRS in UTM 19N), is read
as lon/lat where the cross over Mount Washington is, coloured and labelled by field, drawn by
`Globe.add_vectors` and `globeview render --layer`; bad files are one line."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from globeview.errors import GlobeviewError
from globeview.model.drawables import Lines, Points
from globeview.model.vector_files import read_vector_file

from .gis_samples import (
    COLUMN_LON,
    ROW_LAT,
    east_west,
    line_wkb,
    north_south,
    point_wkb,
    projected,
)
from .test_api_gis_render import HEIGHT_M, MAGENTA, SIZE, _render, bands, magenta

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

#: Mount Washington's summit (lon, lat degrees), a point feature.
SUMMIT = (-71.3036, 44.2705)
EPSG = 32619


def _geo(encoding: str = "WKB", crs: object = "utm") -> dict:
    column: dict = {"encoding": encoding, "geometry_types": ["LineString", "Point"]}
    if crs == "utm":
        from pyproj import CRS

        column["crs"] = CRS.from_epsg(EPSG).to_json_dict()
    elif crs != "absent":
        column["crs"] = crs
    return {"version": "1.1.0", "primary_column": "geometry", "columns": {"geometry": column}}


def write_geoparquet(path: Path, geo: dict | None = None, lonlat: bool = False) -> Path:
    """The cross (two lines) and the summit (a point) plus a feature without geometry, in
    UTM 19N (or lon/lat with ``lonlat``), written by pyarrow with GeoParquet metadata."""
    ew, ns, top = east_west(), north_south(), np.array([SUMMIT])
    if not lonlat:
        ew, ns, top = projected(ew, EPSG), projected(ns, EPSG), projected(top, EPSG)
    blobs = [line_wkb(ew), line_wkb(ns), point_wkb(*top[0]), None]
    table = pa.table(
        {
            "name": ["Route 302", "Appalachian Trail", "Mount Washington", None],
            "kind": ["road", "trail", "peak", None],
            "lanes": [2, None, None, 1],
            "geometry": pa.array(blobs, pa.binary()),
        }
    )
    meta = None if geo is None else {b"geo": json.dumps(geo).encode()}
    pq.write_table(table.replace_schema_metadata(meta), path)
    return path


@pytest.fixture
def cross(tmp_path) -> Path:
    return write_geoparquet(tmp_path / "cross.parquet", _geo())


def test_read_in_lonlat_coloured_and_labelled(cross):
    got = read_vector_file(cross, color_by="kind", label="name")
    lines = [d for d in got if isinstance(d, Lines)]
    points = [d for d in got if isinstance(d, Points)]
    assert sorted(d.legend for d in lines) == ["road", "trail"]
    for d in lines:
        (xy,) = [np.asarray(p) for p in d.path_list()]
        if d.legend == "road":  # the east-west line, back from UTM 19N
            assert np.allclose(xy[:, 1], ROW_LAT, atol=1e-6)
        else:
            assert np.allclose(xy[:, 0], COLUMN_LON, atol=1e-6)
    summit = next(d for d in points if d.legend == "peak")
    assert (float(summit.lon[0]), float(summit.lat[0])) == pytest.approx(SUMMIT, abs=1e-7)
    assert list(summit.labels) == ["Mount Washington"]
    labels = next(d for d in points if d.name == "cross.parquet labels")
    assert sorted(labels.labels) == ["Appalachian Trail", "Route 302"]


def test_default_crs_is_crs84_and_the_layer_is_the_file(tmp_path):
    path = write_geoparquet(tmp_path / "ll.geoparquet", _geo(crs="absent"), lonlat=True)
    from globeview.model.vector_files import vector_file_layers

    assert vector_file_layers(path) == [("ll", "LineString, Point")]
    got = read_vector_file(path, "ll", color=MAGENTA)
    assert got[0].name == "ll.geoparquet::ll"
    lines = next(d for d in got if isinstance(d, Lines))
    assert np.asarray(lines.path_list()[0])[:, 0].min() == pytest.approx(-71.5)


@pytest.mark.parametrize(
    ("geo", "line"),
    [
        (None, "cross.parquet: a Parquet file without GeoParquet ('geo') metadata"),
        ({"columns": {}}, "cross.parquet: its GeoParquet ('geo') metadata is malformed"),
        (
            _geo(encoding="point"),
            "cross.parquet: geometry column 'geometry' is encoded as 'point'; globeview reads "
            "WKB-encoded GeoParquet (write it with geometry_encoding='WKB')",
        ),
        (
            _geo(crs={"type": "not a CRS"}),
            'cross.parquet: unknown CRS \'{"type": "not a CRS"}\', and the coordinates are '
            "not lon/lat degrees",
        ),
    ],
)
def test_bad_geoparquet_is_one_line(tmp_path, geo, line):
    path = write_geoparquet(tmp_path / "cross.parquet", geo)
    with pytest.raises(GlobeviewError) as info:
        read_vector_file(path)
    assert str(info.value).startswith(line) and "\n" not in str(info.value)


def test_not_parquet_unknown_field_and_no_pyarrow_are_one_line(tmp_path, cross, monkeypatch):
    junk = tmp_path / "junk.parquet"
    junk.write_bytes(b"PAR1 not a parquet file")
    with pytest.raises(GlobeviewError, match=r"^junk.parquet: not a Parquet file \("):
        read_vector_file(junk)
    with pytest.raises(GlobeviewError, match=r"^cross.parquet: no field 'colour' \(fields: name"):
        read_vector_file(cross, color_by="colour")
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)  # import fails as uninstalled
    with pytest.raises(
        GlobeviewError,
        match=r"^reading GeoParquet needs pyarrow: pip install 'globeview\[gis-parquet\]'$",
    ):
        read_vector_file(cross)


@pytest.mark.gl
@pytest.mark.slow  # a render on llvmpipe
def test_add_vectors_draws_the_cross_where_it_is(wm_globe, cross):
    before = wm_globe.camera
    wm_globe.fly_to(COLUMN_LON, ROW_LAT, HEIGHT_M, heading=0.0, pitch=-90.0)
    try:
        layer = wm_globe.add_vectors(cross, color=MAGENTA, width_px=3.0)
        row, col, elsewhere = bands(magenta(wm_globe.render(SIZE)))
    finally:
        for ly in wm_globe.overlays:
            wm_globe.remove_overlay(ly)
        wm_globe.camera = before
    assert layer.name == "cross.parquet"
    assert row > 150 and col > 150, (row, col)
    assert elsewhere < 0.05 * max(row, col)


@pytest.mark.gl
@pytest.mark.slow  # a globeview process rendering on llvmpipe
def test_cli_render_layer_draws_a_geoparquet_file(tmp_path, cross):
    out = tmp_path / "cross.png"
    proc = _render(tmp_path, "--out", str(out), "--layer", str(cross))
    assert proc.returncode == 0, proc.stderr
    rgb = np.asarray(Image.open(out).convert("RGB")).astype(int)
    yellow = (rgb[..., 0] > 200) & (rgb[..., 2] < 100)  # the default line colour
    row, col, elsewhere = bands(yellow)
    assert row > 150 and col > 150 and elsewhere < 0.1 * max(row, col), (row, col, elsewhere)
