"""Where each source of an ingest has data, without reading its pixels (issue #25, §4.1).

A planet build names 14 277 SRTM tiles (or ~26 000 Copernicus ones): planning it must not
open them all, let alone scan them. A source's footprint comes from one of two places:

- its **name** (no open; one ``stat`` for the size): SRTM ``N44W072.hgt`` is the 1 x 1
  degree cell whose south-west corner is 44 N 72 W, 1" or 3" by the file size (25 934 402
  or 2 884 802 bytes: 3601^2 or 1201^2 big-endian int16; any other size is read from the
  header); Copernicus ``Copernicus_DSM_COG_10_N44_00_W072_00_DEM.tif`` the same cell at 1"
  (``_10_``, GLO-30) or 3" (``_30_``, GLO-90) of latitude. A name footprint is the cell grown
  by one source pixel on each side (longitude pixels of Copernicus tiles widen past 50
  degrees of latitude), so it contains the samples whether the grid is pixel-is-point or
  pixel-is-area;
- its **header** (`open_dem` with ``scan=False``: transform, CRS, bounds, resolution,
  datum; a few ms a file), on up to 16 threads with a progress bar for thousands of files.

``footprints(..., how="auto")``, the default, takes the name where it is recognised and the
header otherwise. Why names: a header open is ~1 ms locally but tens of ms on a network
filesystem or object store, so 14 k headers cost 15 s to minutes of planning, where names
cost 0.1 s; and the name footprint is an upper bound (grown by a pixel), so the plan it
makes holds every chunk the data reaches (a few more along the edges at most). The build
compares the header with the name when it reads the source (`check_name_footprint`): a file
renamed to the wrong cell is one error line, not a misplaced tile. ``how="header"`` reads
every header (files named like SRTM that are not), ``how="name"`` requires recognised names.

Vertical datums: SRTM .hgt heights are EGM96 ("SRTM .hgt default"), Copernicus DEM heights
EGM2008 ("Copernicus DEM default", also when the footprint comes from the header: the COG
declares a 2D CRS only); others as `open_dem` says (CRS, else assumed EGM96). ``--vdatum``
overrides all.

The result is a `FootprintTable`: numpy columns, ~100 bytes a source.
"""

from __future__ import annotations

import math
import os
import re
import stat
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from globeview.errors import DemError
from globeview.terrain.dem.reader import COPERNICUS_NAME, check_dem_path, open_dem
from globeview.terrain.dem.vdatum import parse_vdatum
from globeview.terrain.store.schema import MAX_LEVEL_LIMIT

__all__ = [
    "COPERNICUS_NAME",
    "DATUMS",
    "FOOTPRINT_MODES",
    "SRTM_NAME",
    "FootprintTable",
    "check_name_footprint",
    "footprints",
    "footprints_from_names",
    "is_tile_name",
    "natural_levels",
    "table_from_bounds",
]

#: Vertical datum codes of `FootprintTable.datum` (index into this tuple).
DATUMS = ("ellipsoid", "egm96", "egm2008")
#: Codes of `FootprintTable.how`.
HOW = ("name", "header")
#: ``--footprints``: where footprints come from (see the module docstring).
FOOTPRINT_MODES = ("auto", "name", "header")

#: SRTM tile names (NASA's and USGS's downloads), e.g. N44W072.hgt.
SRTM_NAME = re.compile(r"^([NS])(\d\d)([EW])(\d{3})\.hgt$", re.IGNORECASE)
#: .hgt file size (bytes) -> pixel size (degrees): 3601^2 and 1201^2 int16 samples.
SRTM_SIZES = {3601 * 3601 * 2: 1.0 / 3600.0, 1201 * 1201 * 2: 3.0 / 3600.0}
#: Copernicus DEM longitude pixel widening by |latitude| band (upper bound of the band,
#: degrees -> factor): product handbook, "grid spacing".
_COP_LON_FACTORS = ((50, 1.0), (60, 1.5), (70, 2.0), (80, 3.0), (85, 5.0), (90, 10.0))

_KIND_OTHER, _KIND_SRTM, _KIND_COP = 0, 1, 2
_WHY = {
    _KIND_SRTM: ("egm96", "SRTM .hgt default"),
    _KIND_COP: ("egm2008", "Copernicus DEM default"),
}
_HEADER_THREADS = 16


