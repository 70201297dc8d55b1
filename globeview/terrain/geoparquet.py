"""GeoParquet files through pyarrow, for a GDAL without its Parquet driver (pyogrio's wheel).

A GeoParquet file is one layer (named by the file's stem): the rows' attribute columns and a
geometry column named by the file's ``geo`` metadata (``primary_column``), WKB-encoded,
in the CRS its PROJJSON ``crs`` gives (absent: OGC:CRS84, lon/lat degrees; ``null``: an
undefined CRS, read as lon/lat only when the coordinates fit). `read_geoparquet` gives the
rows' WKB, CRS and columns; `globeview.terrain.ogr_vectors` puts the WKB through the same
decoding and reprojection as pyogrio's, so a GeoParquet file draws as a GeoPackage would.

pyarrow is optional (``pip install 'globeview[gis-parquet]'``); without it, and for a file
that is not GeoParquet, a geometry encoding other than WKB (GeoArrow's native ``point``,
``linestring``...), or more features than a layer holds: one `GeoParquetError` line.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from globeview.errors import GlobeviewError

__all__ = [
    "INSTALL_HINT",
    "GeoParquetError",
    "GeoParquetRows",
    "geoparquet_fields",
    "geoparquet_layers",
    "is_geoparquet_path",
    "read_geoparquet",
]

#: What the one line says when pyarrow is missing.
INSTALL_HINT = "pip install 'globeview[gis-parquet]'"
#: The CRS of a GeoParquet column without a ``crs`` key (the GeoParquet specification's).
DEFAULT_CRS = "OGC:CRS84"


class GeoParquetError(GlobeviewError):
    """A GeoParquet file cannot be read (one line)."""


@dataclass(frozen=True)
class GeoParquetRows:
    """A GeoParquet file's rows: ``name`` (the file's stem), ``wkb`` one geometry (or None)
    per row, ``crs`` the geometry's CRS as text pyproj reads (None: undefined), and
    ``attributes`` the asked columns (field -> (rows,) values, None/NaN where missing)."""

    name: str
    wkb: list[bytes | None]
    crs: str | None
    attributes: dict[str, np.ndarray]


def _first_line(exc: BaseException) -> str:
    text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return text if len(text) <= 160 else text[:157] + "..."


def is_geoparquet_path(path: str | Path) -> bool:
    """Whether ``path`` is named as a (Geo)Parquet file (``.parquet``, ``.geoparquet``)."""
    return Path(path).suffix.lower() in (".parquet", ".geoparquet")


def _pq() -> Any:
    try:
        import pyarrow.parquet as pq  # type: ignore[import-untyped,import-not-found,unused-ignore]
    except ImportError:
        raise GeoParquetError(f"reading GeoParquet needs pyarrow: {INSTALL_HINT}") from None
    return pq


def _schema(p: Path) -> Any:
    """The file's Arrow schema (one line for a file that is not Parquet)."""
    pq = _pq()
    try:
        return pq.read_schema(p)
    except Exception as exc:  # noqa: BLE001  pyarrow raises many types: the file's one line
        raise GeoParquetError(f"{p.name}: not a Parquet file ({_first_line(exc)})") from None


def _geo(p: Path, schema: Any) -> tuple[str, dict[str, Any]]:
    """(geometry column, its ``geo`` metadata entry), checked: one line for a Parquet file
    without GeoParquet metadata or with a geometry encoding other than WKB."""
    raw = (schema.metadata or {}).get(b"geo")
    if raw is None:
        raise GeoParquetError(f"{p.name}: a Parquet file without GeoParquet ('geo') metadata")
    try:
        geo = json.loads(raw)
        column = str(geo["primary_column"])
        meta = geo["columns"][column]
        encoding = str(meta.get("encoding", ""))
    except (ValueError, KeyError, TypeError, AttributeError):
        raise GeoParquetError(f"{p.name}: its GeoParquet ('geo') metadata is malformed") from None
    if encoding.upper() != "WKB":
        raise GeoParquetError(
            f"{p.name}: geometry column {column!r:.60} is encoded as {encoding!r:.40}; "
            "globeview reads WKB-encoded GeoParquet (write it with geometry_encoding='WKB')"
        )
    if column not in schema.names:
        raise GeoParquetError(f"{p.name}: no geometry column {column!r:.60} in the file")
    return column, meta


def geoparquet_layers(path: str | Path) -> list[tuple[str, str]]:
    """The file's one layer: (its stem, geometry types from the metadata or "Unknown")."""
    p = Path(path)
    _, meta = _geo(p, _schema(p))
    types = meta.get("geometry_types")
    kinds = ", ".join(str(t) for t in types) if isinstance(types, list) and types else ""
    return [(p.stem, kinds or "Unknown")]


def geoparquet_fields(path: str | Path) -> list[str]:
    """The attribute columns (every column but the geometry ones)."""
    p = Path(path)
    schema = _schema(p)
    _geo(p, schema)
    geo = json.loads(schema.metadata[b"geo"])
    geometry = set(geo.get("columns", {}))
    return [str(n) for n in schema.names if n not in geometry]


def _crs_text(meta: dict[str, Any]) -> str | None:
    """The column's CRS as text pyproj reads (PROJJSON), the default, or None (undefined)."""
    if "crs" not in meta:
        return DEFAULT_CRS
    crs = meta["crs"]
    if crs is None:
        return None
    return json.dumps(crs) if isinstance(crs, dict) else str(crs)


def read_geoparquet(
    path: str | Path, fields: Sequence[str] = (), max_rows: int = 2_000_000
) -> GeoParquetRows:
    """The file's rows with the attribute columns ``fields`` (see the module docstring);
    `GeoParquetError` (one line) for bad input and more than ``max_rows`` rows."""
    p = Path(path)
    pq = _pq()
    schema = _schema(p)
    column, meta = _geo(p, schema)
    have = geoparquet_fields(p)
    missing = [f for f in fields if f not in have]
    if missing:
        raise GeoParquetError(
            f"{p.name}: no field {missing[0]!r:.60} (fields: {', '.join(have)[:200] or 'none'})"
        )
    try:
        rows = int(pq.ParquetFile(p).metadata.num_rows)
        if rows > max_rows:
            raise GeoParquetError(f"{p.name}: {rows:,} features (at most {max_rows:,})")
        table = pq.read_table(p, columns=[*dict.fromkeys(fields), column])
        blobs = table.column(column).to_pylist()
    except GeoParquetError:
        raise
    except Exception as exc:  # noqa: BLE001  as in _schema
        raise GeoParquetError(f"{p.name}: cannot read it ({_first_line(exc)})") from None
    if not all(b is None or isinstance(b, bytes) for b in blobs):
        raise GeoParquetError(f"{p.name}: geometry column {column!r:.60} is not WKB bytes")
    attributes = {
        f: np.asarray(table.column(f).to_numpy(zero_copy_only=False)) for f in dict.fromkeys(fields)
    }
    return GeoParquetRows(p.stem, blobs, _crs_text(meta), attributes)
