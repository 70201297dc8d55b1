"""GIS vector files through OGR (issue #26 item 3), read without GL: files written by GDAL
itself (pyogrio) in several formats and CRSs come back as lon/lat drawables where the cross
over Mount Washington is; layer choice; colour classes; bad input in one line."""

from __future__ import annotations

import logging
import struct

import numpy as np
import pytest

from globeview.errors import GlobeviewError
from globeview.model.drawables import Lines, Points
from globeview.model.vector_files import classify, read_vector_file

from .gis_samples import (
    COLUMN_LON,
    ROW_LAT,
    east_west,
    line_wkb,
    north_south,
    point_wkb,
    polygon_wkb,
    projected,
    write_cross,
    write_gpkg,
    write_gpx,
)


def _paths(drawables) -> list[np.ndarray]:
    return [np.asarray(p) for d in drawables if isinstance(d, Lines) for p in d.path_list()]


def _has_cross(paths: list[np.ndarray], tol: float = 1e-6) -> None:
    """Both lines of the cross are there, vertex for vertex, in lon/lat degrees."""
    want = [east_west(), north_south()]
    for w in want:
        assert any(p.shape == w.shape and np.abs(p - w).max() < tol for p in paths), (
            f"a line {w[0]}..{w[-1]} is missing from {[(p[0], p[-1]) for p in paths]}"
        )


@pytest.mark.parametrize(
    ("name", "driver", "epsg"),
    [
        ("cross.shp", "ESRI Shapefile", 26919),  # NAD83 / UTM 19N
        ("cross.kml", "KML", 4326),
        ("cross.kmz", "LIBKML", 4326),  # zipped KML
        ("cross.fgb", "FlatGeobuf", 3857),  # web Mercator
        ("cross.geojson", "GeoJSON", 32619),  # an old-style GeoJSON with a projected CRS
    ],
)
def test_formats_in_any_crs_come_back_as_lonlat(tmp_path, name, driver, epsg):
    path = write_cross(tmp_path / name, driver, epsg)
    _has_cross(_paths(read_vector_file(path)))


def test_gpx_track_segments(tmp_path):
    _has_cross(_paths(read_vector_file(write_gpx(tmp_path / "cross.gpx"))))


def test_geopackage_first_layer_or_the_named_one(tmp_path, caplog):
    path = write_gpkg(tmp_path / "wm.gpkg")
    with caplog.at_level(logging.WARNING, logger="globeview.vectors"):
        first = read_vector_file(path)
    # roads: the east-west line; its one-vertex line is skipped and counted in one line.
    paths = _paths(first)
    assert len(paths) == 1 and np.abs(paths[0] - east_west()).max() < 1e-6
    warned = [r.getMessage() for r in caplog.records if r.name == "globeview.vectors"]
    assert warned == ["wm.gpkg: 1 features with broken geometry skipped (1 drawn)"]
    trails = read_vector_file(path, "trails")
    paths = _paths(trails)
    assert len(paths) == 1 and np.abs(paths[0] - north_south()).max() < 1e-6
    assert trails[0].name == "wm.gpkg::trails"
    with pytest.raises(
        GlobeviewError, match=r"wm.gpkg: no layer 'rivers' \(layers: roads, trails\)"
    ):
        read_vector_file(path, "rivers")


def test_colour_by_a_field_gives_classes_and_a_legend(tmp_path):
    path = write_cross(tmp_path / "cross.fgb", "FlatGeobuf", 4326)
    got = read_vector_file(path, color_by="kind", width_px=3.0)
    assert [(d.legend, d.color[:3]) for d in got] == [
        ("road", (0.12, 0.47, 0.71)),
        ("trail", (1.0, 0.5, 0.05)),
    ]
    assert all(d.width_px == 3.0 for d in got)
    road = got[0].path_list()
    assert len(road) == 1 and np.abs(road[0][:, 1] - ROW_LAT).max() < 1e-9