@dataclass(frozen=True)
class FootprintTable:
    """The footprints of an ingest's sources, in input order (numpy columns, one row a
    source).

    west, south, east, north: degrees on WGS84 where the source has samples (west > east:
    across the antimeridian; a name footprint is grown by one pixel); res: the smaller pixel
    side (degrees; projected sources: degrees of arc; what the natural level and the fill
    order go by, as in the build); reach: the larger pixel side (how far past its footprint
    a source is read, `tasks.fill_reads_source`); extent: the footprint's smaller side
    (degrees, for `natural_levels`); wraps: a grid all the way round; datum: index into
    `DATUMS`; how: index into `HOW`; datum_why: where each datum came from (for people).
    """

    paths: tuple[str, ...]
    west: np.ndarray
    south: np.ndarray
    east: np.ndarray
    north: np.ndarray
    res: np.ndarray
    reach: np.ndarray
    extent: np.ndarray
    wraps: np.ndarray
    datum: np.ndarray
    how: np.ndarray
    datum_why: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.paths)

    def levels(self, tile_n: int) -> np.ndarray:
        """Each source's natural finest level at ``tile_n`` (int64, `natural_levels`)."""
        return natural_levels(self.res, self.extent, tile_n)

    def datum_counts(self) -> dict[tuple[str, str], int]:
        """(datum, why) -> number of sources, in first-seen order."""
        out: dict[tuple[str, str], int] = {}
        for code, why in zip(self.datum.tolist(), self.datum_why, strict=True):
            key = (DATUMS[code], why)
            out[key] = out.get(key, 0) + 1
        return out

    def first_with_datum(self, datum: str) -> str | None:
        """The path of the first source on ``datum`` (None: none is)."""
        hits = np.flatnonzero(self.datum == DATUMS.index(datum))
        return self.paths[int(hits[0])] if hits.size else None


def table_from_bounds(
    paths: Sequence[str],
    bounds: Sequence[tuple[float, float, float, float]],
    res: Sequence[float],
    reach: Sequence[float],
    wraps: Sequence[bool],
    datums: Sequence[str],
) -> FootprintTable:
    """A FootprintTable from footprints already known (an opened source's ``DemInfo``:
    bounds_lonlat, min and max of res_deg, wraps_longitude, vertical_datum), e.g. for a
    build that has opened its sources: ``plan_chunks(table_from_bounds(...), tile_n)``."""
    b = np.asarray(bounds, dtype=np.float64).reshape(len(paths), 4)
    wr = np.asarray(wraps, dtype=bool)
    width = np.where(wr, 360.0, (b[:, 2] - b[:, 0]) % 360.0)
    width = np.where(width == 0, 360.0, width)
    return FootprintTable(
        paths=tuple(map(str, paths)),
        west=b[:, 0],
        south=b[:, 1],
        east=b[:, 2],
        north=b[:, 3],
        res=np.asarray(res, dtype=np.float64),
        reach=np.asarray(reach, dtype=np.float64),
        extent=np.minimum(width, b[:, 3] - b[:, 1]),
        wraps=wr,
        datum=np.array([DATUMS.index(d) for d in datums], dtype=np.int8),
        how=np.ones(len(paths), dtype=np.int8),
        datum_why=("header",) * len(paths),
    )


