"""The fault corpus of issue #13: hostile and edge-case DEM inputs, generated on demand.

Every case is written from numpy arrays with rasterio (plus a hand-written VRT and a CF netCDF
file) into a folder, so no binary is committed. `make_corpus(root)` writes them and returns one
`Case` per input saying what `globeview info`, `ingest` and `render` must do with it.

Valid inputs hold a high plateau (2200..2800 m, brown in the colour ramp) or, for int8, a shallow
sea bed (blue), so a rendered pixel tells terrain from the no-data ellipsoid (0 m, green) and
from the background. Their ``probe`` is a place (lon, lat, degrees) inside the footprint where
that terrain must show; the image centre of render's default camera (which frames the footprint)
must show it too.

Run as a script to write the corpus for manual runs::

    .venv/bin/python -m tests.fault.corpus /tmp/corpus
"""

from __future__ import annotations

import math
import struct
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rasterio
import rasterio.errors
from affine import Affine
from pyproj import Transformer
from rasterio.control import GroundControlPoint

COMMANDS = ("info", "ingest", "render")

# Terrain kinds a probe pixel must show (see test_fault_corpus.terrain_kind).
LAND = "land"  # the plateau: 2200..2800 m, brown (red above green and blue)
WATER = "water"  # a sea bed of -100..-120 m: blue above red


@dataclass
class Case:
    """One corpus input and the contract for it.

    Attributes:
        name: short identifier (test ids).
        path: the input given to the commands.
        valid: whether info, ingest and render must all succeed.
        expect: exit status per command; a tuple allows several (e.g. info may describe a
            huge raster or refuse it).
        error_substring: for failures, a piece the one error line must contain
            (case-insensitive), e.g. the hint ``--crs``.
        probe: for valid inputs, (lon, lat) degrees where the terrain must be drawn.
        kind: what the probe must show: LAND or WATER.
        extra_probes: more (lon, lat, kind) places; DEMs that are part land, part sea put
            one on each so a mirrored, flipped or shifted grid is caught.
        outside: places (lon, lat) where the render must show no terrain at all: beyond the
            footprint (terrain wrapped round the globe, mirrored or shifted shows there) or
            far from it (terrain wrapped round the globe, mirrored or shifted shows there).
        fill_places: places over fill or nodata inside the footprint: the render may leave
            them bare or fill them from the neighbours (LAND), but must not draw the fill as
            heights (a -9999 m trench shows as WATER, a 1e30 m spike as anything else).
        note: why the case is in the corpus.
    """

    name: str
    path: Path
    valid: bool
    expect: dict[str, int | tuple[int, ...]] = field(default_factory=dict)
    error_substring: str | None = None
    probe: tuple[float, float] | None = None
    kind: str = LAND
    extra_probes: tuple[tuple[float, float, str], ...] = ()
    outside: tuple[tuple[float, float], ...] = ()
    fill_places: tuple[tuple[float, float], ...] = ()
    note: str = ""

    def expected(self, command: str) -> tuple[int, ...]:
        """Allowed exit statuses of ``command`` (0 for valid inputs, else 2 unless stated)."""
        e = self.expect.get(command, 0 if self.valid else 2)
        return e if isinstance(e, tuple) else (e,)


# ---------------------------------------------------------------------------------------------
# Arrays


def plateau(h: int, w: int) -> np.ndarray:
    """(h, w) float64 heights in metres: a plateau 2200..2800 m with gentle relief."""
    r, c = np.mgrid[0:h, 0:w].astype(np.float64)
    return 2500.0 + 300.0 * np.sin(r / max(h, 2) * 6.0) * np.cos(c / max(w, 2) * 5.0)


def seabed(h: int, w: int) -> np.ndarray:
    """(h, w) float64 heights in metres: a shallow sea bed, -100..-120 m."""
    r, c = np.mgrid[0:h, 0:w].astype(np.float64)
    return -110.0 + 10.0 * np.sin(r / 7.0) * np.cos(c / 5.0)


