"""Build a tile-pyramid store from DEM rasters (the engine of `globeview ingest`).

Pipeline (every step works window by window, so memory is bounded by the window size and
GDAL's block cache, not by the raster size):

1. Sources are hashed (sha256) and opened with `open_dem`. Each source gets its natural finest
   level L_s: the level whose node spacing 180/2^L/2^n degrees is closest (round of log2) to
   the source's finer pixel size. L_max = max L_s (or ``max_level``).
2. Level extents: level L covers the tiles that the footprints of the sources with L_s >= L
   touch, plus the parents of level L+1's tiles (so levels nest). A global base thus makes
   every level up to its own L_s global, while a regional DEM adds detail levels only over
   its footprint.
3. Levels are written finest first. A window of level L is the wavelet approximation of level
   L+1 (read back from the raster just written, with ``kernel_halo`` nodes of halo); where that
   is NaN (outside level L+1 or no data there) the sources with L_s <= L are read on the level
   grid with `Dem.read_grid`, the finest source winning where it has data. The finest level is
   read from the sources only. Pole rows are set to one value (see below). Per-tile hmin,
   hmax and stride errors are computed from each window before it is written.
4. Tile errors: for every tile, max |tile bilinear surface - finest data| over the tile's
   footprint, evaluated exactly at the finest nodes (see `tile_errors`). The finest data of a
   place is the finest level that has data there; the pass walks those reference levels
   block by block and updates the per-tile maxima of every coarser level.
5. The manifest is written last, then the temporary directory is renamed into place.

Poles: the pole row of a level (lat = +-90) is a single point on the globe. When a level's
pole row holds data, its finite nodes are all set to the mean of the finest level's pole row
(computed once), at every level. (The odd-mirror wavelet approximation maps a constant pole
row to the same constant, so this is consistent with the pyramid.)
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
import tempfile
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rasterio
from rasterio.windows import Window

from globeview import __version__
from globeview.errors import DemError, StoreError
from globeview.terrain.dem import Dem, open_dem
from globeview.terrain.levels import LevelGrid, read_level_nodes
from globeview.terrain.quadtree import DEFAULT_TILE_N, level_shape, tiles_covering
from globeview.terrain.tile_errors import (
    cell_max,
    cell_min,
    reduce_cells,
    round_sig_down,
    round_sig_up,
    upsample_nodes,
)
from globeview.terrain.wavelet import (
    DEFAULT_WAVELET,
    approximate_window,
    kernel_halo,
    lowpass_kernel,
)

__all__ = [
    "FORMAT_VERSION",
    "MANIFEST_NAME",
    "STRIDES",
    "IngestResult",
    "ingest",
]

FORMAT_VERSION = 2
MANIFEST_NAME = "manifest.json"
STRIDES = (2, 4, 8, 16, 32, 64)
MAX_LEVEL_LIMIT = 22  # 180/2^22/64 degrees ~ 7 mm at the equator: far past any DEM
TILE_N_RANGE = (1, 10)

# A window is about this many nodes a side: big enough that per-window Python overhead is
# negligible, small enough that a window and its temporaries stay in tens of MB.
_WINDOW_NODES = 1024
# GDAL block cache during the build. rasterio's default (5% of RAM) would make the peak RSS
# depend on the machine; a fixed cache keeps the bound. Enough for a row of 256x256 blocks
# of a 64k-node-wide level.
_GDAL_CACHE_MB = 96


@dataclass
class IngestResult:
    """What `ingest` did: the store path and whether it was already up to date."""

    path: Path
    up_to_date: bool
    max_level: int = 0
    seconds: float = 0.0


@dataclass
class _Source:
    path: Path
    dem: Dem
    level: int  # its natural finest level, clamped to L_max
    res: float  # finer pixel size, degrees
    bounds: tuple[float, float, float, float]
    wraps: bool
    record: dict = field(default_factory=dict)


@dataclass
class _LevelStats:
    """Per-tile metadata of one level, arrays (ny, nx); NaN where a tile has no data."""

    hmin: np.ndarray
    hmax: np.ndarray
    error: np.ndarray
    stride_delta: np.ndarray  # (ny, nx, len(STRIDES)): max |S_s - S_1| per tile, see below
    pole: dict[str, float | None] = field(default_factory=dict)
    sha256: str = ""


# ---------------------------------------------------------------------------------------------
# Small helpers


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _natural_level(res_deg: float, tile_n: int) -> int:
    """Level whose node spacing 180/2^L/2^n is closest to res_deg (round of log2)."""
    lv = round(math.log2(180.0 / ((1 << tile_n) * res_deg)))
    return int(min(max(lv, 0), MAX_LEVEL_LIMIT))


def _column_mask(level: int, bounds: tuple[float, float, float, float], wraps: bool) -> tuple:
    """Columns (bool mask over the level) and row range of tiles a footprint touches."""
    ncols, _ = level_shape(level)
    w, s, e, n = bounds
    if wraps:
        w, e = -180.0, 180.0
    xs, ys = tiles_covering(level, w, s, e, n)
    mask = np.zeros(ncols, dtype=bool)
    mask[xs] = True
    return mask, int(ys.min()), int(ys.max())


def _extent_from_mask(mask: np.ndarray) -> tuple[int, int]:
    """(x0, nx) of the shortest run of columns, circularly, containing every True column."""
    ncols = mask.size
    idx = np.flatnonzero(mask)
    if idx.size == ncols:
        return 0, ncols
    nxt = np.roll(idx, -1)
    gap = (nxt - idx - 1) % ncols
    k = int(np.argmax(gap))
    return int(nxt[k]), int(ncols - gap[k])


def _lon_overlaps(a0: float, a1: float, b: tuple[float, float, float, float], wraps: bool) -> bool:
    """Whether the longitude interval [a0, a1] (a1 >= a0, may exceed 180) meets a footprint."""
    if wraps:
        return True
    w, _, e, _ = b
    width = (e - w) % 360.0 or (360.0 if e != w else 0.0)
    return any(a0 <= w + k + width and w + k <= a1 for k in (-360.0, 0.0, 360.0))


def _windows(grid: LevelGrid) -> Iterator[tuple[int, int, int, int]]:
    """Tile blocks (by, bx, kty, ktx) covering the extent, row-major."""
    k = max(1, _WINDOW_NODES // grid.tile_nodes)
    for by in range(0, grid.ny, k):
        for bx in range(0, grid.nx, k):
            yield by, bx, min(k, grid.ny - by), min(k, grid.nx - bx)


def _count_windows(grid: LevelGrid) -> int:
    k = max(1, _WINDOW_NODES // grid.tile_nodes)
    return -(-grid.ny // k) * -(-grid.nx // k)


def _profile(grid: LevelGrid) -> dict:
    return {
        "driver": "GTiff",
        "dtype": "float32",
        "count": 1,
        "width": grid.width,
        "height": grid.height,
        "crs": "EPSG:4326",
        "transform": grid.transform,
        "nodata": float("nan"),
        "tiled": True,
        "blockxsize": 256,
        "blockysize": 256,
        "compress": "deflate",
        "predictor": 3,
        "zlevel": 6,
        "num_threads": "ALL_CPUS",
        "bigtiff": "IF_SAFER",
    }


def _nan_to_none(a: np.ndarray) -> list:
    """Nested lists with None for NaN (JSON null)."""
    obj = a.astype(object)
    obj[np.isnan(a)] = None
    return obj.tolist()


# ---------------------------------------------------------------------------------------------
# The builder


class _Builder:
    def __init__(
        self,
        sources: list[_Source],
        tile_n: int,
        max_level: int,
        wavelet: str,
        out_dir: Path,
        tick: Callable[[int], None],
    ) -> None:
        self.sources = sources
        self.tile_n = tile_n
        self.max_level = max_level
        self.wavelet = wavelet
        self.halo = kernel_halo(wavelet)
        self.out_dir = out_dir
        self.tick = tick
        self.grids = self._plan_extents()
        self.stats: dict[int, _LevelStats] = {}
        self.pole: dict[str, float | None] = {"north": None, "south": None}

    # -- planning ---------------------------------------------------------------------------

    def _plan_extents(self) -> dict[int, LevelGrid]:
        grids: dict[int, LevelGrid] = {}
        finer: LevelGrid | None = None
        for lv in range(self.max_level, -1, -1):
            ncols, _ = level_shape(lv)
            mask = np.zeros(ncols, dtype=bool)
            y_lo, y_hi = 1 << 62, -1
            for s in self.sources:
                if s.level >= lv:
                    m, a, b = _column_mask(lv, s.bounds, s.wraps)
                    mask |= m
                    y_lo, y_hi = min(y_lo, a), max(y_hi, b)
            if finer is not None:
                px = (finer.x0 + np.arange(finer.nx)) % finer.ncols // 2
                mask[px] = True
                y_lo = min(y_lo, finer.y0 // 2)
                y_hi = max(y_hi, (finer.y0 + finer.ny - 1) // 2)
            x0, nx = _extent_from_mask(mask)
            finer = grids[lv] = LevelGrid(lv, self.tile_n, x0, y_lo, nx, y_hi - y_lo + 1)
        return grids

    def total_steps(self) -> int:
        n = sum(_count_windows(g) for g in self.grids.values())  # level writes
        n += sum(_count_windows(self.grids[lv]) for lv in range(1, self.max_level + 1))  # errors
        return n

    # -- sources ----------------------------------------------------------------------------

    def _fill_from_sources(
        self, out: np.ndarray, grid: LevelGrid, gr0: int, gc0: int, max_source_level: int
    ) -> None:
        """Fill NaN nodes of ``out`` (global node window at gr0, gc0) from the sources with
        L_s <= max_source_level, finest first (in place)."""
        h, w = out.shape
        d = grid.d
        west = -180.0 + gc0 * d
        north = 90.0 - gr0 * d
        south = north - (h - 1) * d
        west_n = (west + 180.0) % 360.0 - 180.0
        for s in self.sources:
            if s.level > max_source_level:
                continue
            if not np.isnan(out).any():
                return
            _, bs, _, bn = s.bounds
            if south > bn + d or north < bs - d:
                continue
            if not _lon_overlaps(west - d, west + (w - 1) * d + d, s.bounds, s.wraps):
                continue
            vals = s.dem.read_grid(west_n, north, d, d, w, h)
            np.copyto(out, vals, where=np.isnan(out))

    def _pole_values(self) -> None:
        """Mean of the finest level's pole rows (one point each on the globe)."""
        g = self.grids[self.max_level]
        for name, grow in (("north", 0), ("south", g.nrows * g.tile_nodes)):
            if g.raster_rows(np.array([grow]))[0] < 0:
                continue
            # One node row across the extent: small (a few MB even for a global level 12).
            row = np.full((1, g.width), np.nan, dtype=np.float32)
            self._fill_from_sources(row, g, grow, g.gc0, self.max_level)
            if np.isfinite(row).any():
                self.pole[name] = float(np.nanmean(row.astype(np.float64)))

    # -- level windows ----------------------------------------------------------------------

    def _window_values(
        self,
        grid: LevelGrid,
        fine_ds: rasterio.DatasetReader | None,
        gr0: int,
        gc0: int,
        h: int,
        w: int,
    ) -> np.ndarray:
        """Closed window of nodes of a level (global node indices), float32."""
        if fine_ds is None:
            out = np.full((h, w), np.nan, dtype=np.float32)
        else:
            fine = self.grids[grid.level + 1]
            hl = self.halo
            padded = read_level_nodes(
                fine_ds,
                fine,
                2 * gr0 - hl,
                2 * gc0 - hl,
                2 * h - 1 + 2 * hl,
                2 * w - 1 + 2 * hl,
                mirror=hl,
            )
            out = approximate_window(padded, hl, self.wavelet)
            # Coarse nodes whose own fine node is outside the finer raster carry no data.
            rows_out = fine.raster_rows(2 * (gr0 + np.arange(h))) < 0
            cols_out = fine.raster_cols(2 * (gc0 + np.arange(w))) < 0
            out[rows_out, :] = np.nan
            out[:, cols_out] = np.nan
        self._fill_from_sources(out, grid, gr0, gc0, grid.level)
        # Poles: one value per pole (finite nodes only: a partial pole row stays partial).
        if self.pole["north"] is not None and gr0 == 0:
            out[0, np.isfinite(out[0])] = self.pole["north"]
        south_row = grid.nrows * grid.tile_nodes - gr0
        if self.pole["south"] is not None and 0 <= south_row < h:
            out[south_row, np.isfinite(out[south_row])] = self.pole["south"]
        return out

    def _tile_stats(self, st: _LevelStats, arr: np.ndarray, by: int, bx: int) -> None:
        """hmin/hmax and stride deltas of the tiles of a closed, tile-aligned window."""
        s_n = 1 << self.tile_n
        kty, ktx = (arr.shape[0] - 1) // s_n, (arr.shape[1] - 1) // s_n
        sl = np.s_[by : by + kty, bx : bx + ktx]

        def per_tile(cells: np.ndarray, step: int, op: np.ufunc) -> np.ndarray:
            n = s_n // step
            return op.reduce(op.reduce(cells.reshape(kty, n, ktx, n), axis=3), axis=1)

        st.hmin[sl] = per_tile(cell_min(arr), 1, np.fmin)
        st.hmax[sl] = per_tile(cell_max(arr), 1, np.fmax)
        # Stride deltas: delta_s = max |S_s - S_1| over the tile, where S_s is the bilinear
        # surface on every s-th node and S_1 the tile's own. The max of a difference of
        # piecewise-bilinear surfaces on nested grids sits at the finer grid's nodes, so one
        # upsampling of the s-th nodes to every node gives it exactly; then
        # error(stride s) <= tile error + delta_s (triangle inequality, one term). (Chaining
        # the deltas of successive strides was cheaper but up to 2-3x too loose, which made the
        # LOD draw finer strides than needed.)
        # A running max keeps the bounds monotone: a coarser stride never claims to look
        # better than a finer one (it can by chance, when its nodes hit the features).
        rows = np.arange(arr.shape[0])
        cols = np.arange(arr.shape[1])
        delta = np.zeros((kty, ktx), dtype=np.float64)
        for i, s in enumerate(STRIDES):
            if s <= s_n:
                up = upsample_nodes(arr[::s, ::s], s, rows, cols, np.float32)
                np.subtract(up, arr, out=up)
                np.abs(up, out=up)
                exact = np.nan_to_num(per_tile(cell_max(up), 1, np.fmax), nan=0.0)
                delta = np.maximum(delta, exact)
            st.stride_delta[by : by + kty, bx : bx + ktx, i] = delta

    def _write_level(self, lv: int) -> None:
        grid = self.grids[lv]
        s_n = grid.tile_nodes
        st = _LevelStats(
            hmin=np.full((grid.ny, grid.nx), np.nan),
            hmax=np.full((grid.ny, grid.nx), np.nan),
            error=np.full((grid.ny, grid.nx), np.nan),
            stride_delta=np.zeros((grid.ny, grid.nx, len(STRIDES))),
        )
        path = self.out_dir / grid.file_name
        fine_path = self.out_dir / self.grids[lv + 1].file_name if lv < self.max_level else None
        with contextlib.ExitStack() as stack:
            fine_ds = stack.enter_context(rasterio.open(fine_path)) if fine_path else None
            dst = stack.enter_context(rasterio.open(path, "w", **_profile(grid)))
            dst.update_tags(AREA_OR_POINT="Point")
            dst.update_tags(1, LEVEL=str(lv), TILE_N=str(self.tile_n))
            first_col: np.ndarray | None = None
            for by, bx, kty, ktx in _windows(grid):
                h, w = kty * s_n + 1, ktx * s_n + 1
                arr = self._window_values(
                    grid, fine_ds, grid.gr0 + by * s_n, grid.gc0 + bx * s_n, h, w
                )
                if grid.global_lon:
                    # The east edge (lon 180) is the west edge (lon -180): make it identical.
                    if bx == 0:
                        first_col = arr[:, 0].copy()
                    if bx + ktx == grid.nx and first_col is not None:
                        arr[:, -1] = first_col
                self._tile_stats(st, arr, by, bx)
                # Write the half-open part; the last window row/column also writes its edge.
                hh = h if by + kty == grid.ny else h - 1
                ww = w if bx + ktx == grid.nx else w - 1
                dst.write(arr[:hh, :ww], 1, window=Window(bx * s_n, by * s_n, ww, hh))
                self.tick(1)
        st.pole = {k: (v if self._pole_row_in(grid, k) else None) for k, v in self.pole.items()}
        st.sha256 = _sha256(path)
        self.stats[lv] = st

    @staticmethod
    def _pole_row_in(grid: LevelGrid, which: str) -> bool:
        return grid.y0 == 0 if which == "north" else grid.y0 + grid.ny == grid.nrows

    # -- geometric errors -------------------------------------------------------------------

    def _has_data(self, lv: int, ty: np.ndarray, tx: np.ndarray) -> np.ndarray:
        g = self.grids[lv]
        iy, ix, inside = g.tile_slots(ty, tx)
        return inside & np.isfinite(self.stats[lv].hmin[iy, ix])

    def _errors(self) -> None:
        """Exact tile errors: max |bilinear tile - finest data| at the finest nodes."""
        for st in self.stats.values():
            st.error = np.where(np.isfinite(st.hmin), 0.0, np.nan)
        if self.max_level == 0:
            return
        dss = {lv: rasterio.open(self.out_dir / g.file_name) for lv, g in self.grids.items()}
        try:
            for lf in range(self.max_level, 0, -1):
                self._errors_against(lf, dss)
        finally:
            for ds in dss.values():
                ds.close()

    def _errors_against(self, lf: int, dss: dict[int, rasterio.DatasetReader]) -> None:
        gf = self.grids[lf]
        s_n = gf.tile_nodes
        for by, bx, kty, ktx in _windows(gf):
            self.tick(1)
            h, w = kty * s_n + 1, ktx * s_n + 1
            gr0, gc0 = gf.gr0 + by * s_n, gf.gc0 + bx * s_n
            owned = None
            if lf < self.max_level:
                # Cells whose level-(lf+1) quadrant has data are judged against that finer
                # level (in its own pass); here only the rest.
                half = s_n // 2
                ty = (gr0 + np.arange(h - 1)) // half
                tx = (gc0 + np.arange(w - 1)) // half
                has = self._has_data(lf + 1, ty[:, None], tx[None, :])
                if has.all():
                    continue
                owned = ~has
            fine = dss[lf].read(1, window=Window(bx * s_n, by * s_n, w, h))
            if not np.isfinite(fine).any():
                continue
            fine64 = fine.astype(np.float64)
            cell_r = gr0 + np.arange(h - 1)
            cell_c = gc0 + np.arange(w - 1)
            for lv in range(lf):
                g = self.grids[lv]
                f = 1 << (lf - lv)
                r0, c0 = gr0 // f, gc0 // f
                r1, c1 = -(-(gr0 + h - 1) // f), -(-(gc0 + w - 1) // f)
                coarse = read_level_nodes(dss[lv], g, r0, c0, r1 - r0 + 1, c1 - c0 + 1)
                up = upsample_nodes(
                    coarse, f, gr0 - r0 * f + np.arange(h), gc0 - c0 * f + np.arange(w)
                )
                np.subtract(up, fine64, out=up)
                np.abs(up, out=up)
                cells = cell_max(up)
                if owned is not None:
                    cells[~owned] = np.nan
                tile_span = f * s_n
                rv, cv, red = reduce_cells(cells, cell_r // tile_span, cell_c // tile_span)
                iy, ix, inside = g.tile_slots(rv[:, None], cv[None, :])
                iy, ix, inside = np.broadcast_arrays(iy, ix, inside)
                iy, ix, red = iy[inside], ix[inside], red[inside]
                err = self.stats[lv].error
                err[iy, ix] = np.fmax(err[iy, ix], red)

    # -- run --------------------------------------------------------------------------------

    def build(self) -> None:
        self._pole_values()
        for lv in range(self.max_level, -1, -1):
            self._write_level(lv)
        if not any(np.isfinite(st.hmin).any() for st in self.stats.values()):
            names = ", ".join(str(s.path) for s in self.sources)
            raise DemError(f"no valid heights in {names}: every sample is nodata")
        self._errors()

    def manifest(self, params: dict, source_records: list[dict]) -> dict:
        levels = []
        for lv in range(self.max_level + 1):
            g, st = self.grids[lv], self.stats[lv]
            has = np.isfinite(st.hmin)
            err = np.where(has, round_sig_up(np.nan_to_num(st.error, nan=0.0)), np.nan)
            # The subsampled and full surfaces both stay within [hmin, hmax] (bilinear
            # interpolation of nodes in that range), which caps the chained sum.
            span = (st.hmax - st.hmin)[:, :, None]
            stride = err[:, :, None] + np.minimum(st.stride_delta, span)
            stride = np.where(has[:, :, None], round_sig_up(stride), np.nan)
            level_error = float(np.nanmax(err)) if has.any() else None
            levels.append(
                {
                    "level": lv,
                    "file": g.file_name,
                    "extent": g.to_dict(),
                    "node_spacing_deg": g.d,
                    "error": _nan_to_none(err),
                    "hmin": _nan_to_none(np.where(has, round_sig_down(st.hmin), np.nan)),
                    "hmax": _nan_to_none(np.where(has, round_sig_up(st.hmax), np.nan)),
                    "stride_error": _nan_to_none(stride),
                    "level_error": level_error,
                    "pole_heights": st.pole,
                    "sha256": st.sha256,
                }
            )
        fine = self.grids[self.max_level]
        return {
            "format_version": FORMAT_VERSION,
            "created_by": f"globeview {__version__}",
            "sources": source_records,
            "params": params,
            "tile_n": self.tile_n,
            "tile_size": (1 << self.tile_n) + 1,
            "wavelet": self.wavelet,
            "max_level": self.max_level,
            "strides": list(STRIDES),
            "bounds": _union_bounds(self.sources),
            "finest_extent": fine.to_dict(),
            "pole_heights": dict(self.pole),
            "levels": levels,
        }


def _union_bounds(sources: Sequence[_Source]) -> list[float]:
    """Footprint (w, s, e, n) in degrees covering every source; w > e crosses the antimeridian.

    The shortest longitude arc holding all footprints starts at one of their west edges.
    """
    s = min(src.bounds[1] for src in sources)
    n = max(src.bounds[3] for src in sources)
    arcs = []
    for src in sources:
        w, _, e, _ = src.bounds
        width = 360.0 if src.wraps or (e - w) >= 360.0 else (e - w) % 360.0
        arcs.append((w, width))
    if any(width >= 360.0 for _, width in arcs):
        return [-180.0, s, 180.0, n]
    best: tuple[float, float] | None = None
    for start, _ in arcs:
        extent = max((w - start) % 360.0 + width for w, width in arcs)
        if best is None or extent < best[1]:
            best = (start, extent)
    assert best is not None
    if best[1] >= 360.0:
        return [-180.0, s, 180.0, n]
    west = best[0]
    east = (west + best[1] + 180.0) % 360.0 - 180.0
    if east == -180.0 and west + best[1] > west:
        east = 180.0
    return [west, s, east, n]


# ---------------------------------------------------------------------------------------------
# Public entry point


def _check_target(out: Path) -> dict | None:
    """Existing manifest of ``out`` if it is a store; None if absent/empty; StoreError if it
    is something else."""
    if not out.exists():
        return None
    if not out.is_dir():
        raise StoreError(f"{out} exists and is not a directory; choose another --out")
    manifest = out / MANIFEST_NAME
    if not manifest.exists():
        if any(out.iterdir()):
            raise StoreError(
                f"{out} exists and is not a globeview store (no {MANIFEST_NAME}); "
                "refusing to overwrite it"
            )
        return None
    try:
        data = json.loads(manifest.read_text())
        if not isinstance(data, dict) or "format_version" not in data:
            raise ValueError
        return data
    except (ValueError, OSError, UnicodeDecodeError):
        return {}  # a damaged store: rebuilt in place


def ingest(
    sources: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    tile_n: int = DEFAULT_TILE_N,
    max_level: int | None = None,
    wavelet: str = DEFAULT_WAVELET,
    crs: str | None = None,
    force: bool = False,
    progress: bool = False,
    on_progress: Callable[[int, int], None] | None = None,
) -> IngestResult:
    """Build (or refresh) the tile store ``out`` from DEM rasters.

    Args:
        sources: DEM paths; several may be combined (e.g. a global base and regional detail:
            where they overlap, the one with the finer pixels wins).
        out: store directory. Built in a temporary sibling and renamed into place when
            complete, so a failure never leaves a store that looks valid; an existing store is
            kept intact until the new one is ready.
        tile_n: tiles have (2^tile_n + 1)^2 samples.
        max_level: finest level (default: from the finest source's resolution).
        wavelet: PyWavelets name of the low-pass used for coarser levels.
        crs: CRS for every source (overrides or supplies a missing one).
        force: rebuild even if the store is up to date.
        progress: show a tqdm bar with ETA on stderr.
        on_progress: called as ``on_progress(done, total)`` after each window of work (for a
            GUI progress bar); an exception it raises aborts the build (cancel) and, like any
            failure, leaves no store behind.

    Raises:
        DemError: a source cannot be used (unreadable, no CRS, all nodata, ...).
        StoreError: bad parameters or an output location that cannot be used.
    """
    import time

    t_start = time.perf_counter()
    if not sources:
        raise StoreError("no source DEM given")
    if not (TILE_N_RANGE[0] <= tile_n <= TILE_N_RANGE[1]):
        raise StoreError(f"--tile-n must be in {TILE_N_RANGE[0]}..{TILE_N_RANGE[1]}, got {tile_n}")
    if max_level is not None and not (0 <= max_level <= MAX_LEVEL_LIMIT):
        raise StoreError(f"--max-level must be in 0..{MAX_LEVEL_LIMIT}, got {max_level}")
    lowpass_kernel(wavelet)  # WaveletError (a GlobeviewError) for a bad name
    out_path = Path(out).absolute()
    parent = out_path.parent
    existing = _check_target(out_path)
    if not parent.is_dir():
        raise StoreError(f"the folder for the store does not exist: {parent}")

    src_paths = [Path(p).absolute() for p in sources]
    for p in src_paths:
        if not p.is_file():
            raise DemError(f"DEM file not found: {p}")
    records = [{"path": str(p), "size": p.stat().st_size, "sha256": _sha256(p)} for p in src_paths]
    params = {"tile_n": tile_n, "max_level": max_level, "wavelet": wavelet, "crs": crs}
    if existing and not force and _same_inputs(existing, records, params):
        return IngestResult(out_path, True, int(existing.get("max_level", 0)), 0.0)

    with contextlib.ExitStack() as stack:
        # A fixed GDAL block cache for everything below, the sources' value scan included.
        stack.enter_context(rasterio.Env(GDAL_CACHEMAX=_GDAL_CACHE_MB * 1024 * 1024))
        srcs = []
        for p, rec in zip(src_paths, records):
            dem = stack.enter_context(open_dem(p, crs))
            info = dem.info
            res = float(min(info.res_deg))
            if not (res > 0 and math.isfinite(res)):
                raise DemError(f"{p} has no usable pixel size ({info.res_deg})")
            rec.update(crs=info.crs, bounds=list(info.bounds_lonlat), res_deg=list(info.res_deg))
            srcs.append(
                _Source(
                    p,
                    dem,
                    _natural_level(res, tile_n),
                    res,
                    info.bounds_lonlat,
                    bool(info.wraps_longitude),
                    rec,
                )
            )
        l_max = max(s.level for s in srcs) if max_level is None else max_level
        for s in srcs:
            s.level = min(s.level, l_max)
        srcs.sort(key=lambda s: s.res)  # finest first: it wins where it has data

        try:
            tmp = Path(tempfile.mkdtemp(prefix=f".{out_path.name}.building-", dir=parent))
        except OSError as exc:
            raise StoreError(f"cannot write the store in {parent}: {exc.strerror}") from None
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; a store is an ordinary folder
        try:
            with _progress(progress) as bar:
                done = [0]

                def step(n: int = 1) -> None:
                    bar.update(n)
                    if on_progress is not None:
                        done[0] += n
                        on_progress(done[0], total)

                builder = _Builder(srcs, tile_n, l_max, wavelet, tmp, step)
                total = builder.total_steps()
                bar.total = total
                bar.refresh()
                builder.build()
            manifest = builder.manifest(params, records)
            part = tmp / (MANIFEST_NAME + ".part")
            part.write_text(json.dumps(manifest, separators=(",", ":")))
            os.replace(part, tmp / MANIFEST_NAME)
            _commit(tmp, out_path)
        except OSError as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            raise StoreError(f"cannot write the store {out_path}: {exc.strerror or exc}") from None
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return IngestResult(out_path, False, l_max, time.perf_counter() - t_start)


def _same_inputs(manifest: dict, records: list[dict], params: dict) -> bool:
    try:
        if manifest.get("format_version") != FORMAT_VERSION or manifest.get("params") != params:
            return False
        old = [(s["sha256"], s["size"]) for s in manifest["sources"]]
    except (KeyError, TypeError):
        return False
    return old == [(r["sha256"], r["size"]) for r in records]


def _commit(tmp: Path, out: Path) -> None:
    """Move the finished store into place; an old store is replaced only at the very end."""
    if out.exists():
        old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
        os.replace(out, old)
        try:
            os.replace(tmp, out)
        except BaseException:
            os.replace(old, out)
            raise
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, out)


class _NoBar:
    total = 0

    def update(self, n: int = 1) -> None:
        pass

    def refresh(self) -> None:
        pass


@contextlib.contextmanager
def _progress(enabled: bool) -> Iterator:
    if not enabled:
        yield _NoBar()
        return
    from tqdm import tqdm

    bar = tqdm(total=0, unit="win", desc="ingest", dynamic_ncols=True)
    try:
        yield bar
    finally:
        bar.close()
