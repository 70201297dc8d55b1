"""The ingest's per-window numerics (issue #18): today's kernels against the straightforward
ones they replaced, on real heights, CPU per window and whether the results are identical.

Windows come from the 8192^2 benchmark DEM (benchmarks/cache/big_dem_8192.tif, made by
make_big_dem.py) when present, else from data/N44W072.hgt, read at the level-14 node spacing
with `Dem.read_grid` (the ingest's source read, timed too: the separable resampler of issue
#25 C1 against GDAL's warp it stands for, with their largest difference in float32 ulps).
Kernels:

- errors:  one 1025^2 finest window against the coarser pyramid levels f = 2 .. 1024 (its own
           wavelet pyramid): `tile_errors.upsampled_error_tiles` vs the gather upsampling,
           `cell_max` and `reduce_cells` of the serial ingest;
- pruned:  the same errors by branch and bound (`tile_errors.pruned_error_tiles`, issue #25
           C2: blocks that cannot hold their tile's maximum skipped) vs the strip pass above;
- stats:   hmin/hmax and stride deltas of that window (`tile_min_max`, `stride_deltas`) vs
           `cell_min`/`cell_max` and a gather upsampling per stride;
- wavelet: `approximate_window` on a 2053^2 window, all valid and with a NaN border, vs the
           whole-array passes (mirror pad, four separable passes when NaN is present).

CPU per call is ``time.thread_time`` (median of the rounds, the two versions interleaved),
less sensitive to the load of a shared machine than wall time; the load is printed.

    .venv/bin/python benchmarks/bench_ingest_kernels.py [--rounds 7]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import statistics
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from affine import Affine
from rasterio.enums import Resampling
from rasterio.warp import reproject

from globeview.terrain.dem import reader as dem_module
from globeview.terrain.dem.reader import open_dem
from globeview.terrain.ingest import wavelet as wv
from globeview.terrain.ingest.tile_errors import (
    cell_max,
    cell_min,
    error_window,
    pruned_error_tiles,
    reduce_cells,
    stride_deltas,
    tile_min_max,
    transposed_nodes,
    upsample_nodes,
    upsampled_error_tiles,
)
from globeview.terrain.quadtree import node_spacing

ROOT = Path(__file__).resolve().parents[1]
BIG = ROOT / "benchmarks" / "cache" / "big_dem_8192.tif"
SMALL = ROOT / "data" / "N44W072.hgt"
S_N = 64
STRIDES = (2, 4, 8, 16, 32, 64)


def _cpu_ms(fn: Callable[[], object]) -> float:
    t = time.thread_time()
    fn()
    return (time.thread_time() - t) * 1e3


def _gdal_warp(arr: np.ndarray, src_t: Affine, dst_t: Affine, shape: tuple[int, int]):
    """GDAL's bilinear warp as `Dem._warp` called it before the separable resampler."""
    dst = np.full(shape, np.nan, dtype=np.float32)
    reproject(
        arr,
        dst,
        src_transform=src_t,
        src_crs="EPSG:4326",
        dst_transform=dst_t,
        dst_crs="EPSG:4326",
        resampling=Resampling.bilinear,
        src_nodata=np.nan,
        dst_nodata=np.nan,
    )
    return dst


@contextlib.contextmanager
def _with_gdal_warp() -> Iterator[None]:
    """`Dem.read_grid` through GDAL's warp for lon/lat sources (as before issue #25 C1)."""
    separable = dem_module.resample_bilinear
    dem_module.resample_bilinear = _gdal_warp
    try:
        yield
    finally:
        dem_module.resample_bilinear = separable


