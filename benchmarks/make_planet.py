"""A synthetic planet for issue #25's proof: N one-degree SRTM 3" tiles over the land of the
embedded ETOPO, and a GEBCO-size 86 400 x 43 200 15" global grid (SYNTHETIC data; never
committed: everything goes under benchmarks/cache/planet/ or --out).

**SRTM tiles** (``srtm``). The cells are the embedded ETOPO 20' land cells (data/etopo20.tif,
counted as `scale_planet.land_cells` counts them: any sample above 0 m, 56 S..60 N), the
``--tiles N`` nearest ``--center`` (great-circle distance of the cell centres, then the cell
index): one compact region that grows outward with N, as a continent's download does. Each
tile is an SRTM ``.hgt`` file: NASA's name (``N44W072.hgt``: the south-west corner), 1201 x
1201 big-endian int16 samples at 3" (pixel-is-point: a tile's last row and column are its
neighbours' first), -32768 for voids (none here). Heights: ETOPO's relief sampled bilinearly
at every sample's lon/lat (the cell's relief upsampled; sea (<= 0 m) stays 0 m as in SRTM),
plus fractal detail where there is land: four octaves of value noise (periods 256..4 samples,
amplitudes 60..2 m) whose lattice values are hashed from *global* sample coordinates and the
octave (splitmix64, as `make_big_dem`), so each tile is deterministic, seeded by where it is,
and neighbours agree on their shared edges. Generation is separable (small lattices
interpolated separably), ~0.1 CPU s a tile.

Lazy: a tile is written only when missing (to a ``.part`` name, then renamed, so a killed run
leaves no half tile), so asking for N = 2 000 after N = 200 writes only the 1 800 new ones,
and ``tiles_N.txt`` lists exactly the first N (``globeview ingest @tiles_N.txt``) whatever
else the folder holds. Before writing, the tiles still missing are checked against the free
space (2.9 MB each at 3"): one line, not a full disk. ``--placeholders`` writes instead sparse
files of SRTM 1"'s size (25 934 402 bytes of holes: no disk used) for ``globeview ingest
--plan``, which places SRTM tiles by name and size without opening them: any N fits; their
cells are SRTM 1"'s layout of `bench_plan.planet_cells` (the land cells, then the cells next
to them, up to SRTM's 14 277).

**GEBCO-size grid** (``gebco``): a CF netCDF-4 (GDAL's netCDF driver, int16 ``Band1`` with
lat/lon axes, DEFLATE level 1, nodata -32767), 86 400 x 43 200 cells of 15" over the globe,
pixel-is-area, as GEBCO_2024.nc is; but **mostly nodata**: only a few 8 x 8 degree regions
hold relief (ETOPO upsampled + the same fractal detail, seeded by global sample coordinates),
so no 7 GB of fractal work and a file of a few MB (constant blocks deflate to almost nothing).
GDAL writes it from a VRT of the filled regions over a nodata background (the VRT is kept
beside it: ``gebco_synthetic.vrt``, a second source of the same grid).

    python benchmarks/make_planet.py srtm --tiles 200 [--out DIR] [--center 46,10]
    python benchmarks/make_planet.py srtm --tiles 14277 --placeholders [--out DIR]
    python benchmarks/make_planet.py gebco [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from scale_planet import land_cells  # noqa: E402  (a sibling script)

CACHE = ROOT / "benchmarks" / "cache" / "planet"
ETOPO = ROOT / "data" / "etopo20.tif"
SRTM3_N = 1201  # samples a side of a 3" tile
SRTM1_BYTES = 3601 * 3601 * 2  # a 1" tile's size: what `ingest --plan` reads a name's res from
VOID = -32768
#: (period in samples, amplitude in metres) of the fractal detail's octaves.
OCTAVES = ((256, 60.0), (64, 20.0), (16, 6.0), (4, 2.0))
#: GEBCO's grid: 15" cells, 86 400 x 43 200 over the globe.
GEBCO_PER_DEG = 240
GEBCO_NODATA = -32767
#: Filled regions of the GEBCO-size grid: south-west corners (lat, lon) of 8 x 8 degree boxes
#: (the Alps, the Himalaya, the Andes, the Rockies: relief, coast and sea).
GEBCO_REGIONS = ((42, 4), (26, 82), (-36, -74), (38, -112))
GEBCO_REGION_DEG = 8


class PlanetError(Exception):
    """A bad argument or a disk that cannot take the tiles (one line, exit status 2)."""


# -- which cells ---------------------------------------------------------------------------------


def compact_cells(n: int, center: tuple[float, float]) -> list[tuple[int, int]]:
    """(lat, lon) south-west corners of the ``n`` ETOPO land cells nearest ``center`` (lat,
    lon degrees), nearest first (ties by cell index: deterministic)."""
    cells = land_cells(ETOPO)
    rows, cols = np.nonzero(cells)
    if n > rows.size:
        raise PlanetError(f"--tiles {n}: the embedded ETOPO has {rows.size} land cells")
    lat = np.radians(89.5 - rows)
    lon = np.radians(cols - 179.5)
    la0, lo0 = np.radians(center[0]), np.radians(center[1])
    cosd = np.sin(lat) * np.sin(la0) + np.cos(lat) * np.cos(la0) * np.cos(lon - lo0)
    order = np.lexsort((rows * 360 + cols, -cosd))[:n]
    return [(89 - int(rows[i]), int(cols[i]) - 180) for i in order]


def srtm_name(lat: int, lon: int) -> str:
    """NASA's SRTM name of the cell whose south-west corner is (lat, lon)."""
    ns, ew = ("N" if lat >= 0 else "S"), ("E" if lon >= 0 else "W")
    return f"{ns}{abs(lat):02d}{ew}{abs(lon):03d}.hgt"