def natural_levels(res: np.ndarray, extent: np.ndarray, tile_n: int) -> np.ndarray:
    """The level whose node spacing 180/2^L/2^tile_n is nearest each pixel size ``res``
    (degrees), raised for footprints narrower than two node spacings (``extent``: the
    smaller side, degrees), clipped to 0..MAX_LEVEL_LIMIT: ``driver._natural_level``,
    vectorised over sources."""
    res = np.asarray(res, dtype=np.float64)
    lv = np.round(np.log2(180.0 / ((1 << tile_n) * res)))
    ext = np.asarray(extent, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        small = np.ceil(np.log2(360.0 / ((1 << tile_n) * ext)))
    lv = np.where(ext > 0, np.maximum(lv, small), lv)
    return np.clip(lv, 0, MAX_LEVEL_LIMIT).astype(np.int64)


# -- names ------------------------------------------------------------------------------------


def _cell(ns: str, lat: str, ew: str, lon: str) -> tuple[int, int]:
    """South-west corner (lat, lon) of a named 1-degree cell, degrees."""
    return (int(lat) if ns in "Nn" else -int(lat)), (int(lon) if ew in "Ee" else -int(lon))


def _parse_name(name: str, size: int | None) -> tuple[int, int, int, float, float] | None:
    """(kind, lat, lon, res_lat, res_lon) of a recognised tile name (degrees), or None
    (not recognised, or an .hgt whose size says neither 1" nor 3")."""
    m = SRTM_NAME.match(name)
    if m is not None:
        res = SRTM_SIZES.get(size) if size is not None else None
        if res is None:
            return None
        lat, lon = _cell(*m.groups())
        return _KIND_SRTM, lat, lon, res, res
    m = COPERNICUS_NAME.match(name)
    if m is not None:
        res = (1.0 if m.group(1) == "10" else 3.0) / 3600.0
        lat, lon = _cell(*m.groups()[1:])
        band = max(abs(lat), abs(lat + 1))
        factor = next(f for top, f in _COP_LON_FACTORS if band <= top)
        return _KIND_COP, lat, lon, res, res * factor
    return None


def _valid_cell(lat: int, lon: int) -> bool:
    return -90 <= lat <= 89 and -180 <= lon <= 179


def is_tile_name(name: str, size: int | None) -> bool:
    """Whether a file name (and size, bytes) is an SRTM or Copernicus tile whose footprint
    the name gives (`footprints_from_names` takes it)."""
    parsed = _parse_name(name, size)
    return parsed is not None and _valid_cell(parsed[1], parsed[2])


def footprints_from_names(
    names: Sequence[str],
    sizes: Sequence[int | None] | None = None,
    vdatum: str | None = None,
) -> FootprintTable:
    """Footprints of tiles from their names alone (no file is touched): ``names`` are paths
    or base names, ``sizes`` their sizes in bytes (needed for .hgt; None: every .hgt is
    taken as SRTM 1"). DemError (one line) for a name that is not a recognised tile name."""
    n = len(names)
    rows = np.empty((n, 4), dtype=np.float64)
    kinds = np.empty(n, dtype=np.int8)
    for i, path in enumerate(names):
        base = os.path.basename(path)
        size = sizes[i] if sizes is not None else SRTM_SIZE_1
        parsed = _parse_name(base, size)
        if parsed is None or not _valid_cell(parsed[1], parsed[2]):
            raise DemError(_unrecognised(str(path), size))
        kinds[i] = parsed[0]
        rows[i] = parsed[1:]
    return _name_table(tuple(map(str, names)), rows, kinds, vdatum)


#: The size of an SRTM 1" .hgt, in bytes (the default of `footprints_from_names`).
SRTM_SIZE_1 = 3601 * 3601 * 2


def _unrecognised(path: str, size: int | None) -> str:
    base = os.path.basename(path)
    if SRTM_NAME.match(base) or COPERNICUS_NAME.match(base):
        if SRTM_NAME.match(base) is None or size in SRTM_SIZES:
            return f"{path}: the name places it outside -90..90, -180..180 degrees"
        return (
            f'{path}: {size} bytes is neither SRTM 1" (25934402) nor 3" (2884802); '
            "use --footprints header (or auto) to read its header"
        )
    return (
        f"{path}: not an SRTM (N44W072.hgt) or Copernicus "
        "(Copernicus_DSM_COG_10_N44_00_W072_00_DEM.tif) tile name; use --footprints auto"
    )


def _name_table(
    paths: tuple[str, ...], rows: np.ndarray, kinds: np.ndarray, vdatum: str | None
) -> FootprintTable:
    """The table of name footprints: each cell grown by one pixel (``rows``: lat, lon,
    res_lat, res_lon per source)."""
    lat, lon, rlat, rlon = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]
    west = lon - rlon
    east = lon + 1.0 + rlon
    west = np.where(west < -180.0, west + 360.0, west)  # across the antimeridian: west > east
    east = np.where(east > 180.0, east - 360.0, east)
    datum, why = _name_datums(kinds, vdatum)
    return FootprintTable(
        paths=paths,
        west=west,
        south=np.maximum(lat - rlat, -90.0),
        east=east,
        north=np.minimum(lat + 1.0 + rlat, 90.0),
        res=np.minimum(rlat, rlon),
        reach=np.maximum(rlat, rlon),
        extent=np.ones(len(paths)),
        wraps=np.zeros(len(paths), dtype=bool),
        datum=datum,
        how=np.zeros(len(paths), dtype=np.int8),
        datum_why=why,
    )