def write_raster(
    path: Path,
    bands: np.ndarray,
    transform: Affine | None,
    crs: str | None,
    *,
    dtype: str | None = None,
    nodata: float | None = None,
    driver: str = "GTiff",
    gcps: list | None = None,
) -> Path:
    """Write (h, w) or (bands, h, w) ``bands`` as a raster; returns ``path``."""
    a = np.asarray(bands)
    if a.ndim == 2:
        a = a[None]
    dtype = dtype or a.dtype.name
    profile = {
        "driver": driver,
        "width": a.shape[2],
        "height": a.shape[1],
        "count": a.shape[0],
        "dtype": dtype,
    }
    if transform is not None:
        profile["transform"] = transform
    if crs is not None:
        profile["crs"] = crs
    if nodata is not None:
        profile["nodata"] = nodata
    if gcps is not None:
        profile["gcps"] = gcps
    path.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        # A raster without geotransform is a corpus case, written on purpose.
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path, "w", **profile) as ds:
            ds.write(a.astype(dtype))
    return path


def with_sea(z: np.ndarray, rows: slice, cols: slice) -> np.ndarray:
    """A copy of ``z`` with the sea bed (-100..-120 m) in ``z[rows, cols]``."""
    out = np.array(z, dtype=np.float64)
    out[rows, cols] = seabed(*out.shape)[rows, cols]
    return out


def pixel_lonlat(transform: Affine, crs: str, row: float, col: float) -> tuple[float, float]:
    """(lon, lat) degrees of the centre of pixel (row, col) of a grid in ``crs``."""
    x, y = transform @ (col + 0.5, row + 0.5)
    lon, lat = Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(x, y)
    return float((lon + 180.0) % 360.0 - 180.0), float(lat)


def geo_transform(west: float, north: float, dlon: float, dlat: float) -> Affine:
    """North-up geographic transform: pixel (dlon x dlat) degrees, top-left at (west, north)."""
    return Affine(dlon, 0.0, west, 0.0, -dlat, north)


def centred_transform(crs: str, lon: float, lat: float, w: int, h: int, px: float) -> Affine:
    """North-up transform of a (w x h) grid of ``px`` metre pixels centred on (lon, lat) in
    the projected ``crs``."""
    x, y = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    return Affine(px, 0.0, x - w * px / 2.0, 0.0, -px, y + h * px / 2.0)


# ---------------------------------------------------------------------------------------------
# Hand-written files


def write_netcdf_cf(
    path: Path, lons: np.ndarray, lats: np.ndarray, z: np.ndarray, *, geographic: bool = True
) -> Path:
    """A classic (CDF-1) netCDF file with CF ``lat``/``lon`` coordinate variables and a float
    ``elevation(lat, lon)`` variable, and no grid mapping or CRS attribute at all
    (``geographic=False``: ``y``/``x`` axes in metres instead, so nothing says lon/lat).

    Written by hand: GDAL's netCDF driver writes x/y axes without a CRS and adds a grid
    mapping with one, and neither is the case to test (scipy, the usual writer, is not a
    dependency). Format: the NetCDF Classic Format Specification (big-endian).
    """
    nc_char, nc_float, nc_double = 2, 5, 6

    def name(s: str) -> bytes:
        b = s.encode()
        return struct.pack(">i", len(b)) + b + b"\0" * (-len(b) % 4)

    def att_text(key: str, value: str) -> bytes:
        b = value.encode()
        return name(key) + struct.pack(">ii", nc_char, len(b)) + b + b"\0" * (-len(b) % 4)

    def att_list(items: list[bytes]) -> bytes:
        return struct.pack(">ii", 0x0C, len(items)) + b"".join(items) if items else b"\0" * 8

    lat_b = np.asarray(lats, ">f8").tobytes()
    lon_b = np.asarray(lons, ">f8").tobytes()
    z_b = np.asarray(z, ">f4").tobytes()
    lat_n, lon_n = ("lat", "lon") if geographic else ("y", "x")
    if geographic:
        lat_atts = [att_text("units", "degrees_north"), att_text("standard_name", "latitude")]
        lon_atts = [att_text("units", "degrees_east"), att_text("standard_name", "longitude")]
    else:
        lat_atts = [att_text("units", "m"), att_text("standard_name", "projection_y_coordinate")]
        lon_atts = [att_text("units", "m"), att_text("standard_name", "projection_x_coordinate")]
    variables = [
        (lat_n, [0], lat_atts),
        (lon_n, [1], lon_atts),
        ("elevation", [0, 1], [att_text("units", "m"), att_text("long_name", "elevation")]),
    ]
    types = [nc_double, nc_double, nc_float]
    blobs = [lat_b, lon_b, z_b]
    dims = struct.pack(">ii", 0x0A, 2) + name(lat_n) + struct.pack(">i", len(lats))
    dims += name(lon_n) + struct.pack(">i", len(lons))
    gatts = att_list([att_text("Conventions", "CF-1.6")])

    def var_list(begins: list[int]) -> bytes:
        out = struct.pack(">ii", 0x0B, len(variables))
        for (vname, dimids, atts), t, blob, begin in zip(variables, types, blobs, begins):
            out += name(vname) + struct.pack(">i", len(dimids))
            out += b"".join(struct.pack(">i", d) for d in dimids) + att_list(atts)
            out += struct.pack(">iii", t, len(blob) + (-len(blob) % 4), begin)
        return out

    header_len = 8 + len(dims) + len(gatts) + len(var_list([0, 0, 0]))
    begins, off = [], header_len
    for blob in blobs:
        begins.append(off)
        off += len(blob) + (-len(blob) % 4)
    data = b"".join(b + b"\0" * (-len(b) % 4) for b in blobs)
    path.write_bytes(b"CDF\x01" + struct.pack(">i", 0) + dims + gatts + var_list(begins) + data)
    return path


