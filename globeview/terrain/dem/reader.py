"""Reading DEM rasters: metadata (`DemInfo`) and resampled height grids in WGS84 lon/lat.

Any raster GDAL reads, in any CRS, is opened with `open_dem`; `Dem.read_grid` returns heights at
the nodes of a regular geographic grid (longitude/latitude in degrees on WGS84, heights in
metres: the band's scale/offset applied and feet converted), reprojected with
`rasterio.warp.reproject` (lon/lat sources, bilinear: GDAL's kernel as two separable passes,
`globeview.terrain.dem.resample`). Reading is windowed: only the source window a request
needs is read, so rasters larger than RAM can be read window by window.

Quirks of real data handled here (see data/README.md):
- pixel-is-point grids (SRTM, ETOPO5): GDAL already places samples at cell centres, so the
  footprint is GDAL's bounds shrunk by half a cell;
- undeclared fill values (Crater Lake's -32767, a block of -9999 or -999) are detected and
  treated as nodata; +-inf and heights outside MIN_HEIGHT_M..MAX_HEIGHT_M are nodata too and
  counted (`DemInfo.masked_samples`);
- CF grids (GEBCO, ETOPO 2022 netCDF) with lat/lon axes in degrees and no CRS are WGS84;
- complex samples, latitudes beyond +-90 and unusable paths are refused in one line;
- global grids wrap across the antimeridian and grids reaching a pole are extended to it;
- interior voids (nodata surrounded by data) are filled; nodata touching the edge of what was
  read is left as NaN (outside the footprint);
- at the data's edge (nodata or the raster's end), the nodes just past it that the grid cells
  meeting the data need as corners get the surface continued linearly (`read_grid_parts`,
  `globeview.terrain.dem.edge`), so bilinear interpolation between the nodes follows the DEM
  up to its last samples.
"""

from __future__ import annotations

import errno
import math
import os
import re
import stat
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np
import pyproj
import rasterio
import rasterio.errors
import rasterio.features
import rasterio.io
import rasterio.warp
from affine import Affine
from pyproj import Geod
from rasterio.crs import CRS
from rasterio.enums import Resampling
from rasterio.windows import Window

from globeview.errors import DemError
from globeview.terrain.dem.edge import (
    DataCells,
    continuation_rings,
    continue_surface,
    edge_candidates,
)
from globeview.terrain.dem.resample import grid_scales, resample_bilinear
from globeview.terrain.dem.value_scan import native_scan_applies, scan_block
from globeview.terrain.dem.vdatum import DATUM_LABELS, parse_vdatum
from globeview.terrain.interpolate import bilinear

WGS84 = CRS.from_epsg(4326)

# Rasters above this many pixels get their value range from a decimated read.
EXACT_RANGE_MAX_PIXELS = 50_000_000
# Pixels per block when scanning a raster for statistics (bounded memory).
_SCAN_BLOCK_PIXELS = 4_000_000
#: The most blocks `Dem._decimated` reads one by one (a 50 000^2 raster of 512^2 blocks: 9 604);
#: past it the scan is one decimated GDAL read.
_SCAN_MAX_BLOCKS = 40_000
# Target size of the decimated read used for statistics of huge rasters.
_DECIMATED_PIXELS = 4_000_000
# Extra source cells read around a request so void detection sees a void's surroundings.
_VOID_MARGIN = 32
# Physically possible heights on Earth, in metres after scale/offset and vertical units are
# applied: the Challenger Deep is -10 935 m and Everest 8 849 m; the margins allow for
# ellipsoidal vs geoid heights and datum differences. Anything outside (and +-inf) is garbage or
# an undeclared fill: it is treated as nodata and counted in `DemInfo.masked_samples`.
MIN_HEIGHT_M = -12_000.0
MAX_HEIGHT_M = 9_000.0
# Whether the height limits are float32 values (then float32 sources are checked in float32).
_F32_EXACT_LIMITS = bool(
    np.float32(MIN_HEIGHT_M) == MIN_HEIGHT_M and np.float32(MAX_HEIGHT_M) == MAX_HEIGHT_M
)
_LIMITS_TEXT = f"non-finite or outside {MIN_HEIGHT_M:.0f}..{MAX_HEIGHT_M:.0f} m"
# Raw values conventionally used as fill without being declared as nodata (with the dtype's
# extremes): netCDF's default fill and the float extremes included.
_FLT_MAX = float(np.finfo(np.float32).max)
_DBL_MAX = float(np.finfo(np.float64).max)
_COMMON_FILLS = (
    -999.0,
    -9999.0,
    -32767.0,
    -32768.0,
    -99999.0,
    32767.0,
    65535.0,
    9.969209968386869e36,
    -_FLT_MAX,
    _FLT_MAX,
    -_DBL_MAX,
    _DBL_MAX,
)
# A candidate fill that is a possible height (-999 m, -9999 m) is a fill only when it is an
# exact-repeat plateau of at least this many samples...
_MIN_FILL_PLATEAU = 4
# ...lying below (or above) all other data by a gap of at least this many metres and this
# fraction of the data's range: real terrain is continuous, a fill sits apart from it.
_MIN_FILL_GAP_M = 10.0
_MIN_FILL_GAP_FRACTION = 0.02
# Vertical units -> metres per unit (lower-case names as GDAL and PROJ spell them).
_US_FOOT = 1200.0 / 3937.0
_UNIT_FACTORS = {
    "m": 1.0,
    "metre": 1.0,
    "meter": 1.0,
    "metres": 1.0,
    "meters": 1.0,
    "ft": 0.3048,
    "foot": 0.3048,
    "feet": 0.3048,
    "international foot": 0.3048,
    "us survey foot": _US_FOOT,
    "us-ft": _US_FOOT,
    "ftus": _US_FOOT,
    "us_survey_foot": _US_FOOT,
    "dm": 0.1,
    "cm": 0.01,
    "mm": 0.001,
    "km": 1000.0,
}
# CF units of latitude / longitude axes (CF conventions 4.1, 4.2).
_CF_LAT_UNITS = {"degrees_north", "degree_north", "degree_n", "degrees_n", "degreen", "degreesn"}
_CF_LON_UNITS = {"degrees_east", "degree_east", "degree_e", "degrees_e", "degreee", "degreese"}

# Metres per degree on WGS84, used only for approximate resolutions in `DemInfo`.
_GEOD = Geod(ellps="WGS84")


def _metres(v: float) -> str:
    """A length for people: '92.6 m', '3.71 km', '1113 km'."""
    if abs(v) >= 1e6:
        return f"{v / 1000:.0f} km"
    return f"{v / 1000:.3g} km" if abs(v) >= 1000 else f"{v:.3g} m"