# -- heights -------------------------------------------------------------------------------------


def _hash01(ix: np.ndarray, iy: np.ndarray, octave: int, salt: int = 1) -> np.ndarray:
    """Deterministic value in [-1, 1) per integer lattice point and octave (splitmix64);
    ``salt`` tells one script's fields from another's (make_dtm.py uses 13)."""
    with np.errstate(over="ignore"):
        z = (ix.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)) ^ (
            iy.astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F) + np.uint64(octave * 7919 + salt)
        )
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    out: np.ndarray = (z >> np.uint64(11)).astype(np.float64) / float(1 << 53) * 2.0 - 1.0
    return out


#: `_taps`: (lower lattice index from the first, upper weight, first index, points needed).
Taps = tuple[np.ndarray, np.ndarray, int, int]


def _taps(pos: np.ndarray, smooth: bool) -> Taps:
    """Linear interpolation of lattice points at fractional positions ``pos``: (index of
    each position's lower lattice point counted from the first, its weight t of the upper
    one (smoothstep-eased when ``smooth``), the first lattice index, the lattice points
    needed)."""
    i0 = np.floor(pos).astype(np.int64)
    t = pos - i0
    if smooth:
        t = t * t * (3.0 - 2.0 * t)
    first = int(i0.min())
    return i0 - first, t, first, int(i0.max()) - first + 2


def _interp2(lattice: np.ndarray, ty: Taps, tx: Taps) -> np.ndarray:
    """``lattice`` (m_y x m_x) interpolated at the rows and columns of taps ``ty``, ``tx``
    (`_taps`): separable, columns first (2 gathers a pass)."""
    lat32 = lattice.astype(np.float32)  # float32: half the bandwidth, cm-level rounding
    ix, wx = tx[0], tx[1].astype(np.float32)
    cols = lat32[:, ix] * (1.0 - wx) + lat32[:, ix + 1] * wx  # m_y x len(x)
    iy, wy = ty[0], ty[1].astype(np.float32)[:, None]
    out: np.ndarray = cols[iy] * (1.0 - wy) + cols[iy + 1] * wy
    return out