def write_vrt(path: Path, source: Path, width: int, height: int, transform: Affine) -> Path:
    """A VRT declaring a (width x height) float32 EPSG:4326 raster whose band reads a 64x64
    window of ``source`` into its top-left corner."""
    gt = ", ".join(repr(v) for v in transform.to_gdal())
    path.write_text(
        f"""<VRTDataset rasterXSize="{width}" rasterYSize="{height}">
  <SRS>EPSG:4326</SRS>
  <GeoTransform>{gt}</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">
    <SimpleSource>
      <SourceFilename relativeToVRT="0">{source}</SourceFilename>
      <SourceBand>1</SourceBand>
      <SrcRect xOff="0" yOff="0" xSize="64" ySize="64"/>
      <DstRect xOff="0" yOff="0" xSize="64" ySize="64"/>
    </SimpleSource>
  </VRTRasterBand>
</VRTDataset>
"""
    )
    return path


# ---------------------------------------------------------------------------------------------
# The corpus

# The basic valid raster: 96 x 64 pixels over 8..10 E, 45.5..47 N (the Alps), centre (9, 46.25).
W, H = 96, 64
ALPS = geo_transform(8.0, 47.0, 2.0 / W, 1.5 / H)
ALPS_CENTRE = (9.0, 46.25)