def _max_ulps(a: np.ndarray, b: np.ndarray) -> float:
    """Largest |a - b| in float32 ulps of b (NaN where both are NaN; inf if NaN differs)."""
    if not np.array_equal(np.isnan(a), np.isnan(b)):
        return float("inf")
    ok = ~np.isnan(b)
    diff = np.abs(a[ok].astype(np.float64) - b[ok])
    return float((diff / np.spacing(np.abs(b[ok]))).max()) if ok.any() else 0.0


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    ia = a.view(np.int64 if a.dtype == np.float64 else np.int32).copy()
    ib = b.view(np.int64 if b.dtype == np.float64 else np.int32).copy()
    ia[np.isnan(a)] = -1
    ib[np.isnan(b)] = -1
    return bool(np.array_equal(ia, ib))


def _errors_reference(fine: np.ndarray, pyramid: dict[int, np.ndarray]) -> list[np.ndarray]:
    h, w = fine.shape
    fine64 = fine.astype(np.float64)
    out = []
    for f, coarse in pyramid.items():
        up = upsample_nodes(coarse, f, np.arange(h), np.arange(w))
        np.subtract(up, fine64, out=up)
        np.abs(up, out=up)
        span = f * S_N
        out.append(
            reduce_cells(cell_max(up), np.arange(h - 1) // span, np.arange(w - 1) // span)[2]
        )
    return out


def _errors_new(fine: np.ndarray, pyramid: dict[int, np.ndarray]) -> list[np.ndarray]:
    fine_t = transposed_nodes(fine)
    return [
        upsampled_error_tiles(coarse, fine_t, f, 0, 0, 0, 0, f * S_N, S_N)[2]
        for f, coarse in pyramid.items()
    ]


def _errors_pruned(fine: np.ndarray, pyramid: dict[int, np.ndarray]) -> list[np.ndarray]:
    win = error_window(fine)
    return [
        pruned_error_tiles(coarse, win, f, 0, 0, 0, 0, f * S_N, S_N)[2]
        for f, coarse in pyramid.items()
    ]


def _stats_reference(arr: np.ndarray) -> list[np.ndarray]:
    kty, ktx = (arr.shape[0] - 1) // S_N, (arr.shape[1] - 1) // S_N

    def per_tile(cells: np.ndarray, op: np.ufunc) -> np.ndarray:
        return op.reduce(op.reduce(cells.reshape(kty, S_N, ktx, S_N), axis=3), axis=1)

    rows, cols = np.arange(arr.shape[0]), np.arange(arr.shape[1])
    delta = np.zeros((kty, ktx))
    deltas = np.zeros((kty, ktx, len(STRIDES)))
    for i, s in enumerate(STRIDES):
        up = upsample_nodes(arr[::s, ::s], s, rows, cols, np.float32)
        np.subtract(up, arr, out=up)
        np.abs(up, out=up)
        delta = np.maximum(delta, np.nan_to_num(per_tile(cell_max(up), np.fmax), nan=0.0))
        deltas[:, :, i] = delta
    return [per_tile(cell_min(arr), np.fmin), per_tile(cell_max(arr), np.fmax), deltas]


def _stats_new(arr: np.ndarray) -> list[np.ndarray]:
    lo, hi = tile_min_max(arr, S_N)
    return [lo, hi, stride_deltas(arr, S_N, STRIDES)]


def _wavelet_reference(window: np.ndarray, halo: int) -> np.ndarray:
    """approximate_window as whole-array passes (its implementation before #18)."""
    taps = wv.lowpass_kernel()

    def sep(a: np.ndarray, k: np.ndarray) -> np.ndarray:
        return wv._filter_decimate(wv._filter_decimate(a, k, 1, 2), k, 0, 2)

    h = taps.size // 2
    padded = np.pad(window, h, mode="reflect", reflect_type="odd")
    invalid = np.isnan(padded)
    if not invalid.any():
        out = sep(padded, taps)
    else:
        values = np.where(invalid, np.float32(0.0), padded)
        exact = sep(values, taps)
        touched = sep(invalid.astype(np.float32), np.ones_like(taps)) > 0.5
        positive = np.clip(taps, 0.0, None)
        num = sep(values, positive)
        den = sep((~invalid).astype(np.float32), positive)
        convex = np.divide(num, den, out=np.full_like(num, np.nan), where=den > 0)
        out = np.where(touched, convex, exact)
        out[np.isnan(window[::2, ::2])] = np.nan
    k = halo // 2
    return out.astype(np.float32)[k:-k, k:-k]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args()
    if args.rounds < 1:
        raise SystemExit("--rounds must be at least 1")
    src = BIG if BIG.exists() else SMALL
    d = node_spacing(14, 6)
    with open_dem(src) as dem:
        west, _, _, north = dem.info.bounds_lonlat
        west, north = west + 16 * d, north - 16 * d

        def read() -> np.ndarray:
            return dem.read_grid(west, north, d, d, 1025, 1025)

        sep_ms, gdal_ms = [], []
        for _ in range(args.rounds):
            sep_ms.append(_cpu_ms(read))
            with _with_gdal_warp():
                gdal_ms.append(_cpu_ms(read))
        with _with_gdal_warp():
            reference = read()
        ulps = _max_ulps(read(), reference)
        big = dem.read_grid(west, north, d, d, 2053, 2053)
    fine = big[:1025, :1025].copy()
    # The window's own wavelet pyramid stands in for the coarser levels (f = 2 .. 1024).
    pyramid: dict[int, np.ndarray] = {}
    level = fine
    for k in range(1, 11):
        level = wv.approximate_grid(level)
        pyramid[1 << k] = level
    edge = big.copy()
    edge[:, :40] = np.nan  # a no-data border, as at a source's edge
    edge[-25:, :] = np.nan
    cases: list[tuple[str, Callable[[], list], Callable[[], list]]] = [
        (
            f"errors, 1025^2 window x {len(pyramid)} levels",
            lambda: _errors_reference(fine, pyramid),
            lambda: _errors_new(fine, pyramid),
        ),
        (
            "errors pruned (C2) vs the strip pass",
            lambda: _errors_new(fine, pyramid),
            lambda: _errors_pruned(fine, pyramid),
        ),
        (
            "hmin/hmax + stride deltas, 1025^2",
            lambda: _stats_reference(fine),
            lambda: _stats_new(fine),
        ),
        (
            "wavelet 2053^2 window, valid",
            lambda: [_wavelet_reference(big, 2)],
            lambda: [wv.approximate_window(big, 2)],
        ),
        (
            "wavelet 2053^2 window, NaN border",
            lambda: [_wavelet_reference(edge, 2)],
            lambda: [wv.approximate_window(edge, 2)],
        ),
    ]
    load = os.getloadavg()
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(
                (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu
            )
    except OSError:
        pass
    print(
        f"# ingest kernels, {src.name}, {cpu}, {len(os.sched_getaffinity(0))} cores, "
        f"{datetime.now(UTC):%Y-%m-%d %H:%M} UTC, load {load[0]:.2f} {load[1]:.2f}"
    )
    print(
        f"source read (Dem.read_grid) of a 1025^2 window: GDAL warp "
        f"{statistics.median(gdal_ms):.1f} ms CPU, separable resampler (C1) "
        f"{statistics.median(sep_ms):.1f} ms, largest difference {ulps:.1f} ulp of float32"
    )
    print(f"{'kernel':40s} {'before ms':>10s} {'after ms':>9s} {'speed-up':>9s}  identical")
    for name, old, new in cases:
        same = all(_same(a, b) for a, b in zip(old(), new(), strict=True))
        t_old, t_new = [], []
        for _ in range(args.rounds):
            t_old.append(_cpu_ms(old))
            t_new.append(_cpu_ms(new))
        a, b = statistics.median(t_old), statistics.median(t_new)
        print(f"{name:40s} {a:10.1f} {b:9.1f} {a / b:8.2f}x  {'yes' if same else 'NO'}")
    print(f"load at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