def test_labels_from_a_field_sit_on_the_lines(tmp_path):
    path = write_cross(tmp_path / "cross.shp", "ESRI Shapefile", 26919)
    got = read_vector_file(path, label="name")
    labels = [d for d in got if isinstance(d, Points)]
    assert len(labels) == 1
    pts = labels[0]
    assert sorted(pts.labels) == ["east-west", "north-south"]
    at = dict(zip(pts.labels, zip(pts.lon, pts.lat, strict=True), strict=True))
    assert at["east-west"][1] == pytest.approx(ROW_LAT, abs=1e-6)
    assert at["north-south"][0] == pytest.approx(COLUMN_LON, abs=1e-6)


def test_points_are_labelled_by_their_name_field(tmp_path):
    from pyogrio.raw import write

    path = tmp_path / "peaks.gpkg"
    write(
        str(path),
        np.array([point_wkb(-71.3036, 44.2705), point_wkb(-71.2456, 44.2207)], dtype=object),
        [np.array(["Washington", "Carter Dome"], dtype=object), np.array([1917.0, 1478.0])],
        ["name", "height"],
        crs="EPSG:4326",
        geometry_type="Point",
        driver="GPKG",
    )
    (points,) = read_vector_file(path)
    assert list(points.labels) == ["Washington", "Carter Dome"]
    assert points.lon[0] == pytest.approx(-71.3036)


def test_polygons_are_drawn_as_closed_outlines(tmp_path):
    from pyogrio.raw import write

    ring = np.array([[-71.4, 44.2], [-71.2, 44.2], [-71.2, 44.3], [-71.4, 44.3], [-71.4, 44.2]])
    path = tmp_path / "park.fgb"
    write(
        str(path),
        np.array([polygon_wkb(projected(ring, 32619))], dtype=object),
        [np.array(["park"], dtype=object)],
        ["name"],
        crs="EPSG:32619",
        geometry_type="Polygon",
        driver="FlatGeobuf",
    )
    (outline,) = _paths(read_vector_file(path))
    assert outline.shape == (5, 2) and np.abs(outline - ring).max() < 1e-6


def test_classify_categories_ramp_and_missing_values():
    cats = classify(np.array(["b", "a", None, "b"], dtype=object))
    assert cats.labels == ("a", "b", "no value")
    assert cats.index.tolist() == [1, 0, 2, 1]
    many = classify(np.array([str(i % 12) for i in range(120)] + ["0"] * 5, dtype=object))
    assert len(many.labels) == 9 and many.labels[-1] == "other"  # 8 most frequent + other
    ramp = classify(np.arange(100.0), classes=4)
    assert ramp.labels == ("0 – 24.75", "24.75 – 49.5", "49.5 – 74.25", "74.25 – 99")
    assert np.bincount(ramp.index).tolist() == [25, 25, 25, 25]
    assert ramp.colors[0] != ramp.colors[-1]
    few = classify(np.array([1, 2, 2, 1]), classes=5)  # few distinct numbers: categories
    assert few.labels == ("1", "2")


def _no_crs_file(tmp_path, lonlat: bool):
    import warnings

    from pyogrio.raw import write

    xy = east_west() if lonlat else projected(east_west(), 32619)
    path = tmp_path / ("lonlat.shp" if lonlat else "metres.shp")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "'crs' was not provided": the point of the file
        write(
            str(path),
            np.array([line_wkb(xy)], dtype=object),
            [np.array(["x"], dtype=object)],
            ["name"],
            geometry_type="LineString",
            driver="ESRI Shapefile",
        )
    return path


def test_no_crs_lonlat_is_assumed_with_one_warning(tmp_path, caplog):
    path = _no_crs_file(tmp_path, lonlat=True)
    with caplog.at_level(logging.WARNING, logger="globeview.vectors"):
        _paths_read = _paths(read_vector_file(path))
    assert np.abs(_paths_read[0] - east_west()).max() < 1e-9
    warned = [r.getMessage() for r in caplog.records if r.name == "globeview.vectors"]
    assert warned == ["lonlat.shp: no CRS; its coordinates fit lon/lat degrees: read as WGS84"]


