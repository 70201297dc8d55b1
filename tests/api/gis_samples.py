"""GIS vector files written by GDAL itself (pyogrio's OGR) for the tests: a cross over Mount
Washington in the White Mountains, in several formats and CRSs.

The cross: an east-west line along `ROW_LAT` from `WEST` to `EAST` and a north-south line
along `COLUMN_LON` from `SOUTH` to `NORTH` (degrees, WGS84), each written in the file's CRS.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
from pyogrio.raw import write
from pyproj import Transformer

#: The cross (degrees): the east-west line's latitude and extent, the north-south line's
#: longitude and extent, centred near Mount Washington (-71.3036, 44.2705).
ROW_LAT, WEST, EAST = 44.27, -71.50, -71.10
COLUMN_LON, SOUTH, NORTH = -71.30, 44.12, 44.42
N_VERTICES = 40


def line_wkb(xy: np.ndarray) -> bytes:
    """ISO WKB of a LineString (little endian)."""
    return struct.pack("<BII", 1, 2, len(xy)) + np.asarray(xy, "<f8").tobytes()


def multiline_wkb(parts: list[np.ndarray]) -> bytes:
    return struct.pack("<BII", 1, 5, len(parts)) + b"".join(line_wkb(p) for p in parts)


def point_wkb(x: float, y: float) -> bytes:
    return struct.pack("<BIdd", 1, 1, x, y)


def polygon_wkb(ring: np.ndarray) -> bytes:
    r = np.asarray(ring, "<f8")
    return struct.pack("<BIII", 1, 3, 1, len(r)) + r.tobytes()


def east_west() -> np.ndarray:
    return np.c_[np.linspace(WEST, EAST, N_VERTICES), np.full(N_VERTICES, ROW_LAT)]


def north_south() -> np.ndarray:
    return np.c_[np.full(N_VERTICES, COLUMN_LON), np.linspace(SOUTH, NORTH, N_VERTICES)]


def projected(lonlat: np.ndarray, epsg: int) -> np.ndarray:
    """(N, 2) lon/lat degrees in EPSG:``epsg`` (x, y)."""
    if epsg == 4326:
        return np.asarray(lonlat, np.float64)
    tr = Transformer.from_crs(4326, epsg, always_xy=True)
    x, y = tr.transform(lonlat[:, 0], lonlat[:, 1])
    return np.c_[x, y]


def _write(path: Path, geoms: list, fields: dict, **kw) -> None:
    names = list(fields)
    values = [
        np.asarray(v, dtype=object if isinstance(v[0], str) else None) for v in fields.values()
    ]
    write(str(path), np.array(geoms, dtype=object), values, names, **kw)


def write_gpkg(path: Path, epsg: int = 32619) -> Path:
    """A GeoPackage in EPSG:``epsg`` with two layers: ``roads`` (the east-west line, a
    feature with a broken geometry (a one-vertex line) and one without geometry; fields
    ``name``, ``kind``, ``lanes``) and ``trails`` (the north-south line, ``name``)."""
    one_vertex = struct.pack("<BII", 1, 2, 1) + np.zeros(2, "<f8").tobytes()
    _write(
        path,
        [line_wkb(projected(east_west(), epsg)), one_vertex, None],
        {
            "name": ["Route 302", "broken", "nothing"],
            "kind": ["road", "road", "x"],
            "lanes": [2.0, 4.0, 1.0],
        },
        layer="roads",
        crs=f"EPSG:{epsg}",
        geometry_type="LineString",
        driver="GPKG",
    )
    _write(
        path,
        [line_wkb(projected(north_south(), epsg))],
        {"name": ["Appalachian Trail"]},
        layer="trails",
        crs=f"EPSG:{epsg}",
        geometry_type="LineString",
        driver="GPKG",
        append=True,
    )
    return path


def write_cross(path: Path, driver: str, epsg: int, **kw) -> Path:
    """The whole cross as two line features (fields ``name``, ``kind``) in one layer."""
    _write(
        path,
        [line_wkb(projected(east_west(), epsg)), line_wkb(projected(north_south(), epsg))],
        {"name": ["east-west", "north-south"], "kind": ["road", "trail"]},
        crs=f"EPSG:{epsg}",
        geometry_type="LineString",
        driver=driver,
        **kw,
    )
    return path


def write_gpx(path: Path) -> Path:
    """A GPX file: the cross as one track of two segments (GDAL's GPX driver writes one
    layer per file: no waypoints beside it)."""
    write(
        str(path),
        np.array([multiline_wkb([east_west(), north_south()])], dtype=object),
        [np.array(["Cross"], dtype=object)],
        ["name"],
        layer="tracks",
        crs="EPSG:4326",
        geometry_type="MultiLineString",
        driver="GPX",
    )
    return path
