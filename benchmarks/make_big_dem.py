"""Generate a large synthetic-detail DEM for the ingest benchmark (out of core, reproducible).

The base is the real SRTM3 tile N44W072 (White Mountains, 1201 x 1201, 3") resampled
bilinearly onto an N x N grid over the same 1 x 1 degree; on top of it we add SYNTHETIC
fractal detail (value-noise octaves, 4 octaves from 256 to 4 pixels, a few metres): the
lattice values are hashed from integer lattice coordinates, so every window agrees with its
neighbours and the file is identical on every run. Written window by window (1024 rows at a
time) as an uncompressed tiled float32 GeoTIFF under benchmarks/cache/.

    python benchmarks/make_big_dem.py [--size 16384]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import from_bounds
from rasterio.windows import Window

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "benchmarks" / "cache"
SRTM = ROOT / "data" / "N44W072.hgt"
ROWS_PER_WINDOW = 1024


def _hash01(ix: np.ndarray, iy: np.ndarray, octave: int) -> np.ndarray:
    """Deterministic pseudo-random value in [-1, 1) per integer lattice point (splitmix64)."""
    with np.errstate(over="ignore"):
        z = (ix.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)) ^ (
            iy.astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F) + np.uint64(octave * 7919)
        )
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) / float(1 << 53) * 2.0 - 1.0


def _value_noise(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Sum of value-noise octaves (metres) at integer pixel rows x cols of the big grid."""
    out = np.zeros((rows.size, cols.size), dtype=np.float64)
    for octave, (period, amp) in enumerate(((256, 8.0), (64, 3.0), (16, 1.0), (4, 0.3))):
        fy, fx = rows / period, cols / period
        iy, ix = np.floor(fy).astype(np.int64), np.floor(fx).astype(np.int64)
        ty, tx = fy - iy, fx - ix
        ty, tx = ty * ty * (3 - 2 * ty), tx * tx * (3 - 2 * tx)  # smoothstep
        yy, xx = np.meshgrid(iy, ix, indexing="ij")
        v00 = _hash01(xx, yy, octave)
        v01 = _hash01(xx + 1, yy, octave)
        v10 = _hash01(xx, yy + 1, octave)
        v11 = _hash01(xx + 1, yy + 1, octave)
        top = v00 + (v01 - v00) * tx[None, :]
        bot = v10 + (v11 - v10) * tx[None, :]
        out += amp * (top + (bot - top) * ty[:, None])
    return out


def make(size: int, quiet: bool = False) -> Path:
    """Write (or reuse) the N x N DEM and return its path."""
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"big_dem_{size}.tif"
    if path.exists():
        return path
    with rasterio.open(SRTM) as src:
        base = src.read(1).astype(np.float64)  # 1201 x 1201 nodes, -72..-71, 45..44
    n_b = base.shape[0] - 1
    tmp = path.with_suffix(".part.tif")
    # Pixel-is-area cells whose centres span the tile edge to edge.
    d = 1.0 / size
    transform = from_bounds(-72.0 - d / 2, 44.0 - d / 2, -71.0 + d / 2, 45.0 + d / 2, size, size)
    profile = {
        "driver": "GTiff",
        "dtype": "float32",
        "count": 1,
        "width": size,
        "height": size,
        "crs": "EPSG:4326",
        "transform": transform,
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
        "BIGTIFF": "YES",
    }
    t0 = time.perf_counter()
    cols = np.arange(size)
    u = cols * n_b / (size - 1)
    i0 = np.minimum(np.floor(u).astype(np.int64), n_b - 1)
    tu = u - i0
    with rasterio.open(tmp, "w", **profile) as dst:
        dst.update_tags(SYNTHETIC="fractal value-noise detail added to SRTM3 N44W072 (benchmark)")
        for r0 in range(0, size, ROWS_PER_WINDOW):
            rows = np.arange(r0, min(r0 + ROWS_PER_WINDOW, size))
            v = rows * n_b / (size - 1)
            j0 = np.minimum(np.floor(v).astype(np.int64), n_b - 1)
            tv = (v - j0)[:, None]
            a = base[j0][:, i0] * (1 - tu) + base[j0][:, i0 + 1] * tu
            b = base[j0 + 1][:, i0] * (1 - tu) + base[j0 + 1][:, i0 + 1] * tu
            z = a + (b - a) * tv + _value_noise(rows, cols)
            dst.write(z.astype(np.float32), 1, window=Window(0, r0, size, rows.size))
    tmp.rename(path)
    if not quiet:
        print(f"wrote {path} ({size}x{size}, synthetic detail) in {time.perf_counter() - t0:.1f} s")
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=16384)
    args = ap.parse_args()
    print(make(args.size))


if __name__ == "__main__":
    main()