@dataclass(frozen=True)
class DemInfo:
    """What a DEM holds. Angles in degrees (WGS84 lon/lat), distances in metres.

    bounds_lonlat is the data footprint (west, south, east, north): where samples are, not where
    GDAL's cells end for pixel-is-point grids. west > east when it crosses the antimeridian.
    """

    path: str
    driver: str
    width: int
    height: int
    band_count: int
    dtype: str
    crs: str
    bounds_lonlat: tuple[float, float, float, float]
    # (dlon, dlat) degrees, approximate for a grid not north-up in lon/lat; for a projected
    # grid the ground cell size (res_m) in degrees of arc of the meridian at the centre (~111
    # km each), which stays finite at a pole where degrees of longitude do not.
    res_deg: tuple[float, float]
    res_m: tuple[float, float]  # (east-west, north-south) at the footprint centre, metres
    nodata: float | None
    fill_value: float | None
    vmin: float
    vmax: float
    range_exact: bool
    vertical_units: str | None
    pixel_is_point: bool
    crosses_antimeridian: bool
    reaches_pole: bool
    wraps_longitude: bool = False  # footprint spans all 360 degrees of longitude
    # Every undeclared fill found (raw values), most frequent first; fill_value is the first.
    fill_values: tuple[float, ...] = ()
    fill_samples: int = 0  # samples holding one of fill_values (from the value scan)
    # Samples treated as nodata because they are +-inf or outside MIN_HEIGHT_M..MAX_HEIGHT_M
    # (after scale/offset and units); declared nodata, NaN and undeclared fills not included.
    # Approximate (from the decimated scan) when range_exact is False.
    masked_samples: int = 0
    crs_assumed: str | None = None  # why the CRS was assumed, e.g. "CF lat/lon axes"
    height_scale_m: float = 1.0  # metres per unit of the stored heights (0.3048 for feet)
    # Pixel size in the raster's projected CRS, in metres (None for geographic CRSs).
    res_crs_m: tuple[float, float] | None = None
    # What the heights are measured from: "egm96" or "egm2008" (orthometric, above that geoid)
    # or "ellipsoid" (above WGS84), and where that came from, e.g. "from the CRS EPSG:5773",
    # "SRTM .hgt default", "Copernicus DEM default", "assumed", "--vdatum" (`_vertical_datum`).
    vertical_datum: str = "egm96"
    vertical_datum_source: str = "assumed"

    def summary(self) -> str:
        """A multi-line description for people."""
        w, s, e, n = self.bounds_lonlat
        if self.height_scale_m != 1.0:
            units = f"m (converted from {self.vertical_units})"
        else:
            units = self.vertical_units or "unknown units (taken as m)"
        approx = "" if self.range_exact else " (approximate, from a decimated read)"
        assumed = f" (assumed from {self.crs_assumed})" if self.crs_assumed else ""
        if self.res_crs_m is not None:
            # Degrees of a projected grid mean little (near a pole one cell spans many
            # degrees of longitude): the grid's own spacing and the ground distance instead.
            res = (
                f"{_metres(self.res_crs_m[0])} x {_metres(self.res_crs_m[1])} (projected grid;"
                f" ~{_metres(self.res_m[0])} x {_metres(self.res_m[1])} on the ground at centre)"
            )
        else:
            res = (
                f"{self.res_deg[0]:.6g} x {self.res_deg[1]:.6g} deg"
                f" (~{_metres(self.res_m[0])} x {_metres(self.res_m[1])} at centre)"
            )
        lines = [
            f"{self.path}",
            f"  format      {self.driver}, {self.width} x {self.height} pixels, {self.dtype}",
            f"  CRS         {self.crs}{assumed}",
            f"  footprint   W {w:.6f}  S {s:.6f}  E {e:.6f}  N {n:.6f} (degrees, WGS84)",
            f"  resolution  {res}",
            f"  registration {'pixel-is-point (grid)' if self.pixel_is_point else 'pixel-is-area'}",
            f"  nodata      {'none declared' if self.nodata is None else _fmt(self.nodata)}",
        ]
        if self.fill_values:
            vals = ", ".join(_fmt(v) for v in self.fill_values)
            label = "fill values" if len(self.fill_values) > 1 else "fill value "
            lines.append(
                f"  {label} {vals} (undeclared; treated as nodata; {self.fill_samples} samples)"
            )
        if self.masked_samples:
            about = "" if self.range_exact else "~"  # counted in the decimated read
            lines.append(f"  masked      {about}{self.masked_samples} samples ({_LIMITS_TEXT})")
        lines.append(f"  heights     {self.vmin:.6g} .. {self.vmax:.6g} {units}{approx}")
        datum = DATUM_LABELS.get(self.vertical_datum, self.vertical_datum)
        lines.append(f"  vdatum      {datum} ({self.vertical_datum_source})")
        if self.band_count > 1:
            lines.append(f"  bands       {self.band_count}; band 1 is used as elevation")
        flags = []
        if self.wraps_longitude:
            flags.append("global in longitude (wraps across the antimeridian)")
        elif self.crosses_antimeridian:
            flags.append("crosses the antimeridian")
        if self.reaches_pole:
            flags.append("reaches a pole")
        if flags:
            lines.append(f"  coverage    {'; '.join(flags)}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, object]:
        """JSON-friendly dict of every field (a NaN nodata becomes the string "nan")."""
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        if d["nodata"] is not None and math.isnan(d["nodata"]):
            d["nodata"] = "nan"
        return d


def _fmt(v: float) -> str:
    """A raw value for people: '-9999', '0.5', '9.96921e+36' (huge integers in g format)."""
    return f"{v:.0f}" if float(v).is_integer() and abs(v) < 1e7 else f"{v:.6g}"


def _short(exc: BaseException) -> str:
    """First line of a rasterio/GDAL message, without GDAL's trailing noise.

    rasterio's "See previous exception for details" points at the GDAL error that explains
    the failure (e.g. a VRT's missing source): that one is shown instead.
    """
    while "previous exception" in str(exc) and (exc.__cause__ or exc.__context__):
        exc = exc.__cause__ or exc.__context__  # type: ignore[assignment]
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


# GDAL connection strings (NETCDF:"f.nc":z, HDF5:..., /vsizip/a.zip/b.tif) name no plain file.
_GDAL_NAME = re.compile(r"^(/vsi[a-z0-9_]+/|[A-Za-z][A-Za-z0-9_]+:)")
# Subdataset prefixes that are not driver names.
_SUBDATASET_PREFIXES = {"HDF4_SDS", "HDF4_EOS", "HDF5", "GTIFF_DIR", "NITF_IM", "NETCDF"}


def _is_gdal_name(text: str) -> bool:
    """Whether a path is a GDAL connection string: /vsi... or DRIVER:... with a prefix GDAL
    knows (a file that merely has a colon in its name is not one)."""
    m = _GDAL_NAME.match(text)
    if not m:
        return False
    if text.startswith("/vsi"):
        return True
    prefix = m.group(1)[:-1].upper()
    with rasterio.Env() as env:
        drivers = {d.upper() for d in env.drivers()}
    return prefix in drivers or prefix in _SUBDATASET_PREFIXES


class NoCrsError(DemError):
    """A DEM file without a coordinate reference system (and none given): the window asks for
    one (`globeview.ui.crs_dialog`), the command line says to pass ``--crs``."""


def check_dem_path(path: Path) -> None:
    """One-line DemError for a path that cannot be a DEM file: missing, a dangling link or a
    link loop, a directory, empty, or not a regular file (a FIFO would block GDAL's open)."""
    if not os.path.lexists(path) and _is_gdal_name(str(path)):
        return
    try:
        st = os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise DemError(f"{path} is a symbolic link loop, not a DEM file") from None
        if os.path.islink(path):
            raise DemError(
                f"DEM file not found: {path} (a symbolic link to {os.readlink(path)},"
                " which does not exist)"
            ) from None
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            raise DemError(f"DEM file not found: {path}") from None
        raise DemError(f"cannot read {path}: {exc.strerror}") from None
    if stat.S_ISDIR(st.st_mode):
        raise DemError(f"{path} is a directory, not a DEM file")
    if not stat.S_ISREG(st.st_mode):
        raise DemError(f"{path} is not a regular file, not a DEM file")
    if st.st_size == 0:
        raise DemError(f"{path} is empty (0 bytes), not a DEM raster")


def parse_crs(text: str) -> CRS:
    """A user's CRS (EPSG:n, WKT, PROJ string) or a one-line DemError.

    Parsed inside a rasterio environment so that PROJ's own "ERROR 1: ..." goes to logging
    instead of stderr: the user sees only the DemError's line.
    """
    try:
        with rasterio.Env():
            return CRS.from_user_input(text)
    except (rasterio.errors.CRSError, ValueError):
        raise DemError(f"unknown CRS {text!r} (use e.g. EPSG:4326 or EPSG:32610)") from None


def _cf_geographic(ds: rasterio.io.DatasetReader) -> bool:
    """Whether the dataset's metadata names CF latitude and longitude axes in degrees
    (GDAL's netCDF driver reports e.g. ``lat#units=degrees_north``)."""
    units = {v.strip().lower() for k, v in ds.tags().items() if k.lower().endswith("#units")}
    return bool(units & _CF_LAT_UNITS) and bool(units & _CF_LON_UNITS)


def _unit_factor(ds: rasterio.io.DatasetReader, crs: CRS) -> tuple[str | None, float]:
    """(declared vertical unit, metres per unit): band 1's unit, else the UNITS tag, else the
    vertical axis of a compound CRS. Undeclared or unrecognised units are taken as metres."""
    units = ds.units[0] if ds.units and ds.units[0] else ds.tags().get("UNITS") or None
    if units:
        name = units.strip().lower()
        # "feet above MSL", "m a.s.l.": the unit is the first word when the whole is unknown
        first = name.split()[0] if name.split() else name
        return units, _UNIT_FACTORS.get(name, _UNIT_FACTORS.get(first, 1.0))
    try:
        pc = pyproj.CRS.from_wkt(crs.to_wkt())
    except pyproj.exceptions.CRSError:
        return None, 1.0
    for sub in pc.sub_crs_list:
        if sub.is_vertical and sub.axis_info:
            ax = sub.axis_info[0]
            return ax.unit_name, float(ax.unit_conversion_factor or 1.0)
    return None, 1.0


# Vertical CRSs that are EGM96 heights (EPSG:5773 "EGM96 height") and EGM2008 heights
# (EPSG:3855 "EGM2008 height").
_EGM96_VERTICAL_EPSG = {5773}
_EGM2008_VERTICAL_EPSG = {3855}
#: Copernicus DEM COG names (GLO-30: _10_, GLO-90: _30_), e.g.
#: Copernicus_DSM_COG_10_N44_00_W072_00_DEM.tif: heights on EGM2008 (the COG's CRS is 2D).
COPERNICUS_NAME = re.compile(
    r"^Copernicus_DSM_COG_(10|30)_([NS])(\d\d)_00_([EW])(\d{3})_00_DEM\.tif$"
)


def _vertical_datum(
    ds: rasterio.io.DatasetReader, crs: CRS, path: Path, override: str | None
) -> tuple[str, str]:
    """(datum, where it came from) for a DEM's heights.

    Order: an explicit --vdatum; the CRS when it says (a geographic 3D CRS such as EPSG:4979
    has ellipsoidal heights; a compound CRS names its vertical CRS); a default per recognised
    source (SRTM .hgt: EGM96; a Copernicus DEM tile name: EGM2008, whose grid the ingest
    needs). Unknown DEMs are taken as EGM96: osgEarth defaults to the ellipsoid, but almost
    every DEM a user has (SRTM, ETOPO, GEBCO, national DEMs) is orthometric, "above sea
    level", and EGM96 is the best approximation of that we ship, within a metre or two of
    national datums; taking them as ellipsoidal would leave them 20..100 m off.
    """
    if override is not None:
        return parse_vdatum(override).value, "--vdatum"
    try:
        pc = pyproj.CRS.from_wkt(crs.to_wkt())
    except pyproj.exceptions.CRSError:
        pc = None
    if pc is not None:
        found = _datum_from_crs(pc)
        if found is not None:
            return found
    if ds.driver == "SRTMHGT" or path.suffix.lower() == ".hgt":
        return "egm96", "SRTM .hgt default"
    if COPERNICUS_NAME.match(path.name):
        return "egm2008", "Copernicus DEM default"
    text = " ".join([path.name, *map(str, ds.tags().values())]).lower()
    if "etopo" in text or "sea level" in text or "msl" in text.split():
        return "egm96", "mean sea level, taken as EGM96"
    return "egm96", "assumed"


#: SRTM tile names (N44W072.hgt) and the sizes of their files (3601^2 and 1201^2 int16).
_SRTM_NAME = re.compile(r"^[NS]\d\d[EW]\d{3}\.hgt$", re.IGNORECASE)
_SRTM_SIZES = {3601 * 3601 * 2: '1"', 1201 * 1201 * 2: '3"'}


def _hgt_size_line(path: Path) -> str | None:
    """Why GDAL cannot open an SRTM-named .hgt, when its size is no SRTM tile's (cut short,
    or another file renamed): the one line saying so; None otherwise."""
    if not _SRTM_NAME.match(path.name):
        return None
    try:
        size = path.stat().st_size
    except OSError:
        return None
    if size in _SRTM_SIZES:
        return None
    return (
        f"{path}: {size} bytes is not an SRTM tile's size (25934402 for 1\", 2884802 for "
        '3"): the file is cut short or not an SRTM .hgt, so its name cannot place it'
    )


def _datum_from_crs(pc: pyproj.CRS) -> tuple[str, str] | None:
    """The vertical datum a CRS declares, or None when it declares none (2D)."""
    if pc.is_compound:
        for sub in pc.sub_crs_list:
            if sub.is_vertical:
                code = sub.to_epsg()
                label = f"EPSG:{code}" if code else repr(sub.name)
                if code in _EGM96_VERTICAL_EPSG or "egm96" in sub.name.lower():
                    return "egm96", f"from the CRS {label}"
                if code in _EGM2008_VERTICAL_EPSG or "egm2008" in sub.name.lower():
                    return "egm2008", f"from the CRS {label}"
                # Another geoid or national datum (NAVD88, EVRF2007, ...): EGM96 is the closest
                # surface we ship (they differ by a metre or two, not the geoid's tens).
                return "egm96", f"from the CRS {label} {sub.name}, approximated by EGM96"
        return None
    if len(pc.axis_info) == 3 and (pc.is_geographic or pc.is_projected or pc.is_geocentric):
        code = pc.to_epsg()
        return "ellipsoid", f"from the CRS {f'EPSG:{code}' if code else repr(pc.name)}"
    return None


@dataclass(frozen=True)
class GridParts:
    """Heights on a grid of nodes (float32 (rows, cols) metres, row 0 north), in two parts
    (`Dem.read_grid_parts`).

    data: the source's heights at the nodes inside its data, NaN elsewhere;
    edge: at the nodes outside the data that are corners of a grid cell meeting it, the
        source's surface continued linearly past its data edge; NaN elsewhere.
    """

    data: np.ndarray
    edge: np.ndarray


def _local_cells(
    cols: np.ndarray, rows: np.ndarray, size: tuple[int, int], step: tuple[float, float]
) -> tuple[float, float] | None:
    """Source cells per node spacing where the source is: (smallest, largest) over the
    neighbouring pairs of an (n, n) grid of sample points (fractional source ``cols``,
    ``rows``; NaN where the CRS has no point) with one point inside the source's ``size``
    (width, height), each pair's distance in cells over the nodes between the two samples
    (``step``: along longitude, along latitude). None where no pair has a point inside."""
    width, height = size
    with np.errstate(invalid="ignore"):
        inside = (cols >= 0) & (cols <= width) & (rows >= 0) & (rows <= height)
    spans = []
    pairs_inside = (inside[:, :-1] | inside[:, 1:], inside[:-1, :] | inside[1:, :])
    for axis, nodes, near in zip((1, 0), step, pairs_inside, strict=True):
        dc, dr = np.diff(cols, axis=axis), np.diff(rows, axis=axis)
        d = np.hypot(dc, dr)[near & np.isfinite(dc) & np.isfinite(dr)] / nodes
        spans.append(d)
    every = np.concatenate(spans)
    if every.size == 0:
        return None
    return float(every.min()), float(every.max())


@dataclass(frozen=True)
class _SourceWindow:
    """Source cells to warp: arr (float32, NaN = no data) and its affine transform in the
    source CRS; node_cells, the grid's node spacing in cells of arr (the larger axis);
    raster_ends, (top, bottom, left, right): whether the raster ends at that side of arr
    (no data beyond it)."""

    arr: np.ndarray
    transform: Affine
    node_cells: float
    raster_ends: tuple[bool, bool, bool, bool]

    def has_edge(self) -> bool:
        """Whether the data ends inside or at the side of the window."""
        return any(self.raster_ends) or bool(np.isnan(self.arr).any())

    def continued_at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """The window's surface continued past its data edge (`continue_surface`), bilinear
        at fractional positions in its pixel coordinates (samples at pixel centres): float64,
        NaN where the continuation does not reach. Past the raster's ends the window grows
        by as many NaN cells as the continuation fills."""
        out = np.full(rows.shape, np.nan)
        # Block by block: a data edge is a line through the window, and a continued cell
        # depends only on the cells within 2 * rings of it, so only a band along the edge is
        # continued instead of the whole window.
        block = 128
        keys = (np.floor(rows / block) * (1 << 20) + np.floor(cols / block)).astype(np.int64)
        for key in np.unique(keys):
            at = np.flatnonzero(keys == key)
            out[at] = self._continued_near(rows[at], cols[at])
        return out

    def _continued_near(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """`continued_at` from the cells around the positions only."""

        rings = continuation_rings(self.node_cells)
        top, bottom, left, right = (rings if end else 0 for end in self.raster_ends)
        h, w = self.arr.shape
        m = 2 * rings + 3  # the cells a continued cell depends on, and the bilinear's
        r0 = max(-top, math.floor(float(rows.min())) - m)
        r1 = min(h + bottom, math.ceil(float(rows.max())) + m + 1)
        c0 = max(-left, math.floor(float(cols.min())) - m)
        c1 = min(w + right, math.ceil(float(cols.max())) + m + 1)
        if r1 <= r0 or c1 <= c0:  # all beyond the continued cells (a far, coarse node)
            return np.full(rows.shape, np.nan)
        crop = np.full((r1 - r0, c1 - c0), np.nan, dtype=np.float32)
        ar0, ar1, ac0, ac1 = max(r0, 0), min(r1, h), max(c0, 0), min(c1, w)
        crop[ar0 - r0 : ar1 - r0, ac0 - c0 : ac1 - c0] = self.arr[ar0:ar1, ac0:ac1]
        cont = continue_surface(crop, rings)
        return bilinear(cont, rows - 0.5 - r0, cols - 0.5 - c0)


class Dem:
    """An open DEM raster (band 1 is elevation). Use `open_dem` to create one.

    The geographic helpers assume a north-up geotransform for geographic CRSs; any other source
    goes through a general reprojection path.
    """

    def __init__(
        self,
        path: Path,
        crs_override: str | None = None,
        vdatum: str | None = None,
        *,
        scan: bool = True,
    ) -> None:
        self.path = path
        self._vdatum_override = vdatum
        self._scan = scan
        check_dem_path(path)
        try:
            with warnings.catch_warnings():
                # A raster without geotransform is reported below as a DemError instead.
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                self._ds = rasterio.open(path)
        except rasterio.errors.RasterioIOError as exc:
            raise DemError(
                _hgt_size_line(path) or f"cannot read {path} as a raster: {_short(exc)}"
            ) from None
        try:
            self._setup(crs_override)
        except BaseException:
            self._ds.close()
            raise

    # ---- opening -------------------------------------------------------------------------

    def _setup(self, crs_override: str | None) -> None:
        ds = self._ds
        self._check_contents()
        t = ds.transform
        if t == Affine.identity():
            if ds.gcps[0]:
                raise DemError(
                    f"{self.path} is georeferenced by ground control points only; warp it to a"
                    " regular grid first (e.g. gdalwarp -t_srs EPSG:4326)"
                )
            raise DemError(f"{self.path} has no georeferencing (no geotransform)")
        if not (abs(t.determinant) > 0 and all(math.isfinite(v) for v in t[:6])):
            raise DemError(f"{self.path} has a degenerate geotransform (zero pixel size): {t[:6]}")
        self.crs_assumed: str | None = None
        if crs_override is not None:
            self.crs = parse_crs(crs_override)
        elif ds.crs is not None and ds.crs.to_wkt():
            self.crs = ds.crs
        elif _cf_geographic(ds):
            # GEBCO, ETOPO 2022 and other CF grids: lat/lon axes in degrees and no grid_mapping.
            self.crs, self.crs_assumed = WGS84, "CF lat/lon axes"
        else:
            raise NoCrsError(
                f"{self.path} has no coordinate reference system; supply one with "
                "--crs EPSG:XXXX (e.g. --crs EPSG:4326 for lon/lat degrees)"
            )
        if ds.width < 2 or ds.height < 2:
            raise DemError(f"{self.path} is {ds.width}x{ds.height} pixels: too small to be a DEM")
        self.transform: Affine = t
        self.nodata: float | None = None if ds.nodata is None else float(ds.nodata)
        self.pixel_is_point = str(ds.tags().get("AREA_OR_POINT", "")).lower() == "point"
        if self.crs.is_geographic:
            self._check_latitudes()
        # Geographic north-up sources get the wrap/pole-aware path.
        self._geo_fast = bool(self.crs.is_geographic) and t.b == 0 and t.d == 0 and t.e < 0
        self.wraps_longitude = self._geo_fast and math.isclose(
            abs(t.a) * ds.width, 360.0, rel_tol=1e-6
        )
        # Stored value -> metres: raw * _scale + _offset (scale/offset and vertical units).
        self.vertical_units, unit_m = _unit_factor(ds, self.crs)
        self.vertical_datum, self.vertical_datum_source = _vertical_datum(
            ds, self.crs, self.path, self._vdatum_override
        )
        self.height_scale_m = unit_m
        self._scale = float(ds.scales[0] if ds.scales else 1.0) * unit_m
        self._offset = float(ds.offsets[0] if ds.offsets else 0.0) * unit_m
        # Header only (planning from footprints, issue #25): no pass over the pixels; the
        # value range is then unknown (NaN) and no fill or masked samples are counted.
        scan = self._scan_values() if self._scan else ((), 0, 0, math.nan, math.nan, False)
        self.fill_values, self.fill_samples, self.masked_samples = scan[:3]
        self.fill_value = self.fill_values[0] if self.fill_values else None
        self.vmin, self.vmax, self.range_exact = scan[3:]
        self._info: DemInfo | None = None
        self._pole_values: dict[float, float] = {}

    def _check_contents(self) -> None:
        """Refuse what has no single real-valued band 1: containers of several grids, complex
        samples, VRTs whose sources are missing."""
        ds = self._ds
        if ds.count == 0:
            subs = ds.subdatasets
            if subs:
                names = ", ".join(subs[:3]) + (", ..." if len(subs) > 3 else "")
                raise DemError(
                    f"{self.path} holds {len(subs)} grids, not one; name the elevation grid,"
                    f" e.g. {names}"
                )
            raise DemError(f"{self.path} has no raster bands")
        if "complex" in ds.dtypes[0]:
            raise DemError(f"{self.path} has complex samples; a DEM needs real heights")
        if ds.driver == "VRT":
            for f in ds.files[1:]:
                if not f.startswith("/vsi") and not os.path.exists(f):
                    raise DemError(f"{self.path} refers to {f}, which does not exist")

    def _check_latitudes(self) -> None:
        """Sample centres of a geographic raster must lie within +-90 degrees of latitude
        (and +-540 of longitude).

        GDAL's edges of a node grid that has rows on the poles (netCDF GEBCO/ETOPO) stick out
        half a cell past +-90: that is fine, the centres are on the poles. Centres beyond mean
        the georeferencing is not lon/lat degrees at all, so the raster is refused rather than
        clipped (clipping would silently place its rows at wrong latitudes).

        Longitudes are taken modulo 360 (a 0..360 grid is common), but centres beyond +-540
        (the overlays' limit too) are no longitude any grid uses: refused the same way.
        """
        ds, t = self._ds, self._ds.transform
        corners = [t @ (c, r) for c in (0.5, ds.width - 0.5) for r in (0.5, ds.height - 0.5)]
        tol = max(1e-9, 1e-6 * math.hypot(t.d, t.e))
        worst = max((y for _, y in corners), key=abs)
        far = max((x for x, _ in corners), key=abs)
        for what, value, limit in (("latitude", worst, 90), ("longitude", far, 540)):
            if not abs(value) <= limit + tol:  # NaN too
                raise DemError(
                    f"{self.path} places samples at {what} {value:.6g}, beyond +-{limit} "
                    f"degrees: its georeferencing is not lon/lat degrees (wrong CRS "
                    f"{_crs_label(self.crs)}? supply one with --crs)"
                )

    def _blocks(self) -> Iterator[Window]:
        rows = max(1, _SCAN_BLOCK_PIXELS // self._ds.width)
        for r0 in range(0, self._ds.height, rows):
            yield Window(0, r0, self._ds.width, min(rows, self._ds.height - r0))

    def _scan_values(self) -> tuple[tuple[float, ...], int, int, float, float, bool]:
        """One pass over band 1: undeclared fills, masked samples and the valid value range.

        Returns (fill values, samples holding them, masked samples, vmin, vmax, exact), the
        range in metres. A candidate (a conventional fill or a dtype extreme) present in the
        data is an undeclared fill when it is not a possible height (it would be masked anyway:
        it is then reported as the fill it is), or when it is an exact-repeat plateau of at
        least `_MIN_FILL_PLATEAU` samples set apart from all other data by a clear gap: -999 in
        a DEM of heights 100..2000 is fill; -999 amid depths reaching -5 000 m, or next to
        -998, is data; a raster of nothing but -9999 is all fill. Values that are only possible
        heights (0, -28, -430) are never candidates, so flat lakes and the Dead Sea stay. A
        dtype extreme that is a possible height (0 of uint16, -128 of int8) is not a candidate
        either: it cannot be told from a real sea level or shallow depth.
        """
        ds = self._ds
        dtype = np.dtype(ds.dtypes[0])
        cands = set(_COMMON_FILLS)
        if dtype.kind in "iu":
            info = np.iinfo(dtype)
            ext = {float(info.min), float(info.max)}
        else:
            ext = {float(np.finfo(dtype).min), float(np.finfo(dtype).max)}
        cands |= {c for c in ext if not self._possible(c)}
        if self.nodata is not None:
            cands.discard(self.nodata)
        cand_arr = np.array(sorted(cands), dtype=np.float64)
        exact = ds.width * ds.height <= EXACT_RANGE_MAX_PIXELS
        # Stored values that are the heights: scanned as stored (terrain/dem/value_scan.py, the
        # same answers without a float64 copy and a pass per candidate).
        native = self._scale == 1.0 and self._offset == 0.0 and native_scan_applies(dtype)
        if exact:
            arrays: Iterator[np.ndarray] = (
                self._read_raw(w, native=native) for w in self._blocks()
            )
        else:
            f = math.sqrt(ds.width * ds.height / _DECIMATED_PIXELS)
            shape = (max(2, int(ds.height / f)), max(2, int(ds.width / f)))
            arrays = self._decimated(shape, native)
        counts = np.zeros(cand_arr.size, dtype=np.int64)
        masked = 0
        lo, hi = math.inf, -math.inf
        for a in arrays:
            if native:
                st = scan_block(a, self.nodata, cand_arr, MIN_HEIGHT_M, MAX_HEIGHT_M)
                counts += st.counts
                masked += st.masked
                lo, hi = min(lo, st.lo), max(hi, st.hi)
                continue
            # NaN is nodata by convention: not counted as masked (integers have none).
            v = a[~np.isnan(a)] if dtype.kind == "f" else a.ravel()
            if self.nodata is not None:
                v = v[v != self.nodata]
            is_c = np.isin(v, cand_arr)
            if cand_arr.size and is_c.any():
                counts += np.count_nonzero(v[is_c, None] == cand_arr[None, :], axis=0)
            h = self._to_metres(v[~is_c])
            ok = (h >= MIN_HEIGHT_M) & (h <= MAX_HEIGHT_M)  # False for +-inf and NaN
            masked += int(h.size - np.count_nonzero(ok))
            if ok.any():
                lo, hi = min(lo, float(h[ok].min())), max(hi, float(h[ok].max()))
        fills: list[tuple[int, float]] = []
        present = [(float(c), int(n)) for c, n in zip(cand_arr, counts, strict=True) if n]
        for c, n in present:
            if not self._possible(c) or self._is_fill_plateau(c, n, lo, hi):
                fills.append((n, c))
        # Candidates that are not fills are real data: they widen the range.
        for c, _n in present:
            if all(c != fc for _, fc in fills):
                h_c = float(self._to_metres(np.array([c]))[0])
                lo, hi = min(lo, h_c), max(hi, h_c)
        if not math.isfinite(lo):
            raise DemError(
                f"{self.path} holds no valid data (every pixel is nodata, a fill, NaN, infinite"
                f" or outside {MIN_HEIGHT_M:.0f}..{MAX_HEIGHT_M:.0f} m)"
            )
        fills.sort(key=lambda nc: (-nc[0], nc[1]))
        fill_values = tuple(c for _, c in fills)
        return fill_values, sum(n for n, _ in fills), masked, lo, hi, exact

    def _decimated(self, shape: tuple[int, int], native: bool) -> Iterator[np.ndarray]:
        """Band 1 read with nearest-neighbour decimation to ``shape`` (rows, cols), in pieces:
        the samples GDAL's decimated read takes (source pixel floor((i + 0.5) * size / n)),
        one block of the raster at a time, so that each block is decompressed once. GDAL's
        own decimated read fetches a row of blocks for every output row: where that row
        outgrows the block cache (the ingest's 96 MB; 98 MB for a 50 000-pixel-wide float32
        raster of 512^2 blocks) every block is decompressed again for each of its sampled
        rows, 16x the CPU. Blocks over `_SCAN_BLOCK_PIXELS` are read GDAL's way."""
        ds = self._ds
        bh, bw = ds.block_shapes[0]
        rows = ((np.arange(shape[0]) + 0.5) * (ds.height / shape[0])).astype(np.int64)
        cols = ((np.arange(shape[1]) + 0.5) * (ds.width / shape[1])).astype(np.int64)
        touched = np.unique(rows // bh).size * np.unique(cols // bw).size
        if bh * bw > _SCAN_BLOCK_PIXELS or touched > _SCAN_MAX_BLOCKS:
            # Few large blocks, or more blocks than reads are worth (a VRT of millions of
            # small blocks, mostly empty, as a hostile 2 000 000-pixel-wide one): GDAL's way.
            yield self._read_raw(None, out_shape=shape, native=native)
            return
        for r0 in range(0, ds.height, bh):
            rr = rows[(rows >= r0) & (rows < r0 + bh)] - r0
            for c0 in range(0, ds.width, bw) if rr.size else ():
                cc = cols[(cols >= c0) & (cols < c0 + bw)] - c0
                if cc.size:
                    win = Window(c0, r0, min(bw, ds.width - c0), min(bh, ds.height - r0))
                    yield self._read_raw(win, native=native)[np.ix_(rr, cc)]

    def _to_metres(self, raw: np.ndarray) -> np.ndarray:
        """Stored values -> heights in metres (scale, offset and vertical units applied)."""
        if self._scale == 1.0 and self._offset == 0.0:
            return raw
        with np.errstate(over="ignore", invalid="ignore"):
            return raw * self._scale + self._offset

    def _possible(self, raw: float) -> bool:
        """Whether a stored value is a physically possible height."""
        h = float(self._to_metres(np.array([raw], dtype=np.float64))[0])
        return MIN_HEIGHT_M <= h <= MAX_HEIGHT_M

    def _is_fill_plateau(self, raw: float, n: int, lo: float, hi: float) -> bool:
        """Whether a possible-height candidate (-999, -9999) present n times is a fill: a
        plateau set apart from the other data's range lo..hi (metres) by a clear gap."""
        if not math.isfinite(lo):
            return True  # nothing else in the raster: all of it is the fill, no terrain
        if n < _MIN_FILL_PLATEAU:
            return False
        h = float(self._to_metres(np.array([raw], dtype=np.float64))[0])
        gap = lo - h if h < lo else h - hi if h > hi else 0.0
        return gap >= max(_MIN_FILL_GAP_M, _MIN_FILL_GAP_FRACTION * (hi - lo))

    def _read_raw(
        self, window: Window | None, out_shape: tuple[int, int] | None = None, native: bool = False
    ) -> np.ndarray:
        """Band 1 as float64 (as stored with ``native``) without any masking (statistics)."""
        try:
            a = self._ds.read(1, window=window, out_shape=out_shape, resampling=Resampling.nearest)
        except rasterio.errors.RasterioError as exc:
            raise DemError(f"{self.path} is corrupt or truncated: {_short(exc)}") from None
        return a if native else a.astype(np.float64, copy=False)

    # ---- metadata ------------------------------------------------------------------------

    @property
    def info(self) -> DemInfo:
        """Metadata and statistics of the raster (computed once)."""
        if self._info is None:
            self._info = self._make_info()
        return self._info

    def _footprint_native(self) -> tuple[float, float, float, float]:
        """(left, bottom, right, top) of where samples are, in the source CRS.

        From the four corners through the geotransform, so rotated and south-up grids get
        their true extent (rasterio's ``bounds`` assume a north-up grid).
        """
        ds = self._ds
        h = 0.5 if self.pixel_is_point else 0.0
        corners = [self.transform @ (c, r) for c in (h, ds.width - h) for r in (h, ds.height - h)]
        xs, ys = zip(*corners)
        return min(xs), min(ys), max(xs), max(ys)

    def _footprint_lonlat(self) -> tuple[float, float, float, float, bool]:
        """(west, south, east, north) of the samples in degrees on WGS84, and whether the
        footprint crosses the antimeridian (west > east, or a grid all the way round)."""
        left, bottom, right, top = self._footprint_native()
        if self._geo_fast:
            if self.wraps_longitude:
                west, east = -180.0, 180.0
            else:
                west, east = _wrap_lon(left), _wrap_lon(right)
                if right - left >= 360.0 - 1e-9:
                    west, east = -180.0, 180.0
                elif west > east and math.isclose(east, -180.0):
                    east = 180.0
                elif west == 180.0 and east > -180.0:
                    west = -180.0
            south, north = max(bottom, -90.0), min(top, 90.0)
            return west, south, east, north, bool(self.wraps_longitude or west > east)
        try:
            west, south, east, north = rasterio.warp.transform_bounds(
                self.crs, WGS84, left, bottom, right, top, densify_pts=21
            )
        except Exception as exc:  # noqa: BLE001  pyproj/GDAL raise several types here
            raise DemError(
                f"cannot place {self.path} on the globe from its CRS: {_short(exc)}"
            ) from None
        return west, south, east, north, bool(west > east)

    def _resolution(
        self, bounds: tuple[float, float, float, float]
    ) -> tuple[tuple[float, float], tuple[float, float]]:
        """(metres, degrees) of a cell at the footprint's centre, from one cell's neighbours
        (a projected cell in degrees of arc of the meridian); DemError when the footprint
        (``bounds``, degrees) or the centre cannot be placed on the globe."""
        ds = self._ds
        cc, cr = ds.width / 2.0, ds.height / 2.0
        xs, ys = zip(*(self.transform @ p for p in ((cc, cr), (cc + 1, cr), (cc, cr + 1))))
        if self._geo_fast:
            lons, lats = list(xs), list(ys)
        else:
            lons, lats = rasterio.warp.transform(self.crs, WGS84, list(xs), list(ys))
        bounds_ok = all(math.isfinite(v) for v in bounds)
        if not (bounds_ok and all(math.isfinite(v) and abs(v) <= 90.0 for v in lats)):
            # PROJ gives inf for coordinates outside the CRS's domain (a UTM easting of 1e9).
            raise DemError(
                f"cannot place {self.path} on the globe: its coordinates are outside what"
                f" {_crs_label(self.crs)} can map (wrong CRS? supply one with --crs)"
            )
        _, _, dist_x = _GEOD.inv(lons[0], lats[0], lons[1], lats[1])
        _, _, dist_y = _GEOD.inv(lons[0], lats[0], lons[2], lats[2])
        res_m = (float(dist_x), float(dist_y))
        if self._geo_fast:
            return res_m, (abs(self.transform.a), abs(self.transform.e))
        lat_c = math.radians(lats[0])
        # metres per degree of latitude / longitude on WGS84 (series to O(e^2))
        m_lat = 111_132.954 - 559.822 * math.cos(2 * lat_c)
        # A rotated or south-up lon/lat grid keeps degrees of longitude. A projected cell has a
        # ground size, not a longitude span: degrees of longitude per metre grow without bound
        # toward a pole (a cell there read as 1e9 degrees), so both sides are in degrees of
        # arc of the meridian instead.
        m_lon = max(111_412.84 * math.cos(lat_c), 1e-6) if self.crs.is_geographic else m_lat
        return res_m, (res_m[0] / m_lon, res_m[1] / m_lat)

    def _make_info(self) -> DemInfo:
        ds = self._ds
        west, south, east, north, crosses = self._footprint_lonlat()
        res_m, res_deg = self._resolution((west, south, east, north))
        dy = res_deg[1]
        reaches_pole = north >= 90.0 - dy * 1.0001 or south <= -90.0 + dy * 1.0001
        crs_txt = _crs_label(self.crs)
        res_crs_m = None
        if not self.crs.is_geographic:
            t = self.transform
            unit = float(self.crs.linear_units_factor[1]) if self.crs.linear_units else 1.0
            res_crs_m = (math.hypot(t.a, t.d) * unit, math.hypot(t.b, t.e) * unit)
        return DemInfo(
            path=str(self.path),
            driver=ds.driver,
            width=ds.width,
            height=ds.height,
            band_count=ds.count,
            dtype=ds.dtypes[0],
            crs=crs_txt,
            bounds_lonlat=(float(west), float(south), float(east), float(north)),
            res_deg=(float(res_deg[0]), float(res_deg[1])),
            res_m=res_m,
            nodata=self.nodata,
            fill_value=self.fill_value,
            vmin=self.vmin,
            vmax=self.vmax,
            range_exact=self.range_exact,
            vertical_units=self.vertical_units,
            pixel_is_point=self.pixel_is_point,
            crosses_antimeridian=bool(crosses),
            reaches_pole=bool(reaches_pole),
            wraps_longitude=bool(self.wraps_longitude),
            fill_values=self.fill_values,
            fill_samples=self.fill_samples,
            masked_samples=self.masked_samples,
            crs_assumed=self.crs_assumed,
            height_scale_m=self.height_scale_m,
            res_crs_m=res_crs_m,
            vertical_datum=self.vertical_datum,
            vertical_datum_source=self.vertical_datum_source,
        )

    # ---- reading -------------------------------------------------------------------------

    def read_grid(
        self,
        west: float,
        north: float,
        dlon: float,
        dlat: float,
        width: int,
        height: int,
        resampling: str = "bilinear",
    ) -> np.ndarray:
        """Heights at the nodes lon = west + i*dlon, lat = north - j*dlat (WGS84 degrees).

        Returns float32 (height, width), row j / column i: the source's heights where it has
        data and, at the other corners of the grid cells that meet its data, its surface
        continued past the data edge (`read_grid_parts`); NaN elsewhere. Only the source window
        the grid needs is read.
        """
        parts = self.read_grid_parts(west, north, dlon, dlat, width, height, resampling)
        return np.where(np.isnan(parts.data), parts.edge, parts.data)

    def read_grid_parts(
        self,
        west: float,
        north: float,
        dlon: float,
        dlat: float,
        width: int,
        height: int,
        resampling: str = "bilinear",
    ) -> GridParts:
        """`read_grid` in two parts: the nodes inside the source's data, and the nodes just
        beyond it that bilinear interpolation between the nodes needs.

        A node is inside the data where GDAL's warp gives it a value (the source cell holding
        it has data); ``data`` is that warp, NaN elsewhere. ``edge`` holds the other corners
        of every grid cell that meets the source's data (a source cell whose four samples are
        data, overlapped with positive area): there, the source's surface continued linearly
        past its data edge (`globeview.terrain.dem.edge`). With them, bilinear interpolation
        between the nodes follows the source up to its last samples instead of ramping to
        whatever lies beyond over the last node spacing (issue #29). The parts are separate
        so that a caller combining sources (ingest) lets one source's data win over another's
        edge.
        """
        if width < 1 or height < 1 or not (dlon > 0 and dlat > 0):
            raise ValueError("read_grid needs width, height >= 1 and dlon, dlat > 0")
        try:
            rs = Resampling[resampling]
        except KeyError:
            raise DemError(f"unknown resampling {resampling!r}") from None
        shape = (height, width)
        data: np.ndarray | None = None
        # Destination cells centred on the nodes.
        dst_t = Affine(dlon, 0.0, west - dlon / 2.0, 0.0, -dlat, north + dlat / 2.0)
        windows = self._source_windows(west, north, dlon, dlat, width, height)
        for src, k in windows:
            piece = self._warp(src.arr, src.transform, dst_t, shape, rs, k)
            if data is None:
                # A new float32 array of its own: what copying it into all-NaN nodes gives.
                data = piece
            else:
                np.copyto(data, piece, where=np.isnan(data))
        if data is None:
            data = np.full(shape, np.nan, dtype=np.float32)
        edge = np.full(shape, np.nan, dtype=np.float32)
        for src, k in windows:
            if src.has_edge():
                self._continue_edge(src, k, data, edge, (west, north, dlon, dlat))
        if self._geo_fast and self.wraps_longitude:
            self._set_pole_rows(data, north, dlat)
        return GridParts(data, edge)

    def _source_windows(
        self, west: float, north: float, dlon: float, dlat: float, width: int, height: int
    ) -> list[tuple[_SourceWindow, float]]:
        """The source windows the nodes need, each with its longitude shift (degrees)."""
        lon0, lon1 = west, west + (width - 1) * dlon
        lat1, lat0 = north, north - (height - 1) * dlat
        if not self._geo_fast:
            src = self._projected_source(lon0, lon1, lat0, lat1, dlon, dlat)
            return [] if src is None else [(src, 0.0)]
        windows = []
        # A regional source may use 0..360 longitudes or cross the antimeridian.
        for k in [0.0] if self.wraps_longitude else [-360.0, 0.0, 360.0]:
            src = self._geo_source(lon0 + k, lon1 + k, lat0, lat1, dlon, dlat)
            if src is not None:
                windows.append((src, k))
        return windows

    def _continue_edge(
        self,
        src: _SourceWindow,
        lon_shift: float,
        data: np.ndarray,
        edge: np.ndarray,
        grid: tuple[float, float, float, float],
    ) -> None:
        """Fill in place the nodes of ``edge`` (NaN in ``data`` and ``edge``) that are a corner
        of a grid cell meeting the data of this source window (with positive area) with its
        surface continued past its data edge, bilinear at the node. ``grid``: (west, north,
        dlon, dlat) of the nodes, degrees; ``lon_shift`` moves them into the source's frame."""
        west, north, dlon, dlat = grid
        rows, cols = edge_candidates(data)
        free = np.isnan(edge[rows, cols])  # not filled by another window already
        rows, cols = rows[free], cols[free]
        if rows.size == 0:
            return
        # Each candidate and its 8 neighbours, (n, 3, 3): the corners of its 4 cells.
        dr, dc = np.mgrid[-1:2, -1:2]
        lon = west + lon_shift + (cols[:, None, None] + dc) * dlon
        lat = north - (rows[:, None, None] + dr) * dlat
        px, py = self._pixel_positions(src, lon, lat)
        # Points the source's CRS has no place for (a polar stereographic source's opposite
        # pole) are nowhere near its data: their candidates are left out.
        placed = np.isfinite(px).all(axis=(1, 2)) & np.isfinite(py).all(axis=(1, 2))
        if not placed.all():
            rows, cols, px, py = rows[placed], cols[placed], px[placed], py[placed]
        # Far ones (near that pole) can be beyond int64 in pixels: clipped to a frame a few
        # times the window's, which keeps every corner box's overlap with the window as is.
        far = 4.0 * (max(src.arr.shape) + 4)
        px, py = np.clip(px, -far, far), np.clip(py, -far, far)
        cells = DataCells(src.arr)
        needed = np.zeros(rows.size, dtype=bool)
        for i, j in ((0, 0), (0, 1), (1, 0), (1, 1)):
            needed |= cells.meet(px[:, i : i + 2, j : j + 2], py[:, i : i + 2, j : j + 2])
        if not needed.any():
            return
        values = src.continued_at(py[needed, 1, 1], px[needed, 1, 1])
        edge[rows[needed], cols[needed]] = values.astype(np.float32)

    def _pixel_positions(
        self, src: _SourceWindow, lon: np.ndarray, lat: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (column, row) pixel coordinates in ``src`` of points (degrees; in the
        source's longitude frame for a geographic source). For a projected source a point
        past a pole (a neighbour of a node on the pole row: latitude beyond +-90) is the point
        across it, at latitude +-180 - lat and longitude + 180: PROJ refuses such latitudes
        (a polar stereographic DEM's coarse levels failed with "stere: Invalid latitude")."""
        x, y = lon, lat
        if not self._geo_fast:
            past = np.abs(lat) > 90.0
            if past.any():
                lat = np.where(past, np.copysign(180.0, lat) - lat, lat)
                lon = np.where(past, lon + 180.0, lon)
            with np.errstate(all="ignore"):
                xs, ys = rasterio.warp.transform(WGS84, self.crs, lon.ravel(), lat.ravel())
            x = np.asarray(xs, dtype=np.float64).reshape(lon.shape)
            y = np.asarray(ys, dtype=np.float64).reshape(lat.shape)
        col, row = ~src.transform @ (x, y)
        return np.asarray(col, dtype=np.float64), np.asarray(row, dtype=np.float64)

    def _set_pole_rows(self, out: np.ndarray, north: float, dlat: float) -> None:
        """Give the nodes at lat +-90 one value each: a pole is a single point.

        The value is the mean of the source's edge row, so every window of a global grid agrees
        on it. Only for sources spanning all longitudes (a sector's edge row is not the pole's
        neighbourhood).
        """
        lats = north - np.arange(out.shape[0]) * dlat
        for pole, row in ((90.0, 0), (-90.0, self._ds.height - 1)):
            at_pole = np.isclose(lats, pole, rtol=0.0, atol=1e-9)
            if not at_pole.any() or not self._reaches(pole):
                continue
            if pole not in self._pole_values:
                edge = self._read_window(Window(0, row, self._ds.width, 1), 1)
                ok = np.isfinite(edge)
                self._pole_values[pole] = float(edge[ok].mean()) if ok.any() else np.nan
            out[at_pole, :] = self._pole_values[pole]

    def _reaches(self, pole: float) -> bool:
        """Whether the source's samples come within one cell of the pole (+90 or -90 deg)."""
        t, dy = self.transform, abs(self.transform.e)
        half = dy / 2.0 if self.pixel_is_point else 0.0
        if pole > 0:
            return t.f - half >= 90.0 - dy * 1.0001
        return t.f - self._ds.height * dy + half <= -90.0 + dy * 1.0001

    def _warp(
        self,
        arr: np.ndarray,
        src_t: Affine,
        dst_t: Affine,
        shape: tuple[int, int],
        rs: Resampling,
        lon_shift: float,
    ) -> np.ndarray:
        # Shift the destination into the source's longitude frame (0..360 sources etc.).
        if lon_shift:
            dst_t = Affine.translation(lon_shift, 0.0) @ dst_t
        # The kernel's scales from the grids, not from the window: every window of a level
        # gives a node the same value (terrain/dem/resample.py).
        scales = self._kernel_scales(src_t, dst_t)
        if self._geo_fast and rs == Resampling.bilinear:
            # GDAL's bilinear warp between two lon/lat grids as two separable passes: its
            # values within 1 ulp of float32, 3-4x less CPU (terrain/dem/resample.py).
            return resample_bilinear(arr, src_t, dst_t, shape, scales)
        dst = np.full(shape, np.nan, dtype=np.float32)
        src_crs = self.crs
        dst_crs = self.crs if self._geo_fast else WGS84
        # For geographic sources the grid is in the source datum; the datum shift between
        # geographic CRSs is metres, well below a cell of any DEM this path is used for.
        rasterio.warp.reproject(
            arr,
            dst,
            src_transform=src_t,
            src_crs=src_crs,
            dst_transform=dst_t,
            dst_crs=dst_crs,
            resampling=rs,
            src_nodata=np.nan,
            dst_nodata=np.nan,
            # GDAL's warp options (rasterio passes extra keywords as such): one resampling
            # factor for every warp piece of every window (GDAL otherwise derives it from
            # each piece's own source window).
            XSCALE=repr(scales[0]),
            YSCALE=repr(scales[1]),
        )
        return dst

    def _kernel_scales(self, src_t: Affine, dst_t: Affine) -> tuple[float, float]:
        """The warp kernel's scales (x, y) for destination cells of ``dst_t`` (degrees): the
        source's pixel size over the node spacing (`resample.grid_scales`), the same for
        every window of a level. Lon/lat sources: the source's pixel times the read
        decimation (`_decimation`: a function of the spacing). Others: the window's pixel
        over the node spacing mapped into the source CRS at the source's centre (one point
        per source, so no window moves it)."""
        dlon, dlat = dst_t.a, -dst_t.e
        if self._geo_fast:
            t = self.transform
            f = self._decimation(dlon, dlat, t.a, -t.e)
            return grid_scales((f * t.a, f * t.e), (dlon, dlat))
        step_x, step_y = self._projected_steps(dlon, dlat)
        pixel = (math.hypot(src_t.a, src_t.d), math.hypot(src_t.b, src_t.e))
        return grid_scales(pixel, (step_x, step_y))

    def _projected_steps(self, dlon: float, dlat: float) -> tuple[float, float]:
        """Lengths (source CRS units) of a step of ``dlon`` east and of ``dlat`` south at the
        centre of the source's raster; cached per spacing."""
        cache: dict[tuple[float, float], tuple[float, float]] = self.__dict__.setdefault(
            "_steps", {}
        )
        if (dlon, dlat) not in cache:
            ds = self._ds
            cx, cy = self.transform @ (ds.width / 2.0, ds.height / 2.0)
            (lon,), (lat,) = rasterio.warp.transform(self.crs, WGS84, [cx], [cy])
            lat = min(max(lat, -89.0), 89.0)
            xs, ys = rasterio.warp.transform(
                WGS84, self.crs, [lon, lon + dlon, lon], [lat, lat, lat - dlat]
            )
            east = math.hypot(xs[1] - xs[0], ys[1] - ys[0])
            south = math.hypot(xs[2] - xs[0], ys[2] - ys[0])
            cache[(dlon, dlat)] = (east, south)
        return cache[(dlon, dlat)]

    def _decimation(self, dlon_src: float, dlat_src: float, dx: float, dy: float) -> int:
        """Integer read decimation when the request is much coarser than the source."""
        f = min(dlon_src / dx, dlat_src / dy) / 2.0
        return max(1, int(f))

    def _geo_source(
        self, lon0: float, lon1: float, lat0: float, lat1: float, dlon: float, dlat: float
    ) -> _SourceWindow | None:
        """Source window (with wrap and pole padding) covering the nodes, in source lon/lat."""
        t = self.transform
        ds = self._ds
        dx, dy = t.a, -t.e
        pad = 3 + _VOID_MARGIN
        c0 = math.floor((lon0 - t.c) / dx - 0.5) - pad
        c1 = math.ceil((lon1 - t.c) / dx - 0.5) + pad + 1
        r0 = math.floor((t.f - lat1) / dy - 0.5) - pad
        r1 = math.ceil((t.f - lat0) / dy - 0.5) + pad + 1
        cc0, cc1 = (c0, c1) if self.wraps_longitude else (max(c0, 0), min(c1, ds.width))
        if cc1 <= cc0:
            return None
        # Rows: read what exists, then extend the edge rows if the source reaches a pole.
        rr0, rr1 = max(r0, 0), min(r1, ds.height)
        if rr1 <= rr0:
            return None
        north_pole, south_pole = self._reaches(90.0), self._reaches(-90.0)
        f = self._decimation(dlon, dlat, dx, dy)
        # Column segments (wrap: modulo width), read separately and concatenated.
        pieces = []
        c = cc0
        while c < cc1:
            seg0 = c % ds.width
            n = min(cc1 - c, ds.width - seg0)
            pieces.append(self._read_window(Window(seg0, rr0, n, rr1 - rr0), f))
            c += n
        arr = np.concatenate(pieces, axis=1) if len(pieces) > 1 else pieces[0]
        arr = self._clean(arr)
        # Decimation may round sizes: compute the effective cell size of what was read.
        sx = (cc1 - cc0) * dx / arr.shape[1]
        sy = (rr1 - rr0) * dy / arr.shape[0]
        top = t.f - rr0 * dy
        n_top = math.ceil((rr0 - r0) * dy / sy) if (north_pole and r0 < rr0) else 0
        n_bot = math.ceil((r1 - rr1) * dy / sy) if (south_pole and r1 > rr1) else 0
        if n_top or n_bot:
            # Extend the edge rows past the pole so the pole nodes get values (not NaN).
            arr = np.pad(arr, ((n_top, n_bot), (0, 0)), mode="edge")
            top += n_top * sy
        # Where the window was cut short by the raster's end (not past a pole), the data ends.
        ends = (r0 < rr0 and not n_top, r1 > rr1 and not n_bot, c0 < cc0, c1 > cc1)
        win_t = Affine(sx, 0.0, t.c + cc0 * dx, 0.0, -sy, top)
        return _SourceWindow(arr, win_t, max(dlon / sx, dlat / sy), ends)

    def _projected_source(
        self, lon0: float, lon1: float, lat0: float, lat1: float, dlon: float, dlat: float
    ) -> _SourceWindow | None:
        """Source window covering the nodes for a non-geographic (or rotated) source."""
        ds = self._ds
        n = 21
        lons = np.linspace(lon0 - dlon, lon1 + dlon, n)
        lats = np.clip(np.linspace(lat0 - dlat, lat1 + dlat, n), -90.0, 90.0)
        glon, glat = np.meshgrid(lons, lats)
        with np.errstate(all="ignore"):
            xs, ys = rasterio.warp.transform(WGS84, self.crs, glon.ravel(), glat.ravel())
        xs, ys = np.asarray(xs), np.asarray(ys)
        ok = np.isfinite(xs) & np.isfinite(ys)
        if not ok.any():
            return None
        inv = ~self.transform
        grid_cols, grid_rows = inv @ (np.where(ok, xs, np.nan), np.where(ok, ys, np.nan))
        cols, rows = np.asarray(grid_cols)[ok], np.asarray(grid_rows)[ok]
        pad = 3 + _VOID_MARGIN
        # The sampled nodes bound the window only approximately: pad by a tenth of its span.
        span_c = float(cols.max() - cols.min()) / 10.0
        span_r = float(rows.max() - rows.min()) / 10.0
        c0 = math.floor(cols.min() - span_c) - pad
        c1 = math.ceil(cols.max() + span_c) + pad + 1
        r0 = math.floor(rows.min() - span_r) - pad
        r1 = math.ceil(rows.max() + span_r) + pad + 1
        cc0, cc1, rr0, rr1 = max(0, c0), min(ds.width, c1), max(0, r0), min(ds.height, r1)
        if cc1 <= cc0 or rr1 <= rr0:
            return None
        # Source cells per destination cell, from the node spacing mapped into the source.
        nodes_x = max(1, (lon1 - lon0) / dlon + 2)
        nodes_y = max(1, (lat1 - lat0) / dlat + 2)
        cells_x = (cols.max() - cols.min()) / nodes_x
        cells_y = (rows.max() - rows.min()) / nodes_y
        shape = (n, n)
        near = _local_cells(
            np.asarray(grid_cols).reshape(shape),
            np.asarray(grid_rows).reshape(shape),
            (ds.width, ds.height),
            (nodes_x / (n - 1), nodes_y / (n - 1)),
        )
        # The whole window's spread can overstate the scale where the source is: a polar
        # stereographic DEM seen from a hemisphere-wide window (coarse levels) maps the far
        # latitudes to huge distances, and its read was decimated to one averaged pixel. Where
        # the two agree within 2x (near-linear projections) the spread decides, as before.
        node_span = None  # the largest spacing near the source, where that decides
        if near is not None and near[0] < 0.5 * min(cells_x, cells_y):
            cells_x = cells_y = near[0]
            node_span = near[1]
        f = max(1, int(min(cells_x, cells_y) / 2.0))
        arr = self._clean(self._read_window(Window(cc0, rr0, cc1 - cc0, rr1 - rr0), f))
        sx, sy = (cc1 - cc0) / arr.shape[1], (rr1 - rr0) / arr.shape[0]
        win_t = self.transform @ Affine.translation(cc0, rr0) @ Affine.scale(sx, sy)
        ends = (r0 < rr0, r1 > rr1, c0 < cc0, c1 > cc1)
        if node_span is None:
            node_cells = max(cells_x / sx, cells_y / sy)
        else:
            node_cells = node_span / min(sx, sy)
        return _SourceWindow(arr, win_t, float(node_cells), ends)

    def _read_window(self, window: Window, f: int) -> np.ndarray:
        """Band 1 of a window as float32 metres, decimated by f; nodata, undeclared fills,
        +-inf and impossible heights as NaN."""
        shape = (max(1, math.ceil(window.height / f)), max(1, math.ceil(window.width / f)))
        # Averaging would mix a fill or a garbage value into real heights: use nearest then.
        clean = not self.fill_values and not self.masked_samples
        rs = Resampling.average if (f > 1 and clean) else Resampling.nearest
        try:
            a = self._ds.read(1, window=window, out_shape=shape, resampling=rs, masked=True)
        except rasterio.errors.RasterioError as exc:
            raise DemError(f"{self.path} is corrupt or truncated: {_short(exc)}") from None
        if (
            a.dtype == np.float32
            and not self.fill_values
            and self._scale == 1.0
            and self._offset == 0.0
            and _F32_EXACT_LIMITS
        ):
            # Float32 metres need no float64 round trip: float32 -> float64 -> float32 is exact
            # and the limits are float32 values, so the float32 comparisons decide alike (the
            # same array bit for bit; NaN written as the same canonical NaN). 4x less time.
            h32 = a.filled(np.float32(np.nan))
            h32[~((h32 >= np.float32(MIN_HEIGHT_M)) & (h32 <= np.float32(MAX_HEIGHT_M)))] = np.nan
            return h32
        raw = a.astype(np.float64).filled(np.nan)
        if self.fill_values:
            raw[np.isin(raw, self.fill_values)] = np.nan
        h = self._to_metres(raw)
        h[~((h >= MIN_HEIGHT_M) & (h <= MAX_HEIGHT_M))] = np.nan
        return h.astype(np.float32)

    def _clean(self, arr: np.ndarray) -> np.ndarray:
        """Fill interior voids: NaN regions that do not touch the edge of what was read."""
        void = np.isnan(arr)
        if not void.any() or void.all():
            return arr
        h, w = arr.shape
        shapes = rasterio.features.shapes(
            void.astype(np.uint8), mask=void, connectivity=4, transform=Affine.identity()
        )
        interior = []
        for geom, _ in shapes:
            ring = np.asarray(geom["coordinates"][0])
            x0, y0 = ring.min(axis=0)
            x1, y1 = ring.max(axis=0)
            if x0 > 0 and y0 > 0 and x1 < w and y1 < h:
                interior.append(geom)
        if not interior:
            return arr
        fill_mask = rasterio.features.rasterize(
            ((g, 1) for g in interior), out_shape=arr.shape, dtype=np.uint8
        ).astype(bool)
        valid = ~void
        # Here: rasterio.fill imports numpy.ma (~0.1 s), which opening a store never needs.
        from rasterio.fill import fillnodata

        filled = fillnodata(
            np.where(valid, arr, 0.0).astype(np.float32),
            mask=valid.astype(np.uint8),
            max_search_distance=float(max(h, w)),
            smoothing_iterations=0,
        )
        return np.where(fill_mask, filled, arr).astype(np.float32)

    # ---- pickling (ingest tasks in other threads, processes, cluster workers) -------------

    def __getstate__(self) -> dict[str, object]:
        """Everything but the open dataset: the value scan's results and the metadata travel
        (a few KB), so a copy reopens the file without scanning it again."""
        self.info  # noqa: B018  computed once here, not in every copy
        return {k: v for k, v in self.__dict__.items() if k != "_ds"}

    def __setstate__(self, state: dict[str, object]) -> None:
        """Reopen the file (its own GDAL handle: datasets are not thread-safe)."""
        self.__dict__.update(state)
        self._pole_values = dict(self._pole_values)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                self._ds = rasterio.open(self.path)
        except rasterio.errors.RasterioIOError as exc:
            raise DemError(f"cannot read {self.path} as a raster: {_short(exc)}") from None

    # ---- context manager ----------------------------------------------------------------

    def close(self) -> None:
        """Close the underlying dataset."""
        self._ds.close()

    def __enter__(self) -> Dem:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _crs_label(crs: CRS) -> str:
    """'EPSG:n' when the CRS has an EPSG code, else its name."""
    epsg = crs.to_epsg()
    if epsg:
        return f"EPSG:{epsg}"
    try:
        return pyproj.CRS.from_wkt(crs.to_wkt()).name
    except pyproj.exceptions.CRSError:
        return crs.to_string()


def _wrap_lon(lon: float) -> float:
    """Longitude in degrees folded into [-180, 180)."""
    return ((lon + 180.0) % 360.0) - 180.0


def open_dem(
    path: str | Path, crs: str | None = None, vdatum: str | None = None, *, scan: bool = True
) -> Dem:
    """Open a DEM raster (band 1 = elevation); `crs` overrides or supplies its CRS, `vdatum`
    ("ellipsoid", "egm96" or "egm2008") its vertical datum. ``scan=False`` reads the header only (no
    pass over the pixels: ``info`` then has a NaN value range and no fill counts), for
    planning from footprints.

    Raises DemError with a one-line message for anything that cannot be used as a DEM.
    """
    return Dem(Path(path), crs, vdatum, scan=scan)