def _valid(root: Path) -> list[Case]:
    cases: list[Case] = []

    def add(name: str, path: Path, probe: tuple[float, float], note: str, **kw) -> None:
        # By default one place a quarter of the globe east of the probe must stay bare.
        away = ((probe[0] + 90.0 + 180.0) % 360.0 - 180.0, probe[1])
        kw.setdefault("outside", (away,))
        cases.append(Case(name, path, True, probe=probe, note=note, **kw))

    def lonlat(row: float, col: float) -> tuple[float, float]:
        """Centre of pixel (row, col) of the ALPS grid."""
        lon, lat = ALPS @ (col + 0.5, row + 0.5)
        return float(lon), float(lat)

    base = plateau(H, W)
    add(
        "float32",
        write_raster(root / "float32.tif", base, ALPS, "EPSG:4326", dtype="float32"),
        ALPS_CENTRE,
        "the plain case",
    )
    add(
        "float64",
        write_raster(root / "float64.tif", base, ALPS, "EPSG:4326", dtype="float64"),
        ALPS_CENTRE,
        "float64 samples",
    )
    z = base.copy()
    z[:16, :24] = -32768
    add(
        "int16_nodata_corner",
        write_raster(root / "int16.tif", z, ALPS, "EPSG:4326", dtype="int16", nodata=-32768),
        ALPS_CENTRE,
        "int16 with a declared nodata filling a corner",
        fill_places=(lonlat(7, 11),),
    )
    add(
        "uint32",
        write_raster(root / "uint32.tif", base, ALPS, "EPSG:4326", dtype="uint32"),
        ALPS_CENTRE,
        "uint32 samples",
    )
    add(
        "int8_seabed",
        write_raster(root / "int8.tif", seabed(H, W), ALPS, "EPSG:4326", dtype="int8"),
        ALPS_CENTRE,
        "int8 samples (a sea bed: int8 cannot hold a plateau)",
        kind=WATER,
    )
    z = base.copy()
    rng = np.random.default_rng(13)
    holes = rng.random((H, W)) < 0.15
    holes[24:40, 40:56] = False  # keep the probe's surroundings
    z[holes] = np.nan
    z[2:10, 70:90] = np.nan  # and one bigger hole
    add(
        "nan_holes",
        write_raster(root / "nan_holes.tif", z, ALPS, "EPSG:4326", dtype="float32"),
        ALPS_CENTRE,
        "NaN holes, no nodata declared",
        fill_places=(lonlat(5.5, 79.5),),
    )
    z = base.copy()
    z[3, 5], z[60, 90], z[10, 80] = np.inf, -np.inf, np.inf
    z[50:54, 2:6] = -np.inf
    add(
        "inf_samples",
        write_raster(root / "inf.tif", z, ALPS, "EPSG:4326", dtype="float32"),
        ALPS_CENTRE,
        "+-inf samples",
        fill_places=(lonlat(51.5, 3.5),),
    )
    z = base.copy()
    z[2:8, 2:8] = 1e30
    add(
        "heights_1e30",
        write_raster(root / "h1e30.tif", z, ALPS, "EPSG:4326", dtype="float32"),
        ALPS_CENTRE,
        "1e30 heights in a corner (an undeclared fill, not a 1e30 m mountain)",
        fill_places=(lonlat(4.5, 4.5),),
    )
    for fill in (-9999, -999):
        z = base.copy()
        z[:, :30] = fill  # a whole strip of fill, no nodata declared
        z[50:, 60:] = fill
        add(
            f"fill{fill}_rectangles",
            write_raster(root / f"fill{-fill}.tif", z, ALPS, "EPSG:4326", dtype="float32"),
            ALPS_CENTRE,
            f"{fill} fill covering whole rectangles without a declared nodata",
            fill_places=(lonlat(32, 14), lonlat(57, 78)),
        )
    rng = np.random.default_rng(3)
    bands = np.stack([base, rng.normal(0, 1e6, (H, W)), rng.normal(0, 1, (H, W))])
    add(
        "multiband",
        write_raster(root / "multiband.tif", bands, ALPS, "EPSG:4326", dtype="float32"),
        ALPS_CENTRE,
        "three bands; band 1 is elevation",
    )
    add(
        "non_square_pixels",
        write_raster(
            root / "nonsquare.tif",
            plateau(40, 120),
            geo_transform(8.0, 47.0, 2.0 / 120, 1.5 / 40),
            "EPSG:4326",
            dtype="float32",
        ),
        ALPS_CENTRE,
        "non-square pixels (0.0167 x 0.0375 deg), 120 x 40",
    )
    # Rotated pixels: a UTM grid turned by 20 degrees around its centre (46.25 N, 9 E).
    cx, cy = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(*ALPS_CENTRE)
    rot = (
        Affine.translation(cx, cy)
        @ Affine.rotation(20.0)
        @ Affine.scale(1000.0, -1000.0)
        @ Affine.translation(-40, -30)
    )
    add(
        "rotated_pixels",
        write_raster(
            root / "rotated.tif",
            with_sea(plateau(60, 80), slice(None), slice(60, None)),
            rot,
            "EPSG:32632",
            dtype="float32",
        ),
        ALPS_CENTRE,
        "rotated pixels: UTM 32N, 1 km pixels, geotransform turned by 20 deg; sea in the "
        "last quarter of the columns",
        extra_probes=(
            (*pixel_lonlat(rot, "EPSG:32632", 8, 72), WATER),
            (*pixel_lonlat(rot, "EPSG:32632", 52, 72), WATER),
            (*pixel_lonlat(rot, "EPSG:32632", 8, 8), LAND),
            (*pixel_lonlat(rot, "EPSG:32632", 52, 8), LAND),
        ),
    )
    # South-up: the geotransform's rows run north (positive pixel height); sea in the south.
    south_up = geo_transform(8.0, 45.5, 2.0 / W, -1.5 / H)
    add(
        "south_up",
        write_raster(
            root / "south_up.tif",
            with_sea(plateau(H, W), slice(0, 15), slice(None)),
            south_up,
            "EPSG:4326",
            dtype="float32",
        ),
        ALPS_CENTRE,
        "rows stored south to north (positive pixel height); sea along the south edge",
        extra_probes=((9.0, 45.6, WATER), (9.0, 46.9, LAND)),
    )
    add(
        "antimeridian_4326",
        write_raster(
            root / "antimeridian_4326.tif",
            with_sea(plateau(60, 80), slice(None), slice(60, None)),
            geo_transform(179.0, 66.0, 2.0 / 80, 1.5 / 60),
            "EPSG:4326",
            dtype="float32",
        ),
        (180.0, 65.25),
        "EPSG:4326 across the antimeridian: longitudes 179..181; sea east of 180.5",
        extra_probes=((179.4, 65.25, LAND), (-179.25, 65.25, WATER)),
        outside=((-90.0, 65.25), (178.0, 65.25), (-178.0, 65.25)),
    )
    pdc = centred_transform("EPSG:3832", 180.0, -17.0, 80, 60, 2000.0)
    add(
        "antimeridian_3832",
        write_raster(
            root / "antimeridian_3832.tif",
            with_sea(plateau(60, 80), slice(None), slice(60, None)),
            pdc,
            "EPSG:3832",
            dtype="float32",
        ),
        (180.0, -17.0),
        "EPSG:3832 (PDC Mercator) across the antimeridian near Fiji, 2 km pixels; sea in "
        "the eastern quarter",
        extra_probes=(
            (*pixel_lonlat(pdc, "EPSG:3832", 30, 15), LAND),
            (*pixel_lonlat(pdc, "EPSG:3832", 30, 72), WATER),
        ),
        outside=((-90.0, -17.0), (178.0, -17.0), (-178.0, -17.0)),
    )
    # Polar caps: 1000 km squares centred on the pole, sea in one quadrant (away from the
    # probe and from the default camera's view of the footprint centre at longitude 0).
    for name, crs, pole, sea_rows in (
        ("north_pole_3413", "EPSG:3413", 90.0, slice(0, 50)),
        ("south_pole_3031", "EPSG:3031", -90.0, slice(50, None)),
    ):
        t = centred_transform(crs, 0.0, pole, 100, 100, 10000.0)
        sea_row = 25 if sea_rows.start == 0 else 75
        add(
            name,
            write_raster(
                root / f"{name}.tif",
                with_sea(plateau(100, 100), sea_rows, slice(50, None)),
                t,
                crs,
                dtype="float32",
            ),
            (0.0, math.copysign(88.0, pole)),
            f"{crs} polar stereographic, 1000 km square around the pole, one quadrant sea",
            extra_probes=(
                (*pixel_lonlat(t, crs, sea_row, 75), WATER),
                (*pixel_lonlat(t, crs, 100 - sea_row, 75), LAND),
                (*pixel_lonlat(t, crs, sea_row, 25), LAND),
            ),
            outside=((0.0, math.copysign(70.0, pole)), (0.0, -math.copysign(88.0, pole))),
        )
    add(
        "global_past_poles",
        write_raster(
            root / "global_half_pixel.tif",
            plateau(181, 360),
            geo_transform(-180.5, 90.5, 1.0, 1.0),
            "EPSG:4326",
            dtype="float32",
        ),
        (20.0, 10.0),
        "global 1 deg grid whose pixel centres sit on the poles: edges at +-90.5 lat",
        outside=(),
    )
    lats = np.linspace(46.99, 45.51, H)
    lons = np.linspace(8.01, 9.99, W)
    add(
        "netcdf_cf_no_crs",
        write_netcdf_cf(root / "cf_latlon.nc", lons, lats, base),
        ALPS_CENTRE,
        "CF netCDF with lat/lon axes and no CRS: EPSG:4326 assumed",
    )
    add(
        "two_by_two",
        write_raster(
            root / "two_by_two.tif",
            plateau(2, 2),
            geo_transform(8.5, 46.75, 0.5, 0.5),
            "EPSG:4326",
            dtype="float32",
        ),
        ALPS_CENTRE,
        "the smallest DEM: 2 x 2 pixels of 0.5 deg",
    )
    uni = root / "données ✓" / "Gipfel-ß-山 ⛰.tif"
    add(
        "unicode_path",
        write_raster(uni, base, ALPS, "EPSG:4326", dtype="float32"),
        ALPS_CENTRE,
        "non-ASCII folder and file names",
    )
    link = root / "link_to_float32.tif"
    link.symlink_to(root / "float32.tif")
    add("symlink", link, ALPS_CENTRE, "a symlink to a valid DEM")
    return cases