def fractal(gy: np.ndarray, gx: np.ndarray, per_deg: int) -> np.ndarray:
    """Value-noise detail (metres, float32 len(gy) x len(gx)) at global sample rows ``gy``
    (0 at 90 N) and columns ``gx`` (0 at 180 W) of a grid of ``per_deg`` samples a degree.
    Periods scale with the grid (`OCTAVES` are for 1200 a degree), so a 15" grid and a 3"
    tile of the same place have the same kind of relief."""
    out = np.zeros((gy.size, gx.size), dtype=np.float32)
    scale = per_deg / 1200.0
    for octave, (period, amp) in enumerate(OCTAVES):
        p = max(period * scale, 1.0)
        ty, tx = _taps(gy / p, smooth=True), _taps(gx / p, smooth=True)
        ly = np.arange(ty[2], ty[2] + ty[3])
        lx = np.arange(tx[2], tx[2] + tx[3])
        lattice = _hash01(lx[None, :], ly[:, None], octave)  # m_y x m_x
        out += np.float32(amp) * _interp2(lattice, ty, tx)
    return out


def relief(lat: np.ndarray, lon: np.ndarray, etopo: np.ndarray) -> np.ndarray:
    """ETOPO 20' heights (metres) sampled bilinearly at latitudes ``lat`` (rows) x longitudes
    ``lon`` (columns), degrees; ETOPO's cells are pixel-is-area (centres at 1/6 + k/3 deg),
    longitudes wrap."""
    py = np.clip((90.0 - lat) * 3.0 - 0.5, 0.0, etopo.shape[0] - 1.0 - 1e-9)
    px = (lon + 180.0) * 3.0 - 0.5
    ty, tx = _taps(py, smooth=False), _taps(px, smooth=False)
    rows = np.arange(ty[2], ty[2] + ty[3])
    cols = np.arange(tx[2], tx[2] + tx[3]) % etopo.shape[1]
    return _interp2(etopo[np.ix_(rows, cols)], ty, tx)


def heights(base: np.ndarray, detail: np.ndarray) -> np.ndarray:
    """int16 heights: land (base > 0 m) gets the detail (never below 1 m), sea is 0 m."""
    z = np.where(base > 0.0, np.maximum(base + detail, 1.0), 0.0)
    return np.round(z).astype(np.int16)


def srtm_tile(lat: int, lon: int, etopo: np.ndarray) -> np.ndarray:
    """The 1201 x 1201 int16 heights of the 3" tile at south-west corner (lat, lon)."""
    k = np.arange(SRTM3_N)
    gy = (90 - (lat + 1)) * 1200 + k  # global 3" sample rows, north first
    gx = (lon + 180) * 1200 + k
    base = relief(lat + 1 - k / 1200.0, lon + k / 1200.0, etopo)
    return heights(base, fractal(gy.astype(np.float64), gx.astype(np.float64), 1200))


def read_etopo() -> np.ndarray:
    """The embedded ETOPO 20' (540 x 1080 float64, metres)."""
    import rasterio

    with rasterio.open(ETOPO) as ds:
        z: np.ndarray = ds.read(1).astype(np.float64)
    return z


# -- writing -------------------------------------------------------------------------------------


def _check_space(folder: Path, need: int) -> None:
    """PlanetError (one line) when ``need`` bytes do not fit in ``folder``'s free space (with
    1 GB left over for the stores built from the tiles)."""
    free = shutil.disk_usage(folder).free
    if need + 10**9 > free:
        raise PlanetError(
            f"{need / 1e9:.1f} GB of tiles to write and {free / 1e9:.1f} GB free in {folder} "
            "(1 GB kept free): use fewer --tiles or another --out"
        )


def _write_atomic(path: Path, data: bytes | None, size: int = 0) -> None:
    """Write ``data`` (None: a sparse file of ``size`` bytes of holes) to ``path`` via a
    ``.part`` sibling, renamed into place."""
    part = path.with_name(path.name + ".part")
    with part.open("wb") as f:
        if data is None:
            f.truncate(size)
        else:
            f.write(data)
    os.replace(part, path)


