"""Generate a county-size 1 m LiDAR-like DTM in UTM (SYNTHETIC, reproducible, out of core).

The shape of a common public download (a county's bare-earth DTM from an airborne LiDAR
survey): N x N float32 pixels of 1 m (default 50 000 x 50 000, 2.5 G pixels) in UTM zone 19N
on NAD83 (EPSG:26919), a tiled (512 x 512) DEFLATE GeoTIFF with the floating-point
predictor, nodata (-9999) outside an irregular county-like footprint (a lobed outline with a
wiggling river border and a straight surveyed north line), heights in metres above sea
level. It lies over the White Mountains of New Hampshire, centred at 71.40 W 44.35 N:

- the base is the real SRTM3 tile data/N44W072.hgt sampled bilinearly at the nodes of a 30 m
  UTM grid (through pyproj), then interpolated to the 1 m pixel centres by a cubic
  (Catmull-Rom, separable);
- on top, SYNTHETIC fractal detail: six octaves of cubic value noise (periods 2048 m down to 2 m,
  amplitudes 12 m down to 4 cm), whose lattice values are hashed (splitmix64, as
  `make_big_dem`) from integer lattice coordinates: every window agrees with its neighbours
  and the file is identical on every run.

Written window by window (512 rows x 10 240 columns: a few tens of MB of memory whatever N)
into a `.part.tif` renamed when complete; an existing output is reused.

    python benchmarks/make_dtm.py [--size 50000] [--out /work/cache_keep/dtm/dtm_50000.tif]
    python benchmarks/make_dtm.py --out DTM.tif --check STORE   # heights of a store built from it
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyproj
import rasterio
import rasterio.features
from affine import Affine
from rasterio.windows import Window

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from make_planet import _hash01 as planet_hash01  # noqa: E402  (a sibling script)

CACHE = ROOT / "benchmarks" / "cache"
SRTM = ROOT / "data" / "N44W072.hgt"
CRS = "EPSG:26919"  # NAD83 / UTM zone 19N
CENTRE_LONLAT = (-71.40, 44.35)
NODATA = -9999.0
BLOCK = 512
WINDOW_COLS = 20 * BLOCK
BASE_STEP_M = 30.0
#: Largest lattice run interpolated by a matrix product rather than gathers.
_MATMUL_LATTICE = 40
#: (period in pixels = metres, amplitude in metres) of the value-noise octaves.
OCTAVES = ((2048, 12.0), (512, 4.0), (128, 1.5), (32, 0.5), (8, 0.15), (2, 0.04))


def _hash01(ix: np.ndarray, iy: np.ndarray, octave: int) -> np.ndarray:
    """make_planet.py's lattice hash with this script's salt, as float32 in [-1, 1)."""
    return planet_hash01(ix, iy, octave, salt=13).astype(np.float32)


def _axis_weights(
    idx: np.ndarray, period: float, shift: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Lattice cell (int64) and Catmull-Rom weights (float32, (4, n): lattice points i-1..i+2)
    of each pixel centre ``idx + 0.5`` along one axis, ``shift`` lattice steps from point 0.
    A cubic through the lattice values: C1, with none of the flats and creases that
    smoothstep or linear value noise leaves on the lattice lines (seen in a hillshade)."""
    f = (idx + 0.5) / period + shift
    i = np.floor(f).astype(np.int64)
    t = f - i
    t2, t3 = t * t, t * t * t
    w = np.stack(
        [
            (-t3 + 2 * t2 - t) / 2,
            (3 * t3 - 5 * t2 + 2) / 2,
            (-3 * t3 + 4 * t2 + t) / 2,
            (t3 - t2) / 2,
        ]
    )
    return i, w.astype(np.float32)


def _weight_matrix(i: np.ndarray, w: np.ndarray, n_lattice: int) -> np.ndarray:
    """Dense (pixels, n_lattice) float32 matrix of the four weights of each pixel (cell
    indices ``i`` relative to the lattice's second point)."""
    m = np.zeros((i.size, n_lattice), dtype=np.float32)
    rows = np.arange(i.size)
    for k in range(4):
        np.add.at(m, (rows, i + k), w[k])
    return m