def _name_datums(kinds: np.ndarray, vdatum: str | None) -> tuple[np.ndarray, tuple[str, ...]]:
    """Datum codes and reasons of named tiles (``vdatum``: the --vdatum override)."""
    if vdatum is not None:
        code = DATUMS.index(parse_vdatum(vdatum).value)
        return np.full(kinds.size, code, dtype=np.int8), ("--vdatum",) * kinds.size
    datum = np.empty(kinds.size, dtype=np.int8)
    why: list[str] = []
    for i, kind in enumerate(kinds.tolist()):
        name, reason = _WHY[kind]
        datum[i] = DATUMS.index(name)
        why.append(reason)
    return datum, tuple(why)


# -- headers ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _HeaderRow:
    west: float
    south: float
    east: float
    north: float
    res: float
    reach: float
    extent: float
    wraps: bool
    datum: str
    why: str


def _header_row(path: str, crs: str | None, vdatum: str | None) -> _HeaderRow:
    """One source's footprint from its header (`open_dem` without the value scan)."""
    with open_dem(path, crs, vdatum, scan=False) as dem:
        info = dem.info
    res = float(min(info.res_deg))
    if not (res > 0 and math.isfinite(res)):
        raise DemError(f"{path} has no usable pixel size ({info.res_deg})")
    w, s, e, n = info.bounds_lonlat
    width = 360.0 if info.wraps_longitude else (e - w) % 360.0 or 360.0
    datum, why = info.vertical_datum, info.vertical_datum_source
    if vdatum is None and COPERNICUS_NAME.match(os.path.basename(path)):
        datum, why = _WHY[_KIND_COP]
    extent = min(width, n - s)
    return _HeaderRow(
        w, s, e, n, res, float(max(info.res_deg)), extent, bool(info.wraps_longitude), datum, why
    )


def _read_headers(
    paths: Sequence[str],
    crs: str | None,
    vdatum: str | None,
    on_progress: Callable[[int, int], None] | None,
) -> list[_HeaderRow]:
    """Header footprints of ``paths`` on a few threads, in order; the first failure in input
    order raised once all have ended (one DemError line)."""
    total = len(paths)
    if total == 0:
        return []
    threads = max(1, min(_HEADER_THREADS, os.cpu_count() or 1, total))
    rows: list[_HeaderRow] = []
    with ThreadPoolExecutor(max_workers=threads) as pool:
        futures = [pool.submit(_header_row, p, crs, vdatum) for p in paths]
        for done, f in enumerate(futures, 1):
            f.exception()  # waits
            if on_progress is not None:
                on_progress(done, total)
    for f in futures:
        rows.append(f.result())  # the first failure in input order raises here
    return rows


def _header_table(paths: tuple[str, ...], rows: list[_HeaderRow]) -> FootprintTable:
    col = np.array([(r.west, r.south, r.east, r.north, r.res, r.reach, r.extent) for r in rows])
    col = col.reshape(len(rows), 7)
    return FootprintTable(
        paths=paths,
        west=col[:, 0],
        south=col[:, 1],
        east=col[:, 2],
        north=col[:, 3],
        res=col[:, 4],
        reach=col[:, 5],
        extent=col[:, 6],
        wraps=np.array([r.wraps for r in rows], dtype=bool),
        datum=np.array([DATUMS.index(r.datum) for r in rows], dtype=np.int8),
        how=np.ones(len(rows), dtype=np.int8),
        datum_why=tuple(r.why for r in rows),
    )


# -- both -------------------------------------------------------------------------------------


