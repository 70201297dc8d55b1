"""Vertical datums: which surface a DEM's heights are measured from, and the EGM96 geoid that
converts between them.

h (ellipsoidal, above the WGS84 ellipsoid) = H (orthometric, above the geoid) + N, where N is
the geoid undulation, read from the EGM96 15' grid shipped in data/egm96_15.tif (made from the
NGA grid by scripts/make_geoid_tif.py). Tile stores hold h.
"""

from __future__ import annotations

import enum
import hashlib
import threading
from pathlib import Path

import numpy as np
import rasterio

from globeview.errors import DemError
from globeview.geodesy.geoid import Geoid
from globeview.terrain.dem.data import EMBEDDED_DATA_DIR

GEOID_FILE = "egm96_15.tif"


class VerticalDatum(enum.Enum):
    """A DEM's vertical datum, by the name used on the command line (``--vdatum``)."""

    ELLIPSOID = "ellipsoid"
    EGM96 = "egm96"

    @property
    def label(self) -> str:
        """How `info` names it."""
        return "WGS84 ellipsoid" if self is VerticalDatum.ELLIPSOID else "EGM96 geoid"

    def to_ellipsoidal(self, heights: np.ndarray, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Heights on this datum (m) at lon/lat (degrees) -> ellipsoidal heights h (m)."""
        if self is VerticalDatum.ELLIPSOID:
            return np.asarray(heights, dtype=np.float64)
        return np.asarray(heights, dtype=np.float64) + egm96().undulation(lon, lat)

    def from_ellipsoidal(self, h: np.ndarray, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Ellipsoidal heights h (m) at lon/lat (degrees) -> heights on this datum (m)."""
        if self is VerticalDatum.ELLIPSOID:
            return np.asarray(h, dtype=np.float64)
        return np.asarray(h, dtype=np.float64) - egm96().undulation(lon, lat)


VDATUM_CHOICES = tuple(d.value for d in VerticalDatum)
# Datums people ask for that globeview knows of but does not ship a grid for.
_NOT_SHIPPED = {"egm2008": "its grid is not shipped with globeview"}


def parse_vdatum(name: str) -> VerticalDatum:
    """A ``--vdatum`` value -> VerticalDatum; DemError (one line) for anything else."""
    key = name.strip().lower()
    try:
        return VerticalDatum(key)
    except ValueError:
        pass
    if key in _NOT_SHIPPED:
        raise DemError(
            f"vertical datum {name!r} is not available ({_NOT_SHIPPED[key]}); "
            f"use one of {', '.join(VDATUM_CHOICES)}"
        )
    raise DemError(f"unknown vertical datum {name!r}: use one of {', '.join(VDATUM_CHOICES)}")


def to_ellipsoidal(H: np.ndarray, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Orthometric (EGM96) heights H (m) at lon/lat (degrees) -> h = H + N (m)."""
    return VerticalDatum.EGM96.to_ellipsoidal(H, lon, lat)


def to_orthometric(h: np.ndarray, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Ellipsoidal heights h (m) at lon/lat (degrees) -> H = h - N (m, above EGM96)."""
    return VerticalDatum.EGM96.from_ellipsoidal(h, lon, lat)


def geoid_path() -> Path:
    """The shipped EGM96 grid (the same data folder as the embedded DEMs)."""
    return EMBEDDED_DATA_DIR / GEOID_FILE


_lock = threading.Lock()
_cache: dict[str, object] = {}


def egm96() -> Geoid:
    """The EGM96 geoid, loaded from data/egm96_15.tif once per process (thread-safe)."""
    with _lock:
        geoid = _cache.get("geoid")
        if geoid is None:
            geoid = _load(geoid_path())
            _cache["geoid"] = geoid
        return geoid  # type: ignore[return-value]


def egm96_sha256() -> str:
    """sha256 of the shipped geoid file, recorded in store manifests."""
    with _lock:
        digest = _cache.get("sha256")
        if digest is None:
            try:
                digest = hashlib.sha256(geoid_path().read_bytes()).hexdigest()
            except OSError as exc:
                raise DemError(
                    f"cannot read the EGM96 geoid {geoid_path()}: {exc.strerror or exc}"
                ) from None
            _cache["sha256"] = digest
        return digest  # type: ignore[return-value]


def _load(path: Path) -> Geoid:
    """Read a node-registered geoid grid; its GDAL transform puts the first node half a cell
    inside the top-left corner."""
    try:
        with rasterio.open(path) as ds:
            grid = ds.read(1)
            t = ds.transform
    except (rasterio.errors.RasterioError, OSError) as exc:
        raise DemError(f"cannot read the EGM96 geoid {path}: {exc}") from None
    dlon, dlat = float(t.a), float(-t.e)
    return Geoid(grid, t.c + dlon / 2, t.f - dlat / 2, dlon, dlat)