def test_no_crs_projected_is_refused_in_one_line(tmp_path):
    path = _no_crs_file(tmp_path, lonlat=False)
    with pytest.raises(GlobeviewError) as err:
        read_vector_file(path)
    assert str(err.value) == (
        "metres.shp: no CRS, and the coordinates are not lon/lat degrees "
        "(give the file its CRS, e.g. a .prj beside a Shapefile)"
    )


def test_bad_input_is_one_line(tmp_path, monkeypatch):
    path = write_gpkg(tmp_path / "wm.gpkg")
    with pytest.raises(
        GlobeviewError, match=r"no field 'colour' in layer 'roads' \(fields: name, kind, lanes\)"
    ):
        read_vector_file(path, color_by="colour")
    junk = tmp_path / "junk.gpkg"
    junk.write_bytes(b"SQLite format 3\x00 but not really")
    with pytest.raises(GlobeviewError, match=r"^junk.gpkg: not a vector file OGR reads"):
        read_vector_file(junk)
    import globeview.model.vector_files as vf
    import globeview.terrain.ogr_vectors as ogr

    peaks = tmp_path / "peaks.fgb"
    from pyogrio.raw import write

    write(
        str(peaks),
        np.array([point_wkb(-71.3, 44.27), point_wkb(-71.2, 44.2)], dtype=object),
        [np.array(["a", "b"], dtype=object)],
        ["name"],
        crs="EPSG:4326",
        geometry_type="Point",
        driver="FlatGeobuf",
    )
    monkeypatch.setattr(vf, "MAX_POINTS", 1)  # more points than a layer draws: the file's line
    with pytest.raises(GlobeviewError, match=r"^peaks.fgb: 2 points \(at most 1\)$"):
        read_vector_file(peaks)
    monkeypatch.setattr(ogr, "MAX_FEATURES", 2)  # a file with too many features: refused first
    with pytest.raises(GlobeviewError, match=r"layer 'roads' has 3 features \(at most 2\)"):
        read_vector_file(path)


def test_every_broken_geometry_is_counted_and_skipped(tmp_path):
    from globeview.terrain.wkb import decode_wkb

    good = line_wkb(east_west())
    blobs = [
        good,
        good[:-5],  # truncated
        struct.pack("<BI", 1, 8) + b"\x00" * 40,  # a CircularString: not drawn
        line_wkb(np.array([[0.0, np.inf], [1.0, 1.0]])),  # not finite
        None,  # no geometry: empty, not broken
        point_wkb(float("nan"), float("nan")),  # POINT EMPTY
        b"\x00" + struct.pack(">I", 1) + struct.pack(">dd", -71.3, 44.27),  # big endian
    ]
    g = decode_wkb(blobs)
    assert (g.broken, g.empty) == (3, 2)
    assert g.line_feature.tolist() == [0] and g.point_feature.tolist() == [6]
    assert g.point_xy.tolist() == [[-71.3, 44.27]]


def test_geoparquet_that_is_not_parquet_is_one_line(tmp_path):
    """(GeoParquet itself: tests/api/test_api_geoparquet.py.)"""
    import pyogrio

    if "Parquet" in pyogrio.list_drivers():
        pytest.skip("this GDAL reads GeoParquet")
    pytest.importorskip("pyarrow")
    path = tmp_path / "x.parquet"
    path.write_bytes(b"PAR1 not read")
    with pytest.raises(GlobeviewError, match=r"^x.parquet: not a Parquet file \("):
        read_vector_file(path)