def _file_size(path: str) -> int:
    """Size of a source file in bytes, after `check_dem_path`'s one-line checks."""
    check_dem_path(Path(path))
    try:
        st = os.stat(path)
    except OSError as exc:  # pragma: no cover - check_dem_path said it exists
        raise DemError(f"cannot read {path}: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):  # pragma: no cover - check_dem_path refuses it
        raise DemError(f"{path} is not a regular file, not a DEM file")
    return int(st.st_size)


def footprints(
    paths: Sequence[str | os.PathLike[str]],
    *,
    how: str = "auto",
    crs: str | None = None,
    vdatum: str | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> FootprintTable:
    """The footprints of the source files ``paths`` (in order), from names or headers as
    ``how`` says (`FOOTPRINT_MODES`; see the module docstring). ``crs``/``vdatum``: the
    --crs/--vdatum overrides (a --crs forces headers: a name says nothing of it).
    ``on_progress(done, total)`` after each header read. DemError (one line) for a missing
    file, a file that is not a raster, a name ``how="name"`` does not recognise."""
    if how not in FOOTPRINT_MODES:
        raise DemError(f"--footprints must be one of {', '.join(FOOTPRINT_MODES)}, not {how!r}")
    strs = tuple(str(p) for p in paths)
    sizes = [_file_size(p) for p in strs]
    by_name: list[int] = []
    if how != "header" and crs is None:
        for i, (p, size) in enumerate(zip(strs, sizes, strict=True)):
            parsed = _parse_name(os.path.basename(p), size)
            if parsed is not None and _valid_cell(parsed[1], parsed[2]):
                by_name.append(i)
            elif how == "name":
                raise DemError(_unrecognised(p, size))
    named = set(by_name)
    by_header = [i for i in range(len(strs)) if i not in named]
    parts: list[tuple[list[int], FootprintTable]] = []
    if by_name:
        names = [strs[i] for i in by_name]
        parts.append((by_name, footprints_from_names(names, [sizes[i] for i in by_name], vdatum)))
    if by_header:
        hdr = [strs[i] for i in by_header]
        parts.append(
            (by_header, _header_table(tuple(hdr), _read_headers(hdr, crs, vdatum, on_progress)))
        )
    return _merge(strs, parts)


def _merge(paths: tuple[str, ...], parts: list[tuple[list[int], FootprintTable]]) -> FootprintTable:
    """One table in input order from tables of disjoint subsets (their input positions)."""
    n = len(paths)
    if len(parts) == 1 and parts[0][0] == list(range(n)):
        return parts[0][1]
    cols: dict[str, np.ndarray] = {}
    why: list[str] = [""] * n
    for name, dtype in (
        ("west", np.float64),
        ("south", np.float64),
        ("east", np.float64),
        ("north", np.float64),
        ("res", np.float64),
        ("reach", np.float64),
        ("extent", np.float64),
        ("wraps", bool),
        ("datum", np.int8),
        ("how", np.int8),
    ):
        cols[name] = np.zeros(n, dtype=dtype)
        for idx, table in parts:
            cols[name][idx] = getattr(table, name)
    for idx, table in parts:
        for i, w in zip(idx, table.datum_why, strict=True):
            why[i] = w
    return FootprintTable(paths=paths, datum_why=tuple(why), **cols)


def check_name_footprint(
    path: str, header_bounds: tuple[float, float, float, float], table: FootprintTable, i: int
) -> None:
    """For the build's source task (§4.5): a source whose footprint came from its name must
    have its header's samples inside that footprint (grown by a pixel already); DemError
    naming both places otherwise. ``header_bounds``: (west, south, east, north) from the
    header, degrees."""
    if int(table.how[i]) != 0:
        return
    w, s, e, n = header_bounds
    tw, ts, te, tn = (
        float(table.west[i]),
        float(table.south[i]),
        float(table.east[i]),
        float(table.north[i]),
    )
    tol = 1e-9
    lon_ok = _lon_inside(w, e, tw, te, tol)
    if lon_ok and s >= ts - tol and n <= tn + tol:
        return
    raise DemError(
        f"{os.path.basename(path)}: its header puts it at {_span(w, e, 'E', 'W')}, "
        f"{_span(s, n, 'N', 'S')}, not where its name says ({_span(tw, te, 'E', 'W')}, "
        f"{_span(ts, tn, 'N', 'S')}); rename it (ingest --plan places a named tile by its name)"
    )


def _lon_inside(w: float, e: float, tw: float, te: float, tol: float) -> bool:
    """Whether the longitude interval [w, e] lies inside [tw, te] (either may cross the
    antimeridian: east < west)."""
    tw_width = (te - tw) % 360.0
    if (e - w) % 360.0 > tw_width + tol:
        return False
    return (w - tw + tol) % 360.0 <= tw_width + 2 * tol and (e - tw + tol) % 360.0 <= (
        tw_width + 2 * tol
    )


def _span(a: float, b: float, pos: str, neg: str) -> str:
    def one(v: float) -> str:
        return f"{abs(v):.4g} {pos if v >= 0 else neg}"

    return f"{one(a)}..{one(b)}"