def ensure_srtm(
    out: Path, n: int, center: tuple[float, float], placeholders: bool
) -> tuple[Path, int, float]:
    """The first ``n`` tiles in ``out`` (missing ones written), and ``out/tiles_N.txt``
    listing them: (the list, tiles written now, CPU seconds)."""
    if placeholders:  # SRTM 1"'s layout: the land cells, then the cells around them
        from bench_plan import planet_cells

        cells = planet_cells(n)
    else:
        cells = compact_cells(n, center)
    out.mkdir(parents=True, exist_ok=True)
    names = [srtm_name(lat, lon) for lat, lon in cells]
    missing = [(c, nm) for c, nm in zip(cells, names, strict=True) if not (out / nm).exists()]
    if not placeholders:
        _check_space(out, len(missing) * SRTM3_N * SRTM3_N * 2)
    c0 = time.process_time()
    etopo = None if placeholders else read_etopo()
    for (lat, lon), name in missing:
        if etopo is None:
            _write_atomic(out / name, None, SRTM1_BYTES)
        else:
            _write_atomic(out / name, srtm_tile(lat, lon, etopo).astype(">i2").tobytes())
    listing = out / f"tiles_{n}.txt"
    _write_atomic(listing, ("\n".join(names) + "\n").encode())
    return listing, len(missing), time.process_time() - c0


def _region_tif(path: Path, lat: int, lon: int, etopo: np.ndarray) -> None:
    """A GEBCO-resolution (15") GeoTIFF of the 8 x 8 degree box at south-west (lat, lon)."""
    import rasterio
    from rasterio.transform import from_origin

    n = GEBCO_REGION_DEG * GEBCO_PER_DEG
    k = np.arange(n)
    d = 1.0 / GEBCO_PER_DEG
    north = lat + GEBCO_REGION_DEG
    gy = (90 - north) * GEBCO_PER_DEG + k + 0.5  # cell centres (pixel-is-area)
    gx = (lon + 180) * GEBCO_PER_DEG + k + 0.5
    base = relief(north - (k + 0.5) * d, lon + (k + 0.5) * d, etopo)
    z = heights(base, fractal(gy, gx, GEBCO_PER_DEG))
    z = np.where(base > 0.0, z, np.round(base)).astype(np.int16)  # GEBCO has bathymetry
    profile = {
        "driver": "GTiff", "width": n, "height": n, "count": 1, "dtype": "int16",
        "crs": "EPSG:4326", "transform": from_origin(lon, north, d, d), "nodata": GEBCO_NODATA,
        "tiled": True, "compress": "deflate",
    }  # fmt: skip
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(z, 1)


def gebco_vrt(regions: Sequence[Path], boxes: Sequence[tuple[int, int]]) -> str:
    """A VRT of the global 15" grid: nodata everywhere but the regions' boxes."""
    d = 1.0 / GEBCO_PER_DEG
    n = GEBCO_REGION_DEG * GEBCO_PER_DEG
    sources = "".join(
        f"<SimpleSource><SourceFilename>{p}</SourceFilename><SourceBand>1</SourceBand>"
        f'<SrcRect xOff="0" yOff="0" xSize="{n}" ySize="{n}"/>'
        f'<DstRect xOff="{(lon + 180) * GEBCO_PER_DEG}" '
        f'yOff="{(90 - lat - GEBCO_REGION_DEG) * GEBCO_PER_DEG}" xSize="{n}" ySize="{n}"/>'
        "</SimpleSource>\n"
        for p, (lat, lon) in zip(regions, boxes, strict=True)
    )
    return (
        f'<VRTDataset rasterXSize="{360 * GEBCO_PER_DEG}" rasterYSize="{180 * GEBCO_PER_DEG}">\n'
        f"<SRS>EPSG:4326</SRS><GeoTransform>-180, {d!r}, 0, 90, 0, {-d!r}</GeoTransform>\n"
        f'<VRTRasterBand dataType="Int16" band="1"><NoDataValue>{GEBCO_NODATA}</NoDataValue>\n'
        f"{sources}</VRTRasterBand></VRTDataset>\n"
    )


