"""GIS vector files through GDAL/OGR (pyogrio): Shapefile, GeoPackage, KML/KMZ, GPX,
FlatGeobuf, GeoParquet and any other OGR source. GeoParquet goes through GDAL's Parquet
driver where pyogrio's GDAL has it, else through pyarrow (`globeview.terrain.geoparquet`).

- `vector_layers(path)`: the file's layers (name, geometry type), one line when OGR cannot
  open it as vectors.
- `read_vector_features(path, layer, fields)`: one layer's drawable geometry as WGS84 lon/lat
  degrees (reprojected from any CRS with pyproj, x/y in the traditional GIS order) plus the
  asked attribute columns, one value per feature. Without a ``layer`` the first layer with
  features is read, and a GPX file's waypoints, routes and tracks together.

Bad input is one `VectorError` line: a file OGR does not read, an unknown layer or field, a
layer with more features or vertices than a globe layer holds, a file without a CRS (or with
one PROJ does not know) whose coordinates are not lon/lat degrees. A CRS that is missing or
unknown but whose coordinates fit lon/lat degrees is read as WGS84 with one warning line; broken
geometries are skipped and counted in one warning line (logger ``globeview.vectors``).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from globeview.errors import GlobeviewError
from globeview.terrain.wkb import Decoded, decode_wkb

__all__ = [
    "MAX_FEATURES",
    "MAX_VERTICES",
    "VectorFeatures",
    "VectorFileError",
    "layer_fields",
    "read_vector_features",
    "vector_layers",
]

log = logging.getLogger("globeview.vectors")

#: Most features of one layer read onto the globe (a billion-feature file is refused before
#: anything is read).
MAX_FEATURES = 2_000_000
#: Most vertices of one layer (the overlay layer's own input limit).
MAX_VERTICES = 5_000_000
#: GPX layers read together when no layer is named (the *_points layers repeat the tracks).
_GPX_LAYERS = ("waypoints", "routes", "tracks")


class VectorFileError(GlobeviewError):
    """A GIS vector file cannot be shown (one line)."""


@dataclass
class VectorFeatures:
    """One layer's features in WGS84 degrees.

    Attributes:
        name: the layer's name in the file ("" for single-layer formats' only layer).
        count: features read (``attributes`` columns have this length).
        lines: `Decoded`-style line parts, lon/lat degrees: ``line_xy`` (N, 2), ``line_starts``,
            ``line_feature``, ``line_outer``; points ``point_xy`` (M, 2) and ``point_feature``.
        attributes: field name -> (count,) values (object or numeric arrays; None/NaN where
            a feature has no value).
        broken: features skipped because their geometry cannot be drawn.
    """

    name: str
    count: int
    geometry: Decoded
    attributes: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def broken(self) -> int:
        return self.geometry.broken


def _pyogrio() -> Any:
    import pyogrio  # deferred: GDAL loads only when a vector file is opened

    return pyogrio


def _first_line(exc: BaseException) -> str:
    text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return text if len(text) <= 160 else text[:157] + "..."


def vector_layers(path: str | Path) -> list[tuple[str, str]]:
    """(layer name, geometry type) of every layer OGR finds in ``path``; `VectorFileError`
    (one line) when OGR cannot open it as a vector file."""
    p = Path(path)
    if _through_pyarrow(p):
        from globeview.terrain.geoparquet import geoparquet_layers

        return geoparquet_layers(p)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rows = _pyogrio().list_layers(p)
    except Exception as exc:  # noqa: BLE001  pyogrio/GDAL raise many types: the file's one line
        raise VectorFileError(
            f"{p.name}: not a vector file OGR reads ({_first_line(exc)})"
        ) from None
    layers = [(str(r[0]), str(r[1])) for r in rows]
    if not layers:
        raise VectorFileError(f"{p.name}: no vector layer in the file")
    return layers


def _has_driver(name: str) -> bool:
    return name in _pyogrio().list_drivers()


def _through_pyarrow(p: Path) -> bool:
    """Whether ``p`` is GeoParquet that GDAL cannot read here (pyogrio's wheel has no Parquet
    driver): pyarrow reads it."""
    from globeview.terrain.geoparquet import is_geoparquet_path

    return is_geoparquet_path(p) and not _has_driver("Parquet")


def _info(p: Path, layer: str) -> dict[str, Any]:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            info: dict[str, Any] = _pyogrio().read_info(p, layer=layer, force_feature_count=True)
    except Exception as exc:  # noqa: BLE001  as in vector_layers
        raise VectorFileError(
            f"{p.name}: cannot read layer {layer!r} ({_first_line(exc)})"
        ) from None
    return info


def _chosen_layers(p: Path, layer: str | None) -> list[str]:
    """The layers to read: the one named, else the first with features (GPX: all of
    waypoints, routes and tracks that have features)."""
    layers = vector_layers(p)
    names = [n for n, _ in layers]
    if layer is not None:
        if layer not in names:
            raise VectorFileError(
                f"{p.name}: no layer {layer!r:.60} (layers: {', '.join(names)[:200]})"
            )
        return [layer]
    if _through_pyarrow(p):  # one layer; its features are counted when it is read
        return names
    counts = {n: int(_info(p, n).get("features", 0) or 0) for n in names}
    gpx = [n for n in _GPX_LAYERS if counts.get(n, 0) > 0]
    if gpx and set(_GPX_LAYERS) <= set(names):
        return gpx
    with_features = [n for n in names if counts[n] != 0]
    if not with_features:
        raise VectorFileError(f"{p.name}: no features in any layer ({', '.join(names)[:200]})")
    return with_features[:1]


def layer_fields(path: str | Path, layer: str | None = None) -> list[str]:
    """The attribute fields of the layer `read_vector_features` reads (of several GPX
    layers, those they all have)."""
    p = Path(path)
    chosen = _chosen_layers(p, layer)
    if _through_pyarrow(p):
        from globeview.terrain.geoparquet import geoparquet_fields

        return geoparquet_fields(p)
    fields = [[str(f) for f in _info(p, name).get("fields", [])] for name in chosen]
    return [f for f in fields[0] if all(f in other for other in fields[1:])]


def read_vector_features(
    path: str | Path, layer: str | None = None, fields: Sequence[str] = ()
) -> VectorFeatures:
    """Read one layer of ``path`` (or the default, see the module docstring) as lon/lat
    degrees with the attribute columns ``fields``; see the module docstring for errors."""
    p = Path(path)
    chosen = _chosen_layers(p, layer)
    if _through_pyarrow(p):
        return _read_geoparquet(p, fields)
    parts = [_read_layer(p, name, list(dict.fromkeys(fields))) for name in chosen]
    return parts[0] if len(parts) == 1 else _merge(parts)


def _read_layer(p: Path, layer: str, fields: list[str]) -> VectorFeatures:
    info = _info(p, layer)
    n = int(info.get("features", 0) or 0)
    if n > MAX_FEATURES:
        raise VectorFileError(
            f"{p.name}: layer {layer!r:.60} has {n:,} features (at most {MAX_FEATURES:,})"
        )
    have = [str(f) for f in info.get("fields", [])]
    missing = [f for f in fields if f not in have]
    if missing:
        raise VectorFileError(
            f"{p.name}: no field {missing[0]!r:.60} in layer {layer!r:.60} "
            f"(fields: {', '.join(have)[:200] or 'none'})"
        )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            meta, _, wkb, values = _pyogrio().raw.read(
                p, layer=layer, columns=fields, force_2d=True, encoding=None
            )
    except Exception as exc:  # noqa: BLE001  as in vector_layers
        raise VectorFileError(
            f"{p.name}: cannot read layer {layer!r} ({_first_line(exc)})"
        ) from None
    blobs: Sequence[bytes | None] = [] if wkb is None else wkb
    geometry = decode_wkb(blobs)
    total = len(geometry.line_xy) + len(geometry.point_xy)
    if total > MAX_VERTICES:
        raise VectorFileError(
            f"{p.name}: layer {layer!r:.60} has {total:,} vertices (at most {MAX_VERTICES:,})"
        )
    _to_lonlat(p, meta.get("crs"), geometry)
    # pyogrio returns the columns in the layer's order, whatever order they were asked in.
    names = [str(f) for f in meta.get("fields", [])]
    attributes = {f: np.asarray(v) for f, v in zip(names, values, strict=True)}
    return VectorFeatures(layer, len(blobs), geometry, attributes)


def _read_geoparquet(p: Path, fields: Sequence[str]) -> VectorFeatures:
    """A GeoParquet file's features through pyarrow: its WKB decoded and reprojected as
    pyogrio's is."""
    from globeview.terrain.geoparquet import read_geoparquet

    rows = read_geoparquet(p, fields, MAX_FEATURES)
    geometry = decode_wkb(rows.wkb)
    total = len(geometry.line_xy) + len(geometry.point_xy)
    if total > MAX_VERTICES:
        raise VectorFileError(f"{p.name}: {total:,} vertices (at most {MAX_VERTICES:,})")
    _to_lonlat(p, rows.crs, geometry)
    return VectorFeatures(rows.name, len(rows.wkb), geometry, rows.attributes)


