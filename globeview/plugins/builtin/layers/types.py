"""`layers`: the built-in layer types (imagery, thematic, vector, points).

Written against the public plugin API only, as a third-party layer plugin would be: each
type's ``open(path)`` reads and checks the file on the CPU and returns *drawables*
(`RasterFile`, `Lines`, `Points`); the host draws them (globeview/model/overlay_layers.py).
``sniff(path)`` says by content whether a file is the type's (the host's file dispatch asks
it when several types claim an extension: ``.tif`` may be imagery or thematic, ``.geojson``
lines or points). Bad input raises a `GlobeviewError` subclass with a one-line message.

`detect_layer_type(path)` is the built-ins' content decision on its own (raster vs GeoJSON
lines vs GeoJSON points).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from globeview.plugins.api import (
    GlobeviewError,
    Lines,
    Points,
    RasterFile,
    raster_info,
    read_vector_file,
    vector_file_layers,
)

__all__ = [
    "GisVectorLayerType",
    "ImageryLayerType",
    "PointsLayerType",
    "ThematicLayerType",
    "VectorLayerType",
    "detect_layer_type",
]

RASTER_EXTENSIONS = (".tif", ".tiff", ".png", ".jpg", ".jpeg", ".jp2", ".img", ".vrt", ".asc")
VECTOR_EXTENSIONS = (".geojson", ".json")
#: GIS vector formats read through OGR (a GeoJSON file too when this type is chosen).
GIS_EXTENSIONS = (
    ".shp",
    ".shp.zip",
    ".shz",
    ".gpkg",
    ".kml",
    ".kmz",
    ".gpx",
    ".fgb",
    ".parquet",
    ".geoparquet",
    ".gml",
    ".tab",
    ".mif",
    ".sqlite",
)
#: Default densification of vector lines (metres between vertices).
DENSIFY_M = 20_000.0
_LINE_TYPES = {"LineString", "MultiLineString", "Polygon", "MultiPolygon"}
_POINT_TYPES = {"Point", "MultiPoint"}


def geojson_geometry_types(path: str | Path) -> set[str] | None:
    """The geometry types in a GeoJSON file; None when the file is not JSON text at all
    (its first non-blank byte is not ``{`` or ``[``). Raises `GlobeviewError` for JSON text
    that does not parse, and for an empty (or blank) file, whatever its name: no format
    reads one, and "empty" is the line the user needs."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            head = fh.read(64).lstrip()
    except OSError as exc:
        raise GlobeviewError(f"{p.name}: cannot read ({exc.strerror or exc})") from None
    if not head:
        raise GlobeviewError(f"{p.name}: the file is empty")
    if head[:1] not in (b"{", b"["):
        return None
    # Opening one file asks this several times (the dialog's dispatch, the session's, each
    # GeoJSON type's sniff): parse it once while it is unchanged.
    try:
        stat = p.stat()
    except OSError as exc:
        raise GlobeviewError(f"{p.name}: cannot read ({exc.strerror or exc})") from None
    key = (str(p.resolve()), stat.st_mtime_ns, stat.st_size)
    hit = _TYPES_SEEN.get(key)
    if hit is not None:
        return set(hit)
    types = _parse_geometry_types(p)
    _TYPES_SEEN[key] = frozenset(types)
    while len(_TYPES_SEEN) > 16:
        _TYPES_SEEN.pop(next(iter(_TYPES_SEEN)))
    return types


#: (resolved path, mtime ns, size) -> geometry types, the last few files asked about.
_TYPES_SEEN: dict[tuple[str, int, int], frozenset[str]] = {}


def _parse_geometry_types(p: Path) -> set[str]:
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise GlobeviewError(f"{p.name}: not valid GeoJSON ({exc})") from None
    except RecursionError:  # [[[[...]]]] thousands deep
        raise GlobeviewError(f"{p.name}: not valid GeoJSON (nested too deeply)") from None
    types: set[str] = set()
    feats = doc.get("features", [doc]) if isinstance(doc, dict) else []
    for f in feats if isinstance(feats, list) else []:
        g = (f or {}).get("geometry", f) if isinstance(f, dict) else None
        if isinstance(g, dict) and isinstance(g.get("type"), str):
            types.add(g["type"])
            for sub in g.get("geometries") or [] if isinstance(g.get("geometries"), list) else []:
                if isinstance(sub, dict) and isinstance(sub.get("type"), str):
                    types.add(sub["type"])
    return types


def _raster_kind(path: str | Path) -> str | None:
    """'imagery' (3/4 bands, or a colour table) or 'thematic' (one band), None otherwise
    (not a raster GDAL reads)."""
    try:
        info = raster_info(path)
    except GlobeviewError:
        return None
    if info.bands in (3, 4) or info.palette:
        return "imagery"
    return "thematic" if info.bands == 1 else None


class _LayerTypeBase:
    name = ""
    label = ""
    extensions: tuple[str, ...] = ()

    def __init__(self, context: Any = None) -> None:
        self.context = context

    def configure(self, values: dict) -> None:  # layer types have no settings yet
        pass


class ImageryLayerType(_LayerTypeBase):
    """RGB(A) imagery, or a single band with a colour table, draped on the terrain."""

    name = "imagery"
    label = "Imagery (RGB/RGBA raster)"
    extensions = RASTER_EXTENSIONS

    def sniff(self, path: str) -> bool:
        return _raster_kind(path) == "imagery"

    def open(self, path: str, opacity: float = 1.0) -> RasterFile:
        return RasterFile(path, None, opacity, Path(path).name)


class ThematicLayerType(_LayerTypeBase):
    """A single-band raster coloured by its colour table or by a ramp (default: a
    blue-green-yellow-red ramp over the band's range), draped half-transparent."""

    name = "thematic"
    label = "Thematic raster (single band)"
    extensions = RASTER_EXTENSIONS

    def sniff(self, path: str) -> bool:
        return _raster_kind(path) == "thematic"

    def open(self, path: str, ramp: list | None = None, opacity: float = 0.6) -> RasterFile:
        if ramp is None:
            info = raster_info(path, stats=True)
            lo, hi = info.minimum, info.maximum
            span = hi - lo or 1.0
            ramp = [
                (lo, (40, 60, 200)),
                (lo + span / 3, (40, 180, 90)),
                (lo + 2 * span / 3, (240, 220, 40)),
                (hi, (220, 40, 30)),
            ]
        return RasterFile(path, ramp, opacity, Path(path).name)


class VectorLayerType(_LayerTypeBase):
    """GeoJSON LineString/MultiLineString/Polygon/MultiPolygon outlines, joined along
    geodesics."""

    name = "vector"
    label = "Vector lines/polygons (GeoJSON)"
    extensions = VECTOR_EXTENSIONS

    def sniff(self, path: str) -> bool:
        types = geojson_geometry_types(path)
        if types is not None and not types & (_LINE_TYPES | _POINT_TYPES):
            name = Path(path).name
            raise GlobeviewError(f"{name}: GeoJSON without Point, LineString or Polygon geometry")
        return bool(types and types & _LINE_TYPES)

    def open(self, path: str, densify_m: float = DENSIFY_M, **style: Any) -> Lines:
        return Lines.from_geojson(path, segment_m=densify_m, **style)


class PointsLayerType(_LayerTypeBase):
    """GeoJSON Point/MultiPoint features as labelled placemarks (``name`` property)."""

    name = "points"
    label = "Point objects (GeoJSON)"
    extensions = VECTOR_EXTENSIONS

    def sniff(self, path: str) -> bool:
        types = geojson_geometry_types(path)
        return bool(types and types & _POINT_TYPES and not types & _LINE_TYPES)

    def open(self, path: str, **style: Any) -> Points:
        return Points.from_geojson(path, **style)


class GisVectorLayerType(_LayerTypeBase):
    """GIS vector files through GDAL/OGR (Shapefile, GeoPackage, KML/KMZ, GPX, FlatGeobuf,
    GeoParquet (GDAL's driver, else pyarrow), any OGR source) in any CRS: lines and polygon
    outlines draped along geodesics, points as placemarks; coloured and labelled by attribute.

    ``open(path, layer=None, color_by=None, label=None, color=None, width_px=1.5, size_px=8,
    classes=5, segment_m=1000, name=None)``; see `read_vector_file`."""

    name = "gis"
    label = "GIS vectors (Shapefile, GeoPackage, KML, GPX, FlatGeobuf... via OGR)"
    extensions = GIS_EXTENSIONS

    def sniff(self, path: str) -> bool:
        suffix = "".join(Path(path).suffixes[-2:]).lower()
        claimed = any(suffix.endswith(e) for e in GIS_EXTENSIONS)
        if claimed:
            vector_file_layers(path)  # its format but unreadable: that line, not "no type"
            return True
        try:  # content sniffing of an unknown extension: OGR decides, silently
            return bool(vector_file_layers(path))
        except GlobeviewError:
            return False

    def open(self, path: str, layer: str | None = None, **style: Any) -> list:
        return read_vector_file(path, layer, **style)


def detect_layer_type(path: str | Path) -> str:
    """'imagery', 'thematic', 'vector' or 'points' for a file, decided by its content."""
    p = Path(path)
    if not p.is_file():
        raise GlobeviewError(f"{p.name}: no such file")
    types = geojson_geometry_types(p)
    if types is not None:
        if types & _LINE_TYPES:
            return "vector"
        if types & _POINT_TYPES:
            return "points"
        raise GlobeviewError(f"{p.name}: GeoJSON without Point, LineString or Polygon geometry")
    kind = _raster_kind(p)
    if kind is None:
        raise GlobeviewError(f"{p.name}: neither a raster GDAL reads nor GeoJSON")
    return kind