def _separable(
    lattice: np.ndarray,
    rows: tuple[np.ndarray, np.ndarray],
    cols: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """Interpolate a lattice (rows x cols of lattice points) at the pixels: along columns,
    then rows; ``rows``/``cols`` are cell indices relative to ``lattice``'s second point and
    their weights (`_axis_weights`). A pass over a few lattice points is a small matrix
    product (BLAS); over many, four gathers."""
    ci, cw = cols
    if lattice.shape[1] <= _MATMUL_LATTICE:
        a = lattice @ _weight_matrix(ci, cw, lattice.shape[1]).T
    else:
        a = sum(lattice[:, ci + k] * cw[k] for k in range(4))
    ri, rw = rows
    if lattice.shape[0] <= _MATMUL_LATTICE:
        return _weight_matrix(ri, rw, lattice.shape[0]) @ a
    return sum(a[ri + k] * rw[k][:, None] for k in range(4))


def _lattice_span(i: np.ndarray) -> np.ndarray:
    """Lattice indices a run of cells ``i`` needs (its first cell's point - 1 .. last + 2)."""
    return np.arange(i[0] - 1, i[-1] + 3)


def _noise(r: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Sum of the value-noise octaves (metres, float32) at pixel rows r x columns c."""
    out = np.zeros((r.size, c.size), dtype=np.float32)
    for octave, (period, amp) in enumerate(OCTAVES):
        ri, rw = _axis_weights(r, period)
        ci, cw = _axis_weights(c, period)
        ly, lx = _lattice_span(ri), _lattice_span(ci)
        lat = _hash01(lx[None, :], ly[:, None], octave)
        out += np.float32(amp) * _separable(lat, (ri - ri[0], rw), (ci - ci[0], cw))
    return out


def _base_grid(origin: tuple[float, float], size: int) -> np.ndarray:
    """SRTM3 heights (metres, float32) at the nodes x0 + 30 m * (i - 1), y0 - 30 m * (j - 1)
    of the UTM grid covering the raster (two nodes past each side), bilinear in the tile's
    lon/lat."""
    with rasterio.open(SRTM) as src:
        srtm = src.read(1).astype(np.float64)  # 1201 x 1201 nodes, -72..-71, 45..44 (3")
    n = math.ceil(size / BASE_STEP_M) + 4
    x = origin[0] + BASE_STEP_M * (np.arange(n) - 1)
    y = origin[1] - BASE_STEP_M * (np.arange(n) - 1)
    gx, gy = np.meshgrid(x, y)
    to_ll = pyproj.Transformer.from_crs(CRS, "EPSG:4269", always_xy=True)
    lon, lat = to_ll.transform(gx.ravel(), gy.ravel())
    u = (np.asarray(lon) + 72.0) * 1200.0
    v = (45.0 - np.asarray(lat)) * 1200.0
    if not (u.min() >= 0 and v.min() >= 0 and u.max() < 1200 and v.max() < 1200):
        raise SystemExit(
            f"a {size} m raster at {CENTRE_LONLAT} leaves {SRTM.name}: use a smaller --size"
        )
    i, j = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    tu, tv = u - i, v - j
    top = srtm[j, i] * (1 - tu) + srtm[j, i + 1] * tu
    bot = srtm[j + 1, i] * (1 - tu) + srtm[j + 1, i + 1] * tu
    return (top + (bot - top) * tv).reshape(n, n).astype(np.float32)


def footprint(size: int) -> dict[str, object]:
    """The county-like outline in pixel coordinates (GeoJSON polygon): a lobed disc (a few
    low harmonics of the radius) with a wiggling river border on its south-east (hashed
    fractal jitter) and a straight surveyed line across the north, inside the raster."""
    k = np.arange(720)
    theta = 2.0 * np.pi * k / k.size
    r = 1.0 + 0.10 * np.sin(2 * theta + 0.7) + 0.07 * np.sin(3 * theta + 2.1)
    r += 0.04 * np.sin(5 * theta + 4.0) + 0.02 * np.sin(9 * theta + 1.3)
    river = (theta > 4.2) & (theta < 6.0)  # south-east: y grows downwards (rows)
    jitter = np.zeros(k.size)
    for octave, (period, amp) in enumerate(((40, 0.05), (10, 0.02), (3, 0.008))):
        cell = k / period
        i0 = np.floor(cell).astype(np.int64)
        t = cell - i0
        v0 = _hash01(i0, np.zeros_like(i0), 100 + octave).astype(np.float64)
        v1 = _hash01(i0 + 1, np.zeros_like(i0), 100 + octave).astype(np.float64)
        jitter += amp * (v0 + (v1 - v0) * t)
    r = np.where(river, r + jitter, r)
    half = size / 2.0
    radius = 0.42 * size
    x = half + radius * r * np.cos(theta)
    y = half - radius * r * np.sin(theta)
    y = np.maximum(y, 0.12 * size)  # the straight north line
    ring = np.column_stack([np.clip(x, 1, size - 1), np.clip(y, 1, size - 1)])
    ring = np.vstack([ring, ring[:1]])
    return {"type": "Polygon", "coordinates": [ring.tolist()]}


def _origin(size: int) -> tuple[float, float]:
    """UTM (x, y) of the raster's top-left corner: the centre on CENTRE_LONLAT, whole metres."""
    to_utm = pyproj.Transformer.from_crs("EPSG:4269", CRS, always_xy=True)
    cx, cy = to_utm.transform(*CENTRE_LONLAT)
    return float(round(cx - size / 2.0)), float(round(cy + size / 2.0))


def _write(path: Path, size: int) -> None:
    """Write the raster window by window into ``path``."""
    x0, y0 = _origin(size)
    base = _base_grid((x0, y0), size)
    outline = footprint(size)
    profile = {
        "driver": "GTiff",
        "dtype": "float32",
        "count": 1,
        "width": size,
        "height": size,
        "crs": CRS,
        "transform": Affine(1.0, 0.0, x0, 0.0, -1.0, y0),
        "nodata": NODATA,
        "tiled": True,
        "blockxsize": BLOCK,
        "blockysize": BLOCK,
        "compress": "deflate",
        "predictor": 3,
        "BIGTIFF": "YES",
    }
    with rasterio.open(path, "w", **profile) as dst:
        dst.update_tags(
            SYNTHETIC="1 m fractal value-noise detail on SRTM3 N44W072 in UTM 19N (benchmark)",
            AREA_OR_POINT="Area",
        )
        for r0 in range(0, size, BLOCK):
            r = np.arange(r0, min(r0 + BLOCK, size))
            # Base node 1 is at the raster's corner: pixel centre (c + 0.5) / 30 + 1 nodes.
            bri, brw = _axis_weights(r, BASE_STEP_M, shift=1.0)
            for c0 in range(0, size, WINDOW_COLS):
                c = np.arange(c0, min(c0 + WINDOW_COLS, size))
                bci, bcw = _axis_weights(c, BASE_STEP_M, shift=1.0)
                sub = base[bri[0] - 1 : bri[-1] + 3, bci[0] - 1 : bci[-1] + 3]
                inside = rasterio.features.rasterize(
                    [(outline, 1)],
                    out_shape=(r.size, c.size),
                    transform=Affine.translation(c0, r0),
                    dtype=np.uint8,
                ).astype(bool)
                if not inside.any():
                    z = np.full(inside.shape, NODATA, dtype=np.float32)
                else:
                    z = _separable(sub, (bri - bri[0], brw), (bci - bci[0], bcw))
                    z += _noise(r, c)
                    z[~inside] = NODATA
                dst.write(z, 1, window=Window(c0, r0, c.size, r.size))


def make(size: int, out: Path | None = None, quiet: bool = False) -> Path:
    """Write (or reuse) the size x size DTM and return its path."""
    path = out or CACHE / f"dtm_{size}.tif"
    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    need = size * size * 4 * 0.75  # float32, ~2.5 bytes a data pixel after DEFLATE + margin
    free = shutil.disk_usage(path.parent).free
    if free < need:
        raise SystemExit(
            f"{path.parent}: {free / 1e9:.1f} GB free, the DTM needs ~{need / 1e9:.1f} GB"
        )
    tmp = path.with_suffix(".part.tif")
    t0, c0 = time.perf_counter(), time.process_time()
    _write(tmp, size)
    tmp.rename(path)
    if not quiet:
        print(
            f"wrote {path} ({size}x{size} 1 m, SYNTHETIC detail, {path.stat().st_size / 1e9:.2f}"
            f" GB) in {time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} CPU s"
        )
    return path


def check_points(path: Path, count: int) -> list[tuple[float, float, float]]:
    """``count`` deterministic pixel centres with data (hashed positions within the middle 90 %
    of the raster) as (lon, lat, height in the file), on WGS84 (EPSG:4326, as the reader
    places the raster)."""
    out: list[tuple[float, float, float]] = []
    to_ll = pyproj.Transformer.from_crs(CRS, "EPSG:4326", always_xy=True)
    k = 0
    with rasterio.open(path) as ds:
        while len(out) < count and k < 100 * count:
            u = float(_hash01(np.array([k]), np.array([7]), 200)[0]) * 0.45 + 0.5
            v = float(_hash01(np.array([k]), np.array([11]), 200)[0]) * 0.45 + 0.5
            k += 1
            col, row = int(u * ds.width), int(v * ds.height)
            z = float(ds.read(1, window=Window(col, row, 1, 1))[0, 0])
            if z == NODATA:
                continue
            x, y = ds.transform @ (col + 0.5, row + 0.5)
            lon, lat = to_ll.transform(x, y)
            out.append((float(lon), float(lat), z))
    return out


def check(path: Path, store: Path, count: int) -> None:
    """Print `globeview height` of ``store`` at ``count`` pixel centres of the raster beside the
    pixel's own height (the store's H = h - N(EGM96): the DTM is taken as EGM96 heights)."""
    pts = check_points(path, count)
    exe = Path(sys.executable).with_name("globeview")
    args = [
        str(exe),
        "height",
        *(f"{lon:.9f},{lat:.9f}" for lon, lat, _ in pts),
        str(store),
        "--json",
    ]
    answers = json.loads(subprocess.run(args, check=True, capture_output=True, text=True).stdout)
    worst = 0.0
    print(f"{'lon':>14} {'lat':>13} {'file m':>9} {'store H m':>10} {'diff m':>7}  layer")
    for (lon, lat, z), a in zip(pts, answers, strict=True):
        h = a["orthometric_m"]
        diff = math.nan if h is None else h - z
        worst = max(worst, abs(diff)) if h is not None else math.inf
        shown = math.nan if h is None else h
        print(f"{lon:14.9f} {lat:13.9f} {z:9.3f} {shown:10.3f} {diff:7.3f}  {a['layer']}")
    print(f"largest |store - file|: {worst:.3f} m over {len(pts)} points")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=50_000, help="pixels a side (1 m each)")
    ap.add_argument(
        "--out", type=Path, default=None, help="output GeoTIFF (default under benchmarks/cache)"
    )
    ap.add_argument(
        "--check",
        type=Path,
        default=None,
        metavar="STORE",
        help="compare `globeview height` of STORE with the raster at pixel centres (no writing)",
    )
    ap.add_argument("--points", type=int, default=8, help="points for --check")
    args = ap.parse_args()
    if not 1000 <= args.size <= 60_000:
        raise SystemExit("--size must lie in 1000..60000")
    if args.check is not None:
        path = args.out or CACHE / f"dtm_{args.size}.tif"
        check(path, args.check, args.points)
        return
    print(make(args.size, args.out))


if __name__ == "__main__":
    main()