def _fits_lonlat(g: Decoded) -> bool:
    xy = np.concatenate([g.line_xy, g.point_xy])
    return bool(len(xy)) and bool(
        (np.abs(xy[:, 0]) <= 360.0).all() and (np.abs(xy[:, 1]) <= 90.0).all()
    )


def _to_lonlat(p: Path, crs_text: str | None, g: Decoded) -> None:
    """Reproject ``g`` in place to WGS84 lon/lat degrees; features with a vertex that does
    not reproject (outside the CRS's area) or lands off the globe (latitude past 90 degrees,
    longitude past 540) are dropped and counted as broken."""
    transformer = _transformer_to_wgs84(crs_text)
    if transformer is None:
        what = f"unknown CRS {crs_text!r:.60}" if crs_text else "no CRS"
        if not _fits_lonlat(g):
            raise VectorFileError(
                f"{p.name}: {what}, and the coordinates are not lon/lat degrees "
                "(give the file its CRS, e.g. a .prj beside a Shapefile)"
            )
        log.warning("%s: %s; its coordinates fit lon/lat degrees: read as WGS84", p.name, what)
        return
    if transformer is not _IDENTITY:
        for xy in (g.line_xy, g.point_xy):
            if len(xy):
                lon, lat = transformer.transform(xy[:, 0], xy[:, 1])
                xy[:, 0], xy[:, 1] = lon, lat
    _drop_off_globe(g)