def make_gebco(out: Path, netcdf: bool) -> tuple[Path, float]:
    """Write (or reuse) ``out/gebco_synthetic.vrt`` (and with ``netcdf`` its CF netCDF-4 copy
    ``gebco_synthetic.nc``): (the path of the last, CPU seconds spent now)."""
    out.mkdir(parents=True, exist_ok=True)
    c0 = time.process_time()
    vrt = out / "gebco_synthetic.vrt"
    if not vrt.exists():
        etopo = read_etopo()
        regions = []
        for lat, lon in GEBCO_REGIONS:
            p = out / f"gebco_region_{lat}_{lon}.tif"
            if not p.exists():
                _region_tif(p, lat, lon, etopo)
            regions.append(p)
        _write_atomic(vrt, gebco_vrt(regions, GEBCO_REGIONS).encode())
    if not netcdf:
        return vrt, time.process_time() - c0
    import rasterio.shutil

    nc = out / "gebco_synthetic.nc"
    if not nc.exists():
        part = out / "gebco_synthetic.part.nc"
        # GDAL's netCDF CreateCopy: one chunk a row (86 400 x 1), every row written (26 CPU s).
        rasterio.shutil.copy(
            vrt, part, driver="netCDF", FORMAT="NC4C", COMPRESS="DEFLATE", ZLEVEL="1"
        )
        os.replace(part, nc)
    return nc, time.process_time() - c0


# -- command line --------------------------------------------------------------------------------


def _center(text: str) -> tuple[float, float]:
    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise PlanetError(f"--center must be LAT,LON in degrees, not {text!r}") from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise PlanetError(f"--center {text}: latitude -90..90, longitude -180..180")
    return lat, lon


def main(argv: list[str] | None = None) -> int:
    class Parser(argparse.ArgumentParser):
        def error(self, message: str) -> NoReturn:
            raise PlanetError(message)

    ap = Parser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    s = sub.add_parser("srtm", help='N one-degree 3" SRTM tiles (or 1" placeholders)')
    s.add_argument("--tiles", type=int, required=True, help="how many (the nearest land cells)")
    s.add_argument("--center", default="46,10", help="LAT,LON the region grows from (the Alps)")
    s.add_argument("--placeholders", action="store_true", help='sparse 1"-size files: --plan')
    s.add_argument("--out", type=Path, default=None, help="folder (default benchmarks/cache/…)")
    g = sub.add_parser("gebco", help='the GEBCO-size 15" global grid (mostly nodata)')
    g.add_argument("--out", type=Path, default=CACHE / "gebco")
    g.add_argument("--netcdf", action="store_true", help="also its CF netCDF-4 copy (26 CPU s)")
    try:
        args = ap.parse_args(argv)
        if args.what == "srtm":
            if not 1 <= args.tiles <= 180 * 360:
                raise PlanetError(f"--tiles must be 1..{180 * 360}, not {args.tiles}")
            kind = "srtm1_placeholders" if args.placeholders else "srtm3"
            out = args.out or CACHE / kind
            listing, made, cpu = ensure_srtm(
                out, args.tiles, _center(args.center), args.placeholders
            )
            print(f"{listing}: {args.tiles} tiles ({made} written now, {cpu:.1f} CPU s)")
        else:
            path, cpu = make_gebco(args.out, args.netcdf)
            print(f'{path}: 86400 x 43200 15" cells ({cpu:.1f} CPU s now)')
    except (PlanetError, OSError) as exc:
        msg = exc if isinstance(exc, PlanetError) else f"{exc.strerror}: {exc.filename}"
        print(f"make_planet: error: {msg}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
