"""Vertical datums: which surface a DEM's heights are measured from, and the geoids that
convert between them.

h (ellipsoidal, above the WGS84 ellipsoid) = H (orthometric, above the geoid) + N, where N is
the geoid undulation. EGM96's comes from the 15' grid shipped in data/egm96_15.tif (made from
the NGA grid by scripts/make_geoid_tif.py); EGM2008's (Copernicus DEM heights) from a grid
the user has (PROJ's us_nga_egm08_25.tif, `find_geoid_grid`), read a window at a time
(`grid_window`, `undulation_on_grid`). Tile stores hold h.
"""

from __future__ import annotations

import enum
import functools
import hashlib
import math
import os
import threading
from collections.abc import Mapping, Sequence
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
    EGM2008 = "egm2008"  # its grid is the user's (`find_geoid_grid`), not shipped

    @property
    def label(self) -> str:
        """How `info` names it."""
        return DATUM_LABELS[self.value]

    def to_ellipsoidal(self, heights: np.ndarray, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Heights on this datum (m) at lon/lat (degrees) -> ellipsoidal heights h (m).
        EGM2008: DemError (one line) when its grid is not on this machine."""
        if self is VerticalDatum.ELLIPSOID:
            return np.asarray(heights, dtype=np.float64)
        return np.asarray(heights, dtype=np.float64) + self._undulation(lon, lat)

    def from_ellipsoidal(self, h: np.ndarray, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Ellipsoidal heights h (m) at lon/lat (degrees) -> heights on this datum (m)."""
        if self is VerticalDatum.ELLIPSOID:
            return np.asarray(h, dtype=np.float64)
        return np.asarray(h, dtype=np.float64) - self._undulation(lon, lat)

    def _undulation(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        if self is VerticalDatum.EGM96:
            return egm96().undulation(lon, lat)
        path = find_geoid_grid(self.value)
        if path is None:
            raise DemError(missing_grid_line(self.value, "these heights", "as given"))
        return _external_geoid(str(path)).undulation(lon, lat)


VDATUM_CHOICES = tuple(d.value for d in VerticalDatum)
#: How people read a datum (`info`, the layer panel).
DATUM_LABELS = {"ellipsoid": "WGS84 ellipsoid", "egm96": "EGM96 geoid", "egm2008": "EGM2008 geoid"}


def parse_vdatum(name: str) -> VerticalDatum:
    """A ``--vdatum`` value -> VerticalDatum; DemError (one line) for anything else."""
    key = name.strip().lower()
    try:
        return VerticalDatum(key)
    except ValueError:
        pass
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


# -- geoid grids that are not shipped (issue #25: sources on several datums in one build) ----

#: Geoid models globeview knows by name whose grids the user supplies: name -> the file
#: PROJ distributes (the 2.5' EGM2008 grid, ~80 MB) and where to get it.
EXTERNAL_GRIDS: dict[str, tuple[str, str]] = {
    "egm2008": ("us_nga_egm08_25.tif", "https://cdn.proj.org/us_nga_egm08_25.tif"),
}
#: ``NAME=PATH`` pairs separated by the OS path separator, read after ``--geoid-grid``.
GEOID_GRIDS_ENV = "GLOBEVIEW_GEOID_GRIDS"


def parse_geoid_grids(texts: Sequence[str]) -> dict[str, Path]:
    """``--geoid-grid`` values (``egm2008=PATH``, or a bare ``PATH`` for EGM2008) -> name ->
    path, each checked (`check_geoid_grid`); DemError (one line) for an unknown model."""
    out: dict[str, Path] = {}
    for text in texts:
        name, sep, path = text.partition("=")
        if not sep:
            name, path = "egm2008", text
        key = name.strip().lower()
        if key not in EXTERNAL_GRIDS:
            known = ", ".join(EXTERNAL_GRIDS)
            raise DemError(f"--geoid-grid {text!r:.80}: unknown geoid {name!r} (known: {known})")
        out[key] = check_geoid_grid(Path(path.strip()), f"--geoid-grid {key}=")
    return out


def check_geoid_grid(path: Path, where: str) -> Path:
    """``path`` when it is a raster GDAL opens on a geographic CRS; DemError (one line,
    ``where`` saying who named it) otherwise."""
    if not path.is_file():
        raise DemError(f"{where}{path}: no such file")
    try:
        with rasterio.open(path) as ds:
            geographic = ds.crs is not None and ds.crs.is_geographic
            b = ds.bounds
    except (rasterio.errors.RasterioError, OSError) as exc:
        raise DemError(f"{where}{path}: not a geoid grid GDAL can read ({exc})") from None
    if not geographic:
        raise DemError(f"{where}{path}: a geoid grid must be on lon/lat (a geographic CRS)")
    # Its cells' outer edges: a node-registered global grid reaches half a cell past the
    # poles (and past +-180, or a cell short of +180 when its columns wrap).
    tol = 1e-6
    if b.top < 90 - tol or b.bottom > -90 + tol or b.right - b.left < 360 - tol:
        raise DemError(
            f"{where}{path}: a geoid grid must cover the globe; this one covers "
            f"{b.left:.6g}..{b.right:.6g} E, {b.bottom:.6g}..{b.top:.6g} N"
        )
    return path


def _env_grids() -> dict[str, Path]:
    out: dict[str, Path] = {}
    for item in os.environ.get(GEOID_GRIDS_ENV, "").split(os.pathsep):
        name, sep, path = item.partition("=")
        if sep and name.strip().lower() in EXTERNAL_GRIDS:
            out[name.strip().lower()] = Path(path.strip())
    return out


def _proj_dirs() -> list[Path]:
    """PROJ's data folders (where projsync and PROJ-data packages put grids)."""
    import pyproj.datadir  # deferred: only asked when a grid is looked for

    dirs = [pyproj.datadir.get_data_dir(), pyproj.datadir.get_user_data_dir()]
    return [Path(p) for d in dirs for p in d.split(os.pathsep) if p]


def find_geoid_grid(name: str, given: Mapping[str, Path] | None = None) -> Path | None:
    """The grid of geoid ``name`` on this machine: ``given`` (``--geoid-grid``), then
    `GEOID_GRIDS_ENV`, then PROJ's data folders (its file name); None when nowhere."""
    if given and name in given:
        return given[name]
    env = _env_grids()
    if name in env:
        return check_geoid_grid(env[name], f"${GEOID_GRIDS_ENV} {name}=")
    file_name = EXTERNAL_GRIDS[name][0]
    for folder in _proj_dirs():
        if (folder / file_name).is_file():
            return folder / file_name
    return None


def missing_grid_line(name: str, source: str, why: str) -> str:
    """The one line saying that ``source``'s heights are on geoid ``name`` and its grid is
    not on this machine, and how to point at one."""
    file_name, url = EXTERNAL_GRIDS[name]
    return (
        f"{source}: heights are on {name.upper()} ({why}) and no {name.upper()} grid is on this "
        f"machine; get {file_name} ({url}) and pass --geoid-grid {name}=PATH, or --vdatum "
        "egm96 to approximate (about 1 m)"
    )


# -- windows of a large geoid grid (the build's per-chunk read, §4.6) -------------------------

#: Windows of external grids kept per process (a chunk task's sources share one or two).
GRID_WINDOW_CACHE = 8


@functools.lru_cache(maxsize=32)
def _grid_header(path: str) -> tuple[int, int, float, float, float, float]:
    """(rows, cols, west node lon, north node lat, dlon, dlat) of a node-registered grid
    (its GDAL transform puts the first node half a cell inside the corner, as `_load`)."""
    try:
        with rasterio.open(path) as ds:
            t, rows, cols = ds.transform, ds.height, ds.width
    except (rasterio.errors.RasterioError, OSError) as exc:
        raise DemError(f"cannot read the geoid grid {path}: {exc}") from None
    dlon, dlat = float(t.a), float(-t.e)
    return rows, cols, t.c + dlon / 2, t.f - dlat / 2, dlon, dlat


@functools.lru_cache(maxsize=GRID_WINDOW_CACHE)
def _read_window(path: str, i0: int, i1: int, j0: int, j1: int) -> np.ndarray:
    from rasterio.windows import Window

    try:
        with rasterio.open(path) as ds:
            return ds.read(1, window=Window(j0, i0, j1 - j0 + 1, i1 - i0 + 1)).astype(np.float64)
    except (rasterio.errors.RasterioError, OSError) as exc:
        raise DemError(f"cannot read the geoid grid {path}: {exc}") from None


def grid_window(path: Path, west: float, south: float, east: float, north: float) -> Geoid:
    """The part of the geoid grid file ``path`` that N on lon west..east, lat south..north
    (degrees; west > east: across the antimeridian) interpolates from, as a `Geoid` with the
    same values there as the whole grid's: only those rows (and columns, unless the window
    crosses the grid's seam) are read, a node of margin each side; the last
    `GRID_WINDOW_CACHE` windows are kept. The 2.5' EGM2008 grid is ~150 MB in memory whole;
    a chunk's window is a few KB."""
    rows, cols, lon0, lat0, dlon, dlat = _grid_header(str(path))
    i0 = max(0, math.floor((lat0 - north) / dlat) - 1)
    i1 = min(rows - 1, math.ceil((lat0 - south) / dlat) + 1)
    i1 = max(i1, min(rows - 1, i0 + 1))
    wraps = abs(cols * dlon - 360.0) < 1e-9
    span = (east - west) % 360.0
    j0 = math.floor(((west - lon0) % 360.0 if wraps else west - lon0) / dlon) - 1
    j1 = j0 + math.ceil(span / dlon) + 3
    if wraps and (j0 < 0 or j1 > cols - 1):  # across the grid's seam: every column
        j0, j1 = 0, cols - 1
    j0, j1 = max(0, j0), min(cols - 1, max(j1, j0 + 1))
    grid = _read_window(str(path), i0, i1, j0, j1)
    return Geoid(grid, lon0 + j0 * dlon, lat0 - i0 * dlat, dlon, dlat)


def _undulation_in_grid_lons(
    path: str, lons: np.ndarray, lats: np.ndarray, lon0: float
) -> np.ndarray:
    """`undulation_on_grid` for one external grid whose first column is at ``lon0``: the
    window's longitudes are taken into [lon0, lon0 + 360) and read in runs that do not
    cross the grid's seam, each run from its own `grid_window` (a few KB)."""
    lons_in = lon0 + np.mod(lons - lon0, 360.0)
    cuts = np.flatnonzero(np.diff(lons_in) < 0) + 1
    out = np.empty((lats.size, lons.size))
    south, north = float(lats.min()), float(lats.max())
    for run in np.split(np.arange(lons.size), cuts):
        part = lons_in[run]
        win = grid_window(Path(path), float(part[0]), south, float(part[-1]), north)
        out[:, run] = win.undulation_grid(part, lats)
    return out


def undulation_on_grid(
    datum: str, grid: str | None, lons: np.ndarray, lats: np.ndarray
) -> np.ndarray:
    """N (m, float64, shape (len(lats), len(lons))) of geoid ``datum`` on the nodes lats x
    lons (1-D, degrees; longitudes increasing, any range): EGM96 from the shipped grid,
    EGM2008 from the grid file ``grid`` (`find_geoid_grid`), only the window these nodes
    need being read; zeros for the ellipsoid."""
    lons = np.asarray(lons, dtype=np.float64).reshape(-1)
    lats = np.asarray(lats, dtype=np.float64).reshape(-1)
    if datum == VerticalDatum.ELLIPSOID.value:
        return np.zeros((lats.size, lons.size))
    if datum == VerticalDatum.EGM96.value:
        return egm96().undulation_grid(lons, lats)
    if grid is None:
        raise DemError(f"no {datum.upper()} grid given to convert heights with")
    lon0 = _grid_header(grid)[2]
    return _undulation_in_grid_lons(grid, lons, lats, lon0)


@functools.lru_cache(maxsize=1)
def _external_geoid(path: str) -> Geoid:
    """A whole external grid (for point queries, `VerticalDatum.to_ellipsoidal`; the build
    reads windows)."""
    rows, cols, lon0, lat0, dlon, dlat = _grid_header(path)
    return Geoid(_read_window(path, 0, rows - 1, 0, cols - 1), lon0, lat0, dlon, dlat)


_sha_cache: dict[tuple[str, int, int], str] = {}


def grid_sha256(path: Path) -> str:
    """sha256 of a geoid grid file (recorded in the store's manifest), remembered per path,
    size and modification time in this process (the 2.5' EGM2008 grid is ~80 MB)."""
    try:
        st = path.stat()
        key = (str(path), st.st_size, st.st_mtime_ns)
        with _lock:
            if key in _sha_cache:
                return _sha_cache[key]
        h = hashlib.sha256()
        with path.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    except OSError as exc:
        raise DemError(f"cannot read the geoid grid {path}: {exc.strerror or exc}") from None
    with _lock:
        _sha_cache[key] = h.hexdigest()
    return _sha_cache[key]