#: `_transformer_to_wgs84`'s answer for a file already in WGS84 lon/lat.
_IDENTITY: Any = object()


def _transformer_to_wgs84(crs_text: str | None) -> Any:
    """A pyproj Transformer from ``crs_text`` to WGS84 lon/lat, `_IDENTITY` when it is WGS84
    already, None when PROJ does not know the CRS or cannot transform it (a LOCAL_CS, an
    engineering CRS): the caller then tells lon/lat coordinates from others."""
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError, ProjError

    if not crs_text:
        return None
    try:
        crs = CRS.from_user_input(crs_text)
        if crs.equals("EPSG:4326") or crs.equals("OGC:CRS84"):
            return _IDENTITY
        return Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    except (CRSError, ProjError):
        return None


def _drop_off_globe(g: Decoded) -> None:
    """Drop every feature with a vertex that is not finite (did not reproject) or lies off
    the globe (|latitude| > 90 or |longitude| > 540 degrees, the overlays' limit)."""
    for xy in (g.line_xy, g.point_xy):
        if len(xy):
            off = (np.abs(xy[:, 1]) > 90.0) | (np.abs(xy[:, 0]) > 540.0)
            xy[off] = np.inf
    _drop_non_finite(g)


def _drop_non_finite(g: Decoded) -> None:
    """Drop every part of a feature with a vertex that did not reproject (inf)."""
    bad_vertex = ~np.isfinite(g.line_xy).all(axis=1)
    bad_features: set[int] = set()
    if bad_vertex.any():
        part_of = np.repeat(np.arange(len(g.line_feature)), np.diff(g.line_starts))
        bad_features |= set(g.line_feature[np.unique(part_of[bad_vertex])].tolist())
    bad_point = ~np.isfinite(g.point_xy).all(axis=1)
    bad_features |= set(g.point_feature[bad_point].tolist())
    if not bad_features:
        return
    bad = np.array(sorted(bad_features), np.int64)
    keep_part = ~np.isin(g.line_feature, bad)
    lengths = np.diff(g.line_starts)[keep_part]
    keep_vertex = np.repeat(keep_part, np.diff(g.line_starts))
    g.line_xy = g.line_xy[keep_vertex]
    g.line_starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    g.line_feature = g.line_feature[keep_part]
    g.line_outer = g.line_outer[keep_part]
    keep_point = ~np.isin(g.point_feature, bad)
    g.point_xy = g.point_xy[keep_point]
    g.point_feature = g.point_feature[keep_point]
    g.broken += len(bad)


def _merge(layers: list[VectorFeatures]) -> VectorFeatures:
    """Several layers' features as one (GPX waypoints, routes and tracks)."""
    offset = 0
    lines, starts, lf, lo, pts, pf = [], [np.zeros(1, np.int64)], [], [], [], []
    vertex_offset = 0
    for ly in layers:
        g = ly.geometry
        lines.append(g.line_xy)
        starts.append(g.line_starts[1:] + vertex_offset)
        vertex_offset += len(g.line_xy)
        lf.append(g.line_feature + offset)
        lo.append(g.line_outer)
        pts.append(g.point_xy)
        pf.append(g.point_feature + offset)
        offset += ly.count
    merged = Decoded(
        np.concatenate(lines),
        np.concatenate(starts),
        np.concatenate(lf),
        np.concatenate(lo),
        np.concatenate(pts),
        np.concatenate(pf),
        sum(ly.geometry.broken for ly in layers),
        sum(ly.geometry.empty for ly in layers),
    )
    attributes = {
        k: np.concatenate([np.asarray(ly.attributes[k], object) for ly in layers])
        for k in layers[0].attributes
    }
    return VectorFeatures("+".join(ly.name for ly in layers), offset, merged, attributes)