def _invalid(root: Path) -> list[Case]:
    cases: list[Case] = []

    def add(name: str, path: Path, note: str, **kw) -> None:
        cases.append(Case(name, path, False, note=note, **kw))

    base = plateau(H, W)
    add(
        "all_nan",
        write_raster(
            root / "all_nan.tif", np.full((H, W), np.nan), ALPS, "EPSG:4326", dtype="float32"
        ),
        "every sample NaN",
    )
    add(
        "all_nodata",
        write_raster(
            root / "all_nodata.tif",
            np.full((H, W), -500),
            ALPS,
            "EPSG:4326",
            dtype="int16",
            nodata=-500,
        ),
        "every sample the declared nodata",
    )
    add(
        "all_fill_9999",
        write_raster(
            root / "all_fill.tif", np.full((H, W), -9999.0), ALPS, "EPSG:4326", dtype="float32"
        ),
        "every sample the undeclared fill -9999",
    )
    add(
        "one_by_one",
        write_raster(
            root / "one_by_one.tif", np.full((1, 1), 2500.0), ALPS, "EPSG:4326", dtype="float32"
        ),
        "a single pixel cannot be interpolated",
    )
    add(
        "complex64",
        write_raster(
            root / "iq_samples.tif", (base + 1j * base).astype(np.complex64), ALPS, "EPSG:4326"
        ),
        "complex samples are not heights",
        error_substring="complex",
    )
    add(
        "no_crs",
        write_raster(root / "no_crs.tif", base, ALPS, None, dtype="float32"),
        "a GeoTIFF with a geotransform but no CRS",
        error_substring="--crs",
    )
    add(
        "no_geotransform",
        write_raster(root / "no_transform.tif", base, None, "EPSG:4326", dtype="float32"),
        "a GeoTIFF with a CRS but no geotransform",
    )
    corners = [(0, 0, 8.0, 47.0), (0, W, 10.0, 47.0), (H, 0, 8.0, 45.5), (H, W, 10.0, 45.5)]
    add(
        "gcps_only",
        write_raster(
            root / "gcps_only.tif",
            base,
            None,
            "EPSG:4326",
            dtype="float32",
            gcps=[GroundControlPoint(r, c, x, y) for r, c, x, y in corners],
        ),
        "georeferenced by ground control points only (no geotransform)",
    )
    add(
        "lat_beyond_90",
        write_raster(
            root / "lat_beyond_90.tif",
            plateau(64, 96),
            geo_transform(8.0, 100.0, 0.25, 0.25),
            "EPSG:4326",
            dtype="float32",
        ),
        "EPSG:4326 rows reaching latitude 100 (impossible georeferencing, not half a pixel)",
    )
    good = root / "float32.tif"
    raw = good.read_bytes()
    trunc = root / "truncated.tif"
    trunc.write_bytes(raw[: len(raw) // 2])
    add("truncated", trunc, "a GeoTIFF cut in half")
    text = root / "notes.tif"
    text.write_text("this is a text file, not a raster\n")
    add("text_file", text, "a text file named .tif")
    zero = root / "zero.tif"
    zero.write_bytes(b"")
    add("zero_byte", zero, "an empty file")
    add("dev_null", Path("/dev/null"), "/dev/null")
    folder = root / "a_folder.tif"
    folder.mkdir()
    (folder / "readme.txt").write_text("a folder, not a raster\n")
    add("directory", folder, "a directory")
    a, b = root / "ring_a.tif", root / "ring_b.tif"
    a.symlink_to(b)
    b.symlink_to(a)
    # "not found" would be wrong: the path is there, it just never reaches a file.
    add("symlink_loop", a, "two symlinks pointing at each other", error_substring="loop")
    add("missing", root / "no_such_file.tif", "a path that does not exist")
    add(
        "dangling_vrt",
        write_vrt(root / "dangling.vrt", root / "gone.tif", 64, 64, ALPS),
        "a VRT whose source file does not exist",
        error_substring="gone.tif",  # the user must learn which file is missing
    )
    add(
        "huge_vrt",
        write_vrt(
            root / "huge.vrt",
            good,
            2_000_000,
            1_000_000,
            geo_transform(-180.0, 90.0, 360.0 / 2_000_000, 180.0 / 1_000_000),
        ),
        "a VRT declaring 2 000 000 x 1 000 000 pixels over a 96 x 64 GeoTIFF",
        # Describing it (from a decimated read) is fine; building a pyramid of 2e12 samples
        # or rendering it is not: those must refuse in one line, not run out of memory.
        expect={"info": (0, 2)},
    )
    return cases


def make_corpus(root: Path) -> list[Case]:
    """Write every corpus input under ``root`` (created) and return the cases."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    return _valid(root) + _invalid(root)


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m tests.fault.corpus DIR", file=sys.stderr)
        return 2
    for c in make_corpus(Path(argv[0])):
        verdict = "valid" if c.valid else "must fail"
        print(f"{c.name:24s} {verdict:9s} {c.path}  ({c.note})")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