def test_restyle_reopens_a_layer_in_its_place(tmp_path, registry):
    """`OverlayHost.restyle` (the Layers dock's colour-by and label choice) on the API's globe:
    no GL is needed to open or restyle."""
    import globeview

    path = write_cross(tmp_path / "cross.fgb", "FlatGeobuf", 32619)
    globe = globeview.Globe(registry=registry)
    try:
        first = globe.add_vectors(path)
        top = globe.add_overlay(write_gpx(tmp_path / "cross.gpx"))
        host = globe.overlay_host
        assert host.vector_fields(first) == ["name", "kind"]
        assert host.vector_fields(top)[0] == "name"  # then GPX's own (cmt, desc, src, ...)
        coloured = host.restyle(first, color_by="kind", width_px=4.0)
        assert globe.overlays == [coloured, top]
        assert [e.label for e in coloured.legend] == ["road", "trail"]
        assert host.opened_style(coloured)["color_by"] == "kind"
        with pytest.raises(GlobeviewError, match="no field 'colour'"):
            host.restyle(coloured, color_by="colour")
        assert globe.overlays == [coloured, top]  # refused: the old layer kept
    finally:
        globe.close()


def _hostile(tmp_path, kind: str):
    import shutil

    good = write_cross(tmp_path / "cross.shp", "ESRI Shapefile", 26919)
    data = good.read_bytes()
    if kind == "truncated.shp":
        for ext in (".shx", ".dbf", ".prj"):
            shutil.copy(good.with_suffix(ext), tmp_path / f"truncated{ext}")
        (tmp_path / kind).write_bytes(data[: len(data) // 2])
    elif kind == "noshx.shp":
        (tmp_path / kind).write_bytes(data)
    elif kind == "zeros.gpkg":
        (tmp_path / kind).write_bytes(b"\x00" * 1000)
    else:
        (tmp_path / kind).write_text("")
    return tmp_path / kind


@pytest.mark.parametrize(
    ("kind", "line"),
    [
        ("truncated.shp", "truncated.shp: no point, line or polygon geometry to draw"),
        ("noshx.shp", "noshx.shp: not a vector file OGR reads (Unable to open "),
        ("zeros.gpkg", "zeros.gpkg: not a vector file OGR reads ("),
        ("empty.kml", "empty.kml: not a vector file OGR reads ("),
    ],
)
def test_hostile_files_are_one_line(tmp_path, kind, line):
    with pytest.raises(GlobeviewError) as err:
        read_vector_file(_hostile(tmp_path, kind))
    text = str(err.value)
    assert text.startswith(line) and "\n" not in text and len(text) < 300


def test_features_off_the_globe_or_a_crs_proj_cannot_use_do_not_break_the_layer_type(
    tmp_path, caplog
):
    """Found by the issue #26 review: a WGS84 file with a vertex at latitude 100 (or a
    LOCAL_CS file) made the layer return a path off the globe, and the host disabled the
    built-in `gis` type for the rest of the session. Such features are broken geometry
    (skipped, counted); a CRS PROJ cannot transform is an unknown CRS."""
    import pyogrio.raw

    off = np.array([[-71.3, 44.2], [-71.2, 100.0]])
    far = np.array([[1e300, 44.2], [-71.2, 44.3]])
    blobs = np.array([line_wkb(east_west()), line_wkb(off), line_wkb(far)], dtype=object)
    names = [np.array(["ok", "lat100", "lon1e300"], dtype=object)]
    path = tmp_path / "off.gpkg"
    pyogrio.raw.write(
        path, blobs, names, ["name"], geometry_type="LineString", crs="EPSG:4326", driver="GPKG"
    )
    with caplog.at_level(logging.WARNING):
        drawn = read_vector_file(path)
    paths = _paths(drawn)
    assert len(paths) == 1 and np.abs(paths[0] - east_west()).max() < 1e-9
    assert "2 features with broken geometry skipped (1 drawn)" in caplog.text

    local = 'LOCAL_CS["site",LOCAL_DATUM["x",0],UNIT["metre",1],AXIS["X",EAST],AXIS["Y",NORTH]]'
    lpath = tmp_path / "local.gpkg"
    pyogrio.raw.write(
        lpath,
        blobs[:1],
        [names[0][:1]],
        ["name"],
        geometry_type="LineString",
        crs=local,
        driver="GPKG",
    )
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert len(_paths(read_vector_file(lpath))) == 1
    assert "its coordinates fit lon/lat degrees: read as WGS84" in caplog.text
