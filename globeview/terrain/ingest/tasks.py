"""The tasks of the ingest graph: the pole values, one level chunk, one window of tile errors.

Each task is a plain function of small, picklable arguments (a `BuildPlan`, the sources as
`SourceSpec`s, indices, and the small results of the tasks it depends on), so the same
tasks run in threads, in processes, or on the workers of a ``dask.distributed`` cluster.
Bulk data passes through files in the building folder, never through the graph: a chunk
task reads the finer level's chunk files it needs (wavelet halo included) and writes its own
chunk file; it returns only per-tile statistics (a few KB). The store folder must therefore
be on a filesystem every worker shares.

Memory per task is bounded by the chunk size (`layout.CHUNK_TARGET_NODES` nodes a side:
a window, its halo and temporaries, tens of MB) and GDAL's block cache (`GDAL_CACHE_MB`).

The numerics are those of the serial ingest they replace (same reads, same order of
operations), so the store is bit for bit the same whatever the scheduler: see
`globeview.terrain.ingest.driver` for the pipeline and `tile_errors` for the error bounds.
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

import numpy as np
import rasterio
from rasterio.windows import Window

from globeview.terrain.dem.reader import Dem
from globeview.terrain.dem.vdatum import undulation_on_grid
from globeview.terrain.ingest.stored_ranges import stored_part_facts
from globeview.terrain.ingest.tile_errors import (
    ErrorWindow,
    data_blocks,
    error_window,
    pruned_error_tiles,
    tile_stats,
)
from globeview.terrain.ingest.wavelet import approximate_window
from globeview.terrain.levels import LevelGrid, read_level_nodes
from globeview.terrain.store.layout import (
    EXTRA_COL,
    EXTRA_ROW,
    chunk_file_name,
    chunk_grid_shape,
    chunk_window,
)
from globeview.terrain.store.level_chunks import write_chunk

__all__ = [
    "FAULT_ENV",
    "GDAL_CACHE_MB",
    "STRIDES",
    "BuildPlan",
    "ChunkResult",
    "SourceSpec",
    "chunk_task",
    "close_thread_sources",
    "error_task",
    "fault_point",
    "fill_reads_source",
    "pole_task",
]

STRIDES = (2, 4, 8, 16, 32, 64)
# GDAL block cache of a build (per process). rasterio's default (5% of RAM) would make the
# peak RSS depend on the machine; a fixed cache keeps the bound.
GDAL_CACHE_MB = 96

# Fault injection for tests (works without root): GLOBEVIEW_INGEST_FAULT="KIND@N" makes the
# N-th window write of a build (or the point named N, see `fault_point`) fail: ENOSPC,
# EROFS or any errno name (OSError), INTERRUPT (KeyboardInterrupt) or KILL (SIGKILL to the
# process running it, as `kill -9` at a known point). Window writes are numbered in the
# order of the serial build (levels finest first, chunks row-major), whatever the scheduler.
FAULT_ENV = "GLOBEVIEW_INGEST_FAULT"


def fault_point(point: int | str) -> None:
    """Fail here if GLOBEVIEW_INGEST_FAULT names this point (a window-write number, or
    "manifest" before the manifest is written, "commit" between a commit's two renames)."""
    spec = os.environ.get(FAULT_ENV)
    if not spec:
        return
    kind, _, at = spec.partition("@")
    if at != str(point):
        return
    kind = kind.upper()
    if kind.startswith("E") and isinstance(getattr(errno, kind, None), int):
        code = getattr(errno, kind)
        raise OSError(code, os.strerror(code))
    if kind == "INTERRUPT":
        raise KeyboardInterrupt
    if kind == "KILL":
        os.kill(os.getpid(), signal.SIGKILL)


# ---------------------------------------------------------------------------------------------
# What tasks are given


@dataclass(frozen=True)
class BuildPlan:
    """Everything a task needs to know about the build (small, picklable).

    folder: the building folder (chunk files are read and written there); grids: level ->
    raster geometry (the whole globe: store format 7's chunks are fixed by the quadtree,
    `store.layout`); k: tiles per chunk side (chunk_nodes = k * 2^tile_n); halo: the
    wavelet's halo in fine nodes; gdal_threads: GDAL's compression threads per chunk write.
    """

    folder: str
    tile_n: int
    max_level: int
    wavelet: str
    halo: int
    grids: tuple[LevelGrid, ...]
    k: int
    gdal_threads: str = "1"
    #: Keep chunk files open per worker thread (local schedulers only: on a cluster's shared
    #: filesystem an open file of a removed folder can keep the folder from going away).
    keep_open: bool = True

    @property
    def chunk_nodes(self) -> int:
        return self.k << self.tile_n

    def window(self, lv: int, cy: int, cx: int) -> tuple[int, int, int, int]:
        """Tile block (by, bx, kty, ktx) of chunk (cy, cx) of level lv."""
        g = self.grids[lv]
        by, bx = cy * self.k, cx * self.k
        return by, bx, min(self.k, g.ny - by), min(self.k, g.nx - bx)

    def chunk_shape(self, lv: int) -> tuple[int, int]:
        return chunk_grid_shape(lv, self.tile_n)


# Per-thread open Dems, by `SourceSpec.token`: GDAL datasets are not thread-safe, so each
# worker thread reads through its own handle (opened once per build, no value scan).
_local = threading.local()
_MAX_OPEN_DEMS = 32


@dataclass(frozen=True)
class SourceSpec:
    """A source as a task sees it: its `Dem`'s pickled state (reopened per thread without
    the value scan), its natural level, footprint (degrees), vertical datum, pixel size
    (degrees, the larger axis) and the geoid grid file its datum converts with (None: the
    shipped EGM96 grid, or none for ellipsoidal heights; a cluster's workers must see it)."""

    token: str  # unique per build and source
    dem_state: dict
    path: str
    level: int
    bounds: tuple[float, float, float, float]
    wraps: bool
    datum: str
    res: float
    grid: str | None = None

    def dem(self) -> Dem:
        """This thread's open `Dem` of the source."""
        dems: OrderedDict[str, Dem] | None = getattr(_local, "dems", None)
        if dems is None:
            dems = _local.dems = OrderedDict()
        dem = dems.get(self.token)
        if dem is None:
            dem = Dem.__new__(Dem)
            dem.__setstate__(self.dem_state)
            dems[self.token] = dem
            while len(dems) > _MAX_OPEN_DEMS:
                dems.popitem(last=False)[1].close()
        dems.move_to_end(self.token)
        return dem


def close_thread_sources() -> None:
    """Close the source handles this thread opened (a driver thread that ran a task itself:
    worker threads end with their pool)."""
    dems = getattr(_local, "dems", None)
    while dems:
        dems.popitem()[1].close()


@dataclass(frozen=True)
class ChunkResult:
    """What a chunk task returns: the per-tile statistics of its tile block (hmin, hmax
    (kty, ktx) metres, NaN without data; stride_delta (kty, ktx, len(STRIDES)) metres),
    the chunk file's sha256 (None: all NaN, no file) and size in bytes and, for chunk column
    0, its closed window's first node column (the east edge of the row's last chunk)."""

    level: int
    cy: int
    cx: int
    hmin: np.ndarray
    hmax: np.ndarray
    stride_delta: np.ndarray
    sha256: str | None
    first_col: np.ndarray | None = None
    bytes: int = 0
    flags: int = 0  # `layout.EXTRA_ROW` | `EXTRA_COL`: the file holds its closing row/column
    #: (hmin, hmax, packed edge facts) over the nodes the chunk's file stores
    #: (`stored_ranges.stored_part_facts`): the tiles' ranges as stored, once folded with
    #: the neighbours' (`stored_ranges.tile_ranges`); None: hmin and hmax are those.
    stored: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


# ---------------------------------------------------------------------------------------------
# Reading chunk files


# Per-thread open chunk files by sha256: a chunk is read by several tasks (the coarser chunk
# over it, the error windows of every finer level under it, its neighbours' halos), and a
# dataset kept open keeps its decoded blocks in GDAL's cache (bounded, GDAL_CACHE_MB) instead
# of inflating them again per task. Keyed by content, so a handle can never serve another
# build's file of the same name.
_MAX_OPEN_CHUNKS = 48


def _open_chunk(path: Path, sha256: str) -> rasterio.DatasetReader:
    handles: OrderedDict[str, rasterio.DatasetReader] | None = getattr(_local, "chunks", None)
    if handles is None:
        handles = _local.chunks = OrderedDict()
    ds = handles.get(sha256)
    if ds is None or ds.closed:
        ds = handles[sha256] = rasterio.open(path)
        while len(handles) > _MAX_OPEN_CHUNKS:
            handles.popitem(last=False)[1].close()
    handles.move_to_end(sha256)
    return ds


class ChunkReader:
    """A level raster read from its chunk files in the building folder (what
    `read_level_nodes` needs of a dataset: ``read(1, window=...)``). ``present``: the chunks
    that have a file, with their sha256 and flags (the others are all NaN)."""

    def __init__(
        self, plan: BuildPlan, lv: int, present: dict[tuple[int, int], tuple[str, int]]
    ) -> None:
        self.plan = plan
        self.grid = plan.grids[lv]
        self.present = present

    def read(self, band: int, window: Window, out: np.ndarray | None = None) -> np.ndarray:
        """The window's nodes (float32, NaN where no chunk has data), into ``out`` (of the
        window's shape, may be strided) when given."""
        r_a, c_a = int(window.row_off), int(window.col_off)
        h, w = int(window.height), int(window.width)
        parts = self._parts(r_a, c_a, h, w)
        # NaN first only where no read of its own part writes every node (a part no file
        # holds, or one read over another): a read writes each node of its ``out``.
        covered = sum((b[1] - b[0]) * (b[3] - b[2]) for *_, b, shared in parts if not shared)
        if out is None:
            out = np.empty((h, w), dtype=np.float32)
        if covered < h * w:
            out.fill(np.nan)
        for path, sha, win, (ra, rb, ca, cb), shared in parts:
            dst = out[ra - r_a : rb - r_a, ca - c_a : cb - c_a]
            got = None if shared else dst
            if self.plan.keep_open:
                got = _open_chunk(path, sha).read(band, window=win, out=got)
            else:
                with rasterio.open(path) as ds:
                    got = ds.read(band, window=win, out=got)
            if shared:
                # A node both chunks hold (an owner's first row and its neighbour's
                # closing row): the owner's (read last: row-major) wins where it has a
                # value.
                np.copyto(dst, got, where=np.isnan(dst) | np.isfinite(got))
        return out

    def _parts(
        self, r_a: int, c_a: int, h: int, w: int
    ) -> list[tuple[Path, str, Window, tuple[int, int, int, int], bool]]:
        """The reads of a window (rows r_a.., columns c_a.., h x w nodes of the level), in
        row-major chunk order: (file, sha256, window in the file, level rows ra:rb and
        columns ca:cb it gives, whether it overlaps a part before it)."""
        c = self.plan.chunk_nodes
        rows, cols = self.plan.chunk_shape(self.grid.level)
        parts: list[tuple[Path, str, Window, tuple[int, int, int, int], bool]] = []
        filled: list[tuple[int, int, int, int]] = []
        # From the chunk above / west too: it may store its closing row / column.
        for cy in range(max(0, (r_a - 1) // c), min((r_a + h - 1) // c, rows - 1) + 1):
            for cx in range(max(0, (c_a - 1) // c), min((c_a + w - 1) // c, cols - 1) + 1):
                hit = self.present.get((cy, cx))
                if hit is None:
                    continue
                sha, flags = hit
                r0, c0, ch, cw = chunk_window(
                    self.grid.level,
                    self.plan.tile_n,
                    cy,
                    cx,
                    bool(flags & EXTRA_ROW),
                    bool(flags & EXTRA_COL),
                )
                ra, rb = max(r_a, r0), min(r_a + h, r0 + ch)
                ca, cb = max(c_a, c0), min(c_a + w, c0 + cw)
                if ra >= rb or ca >= cb:
                    continue
                path = Path(self.plan.folder) / chunk_file_name(self.grid.level, cy, cx, sha)
                win = Window(ca - c0, ra - r0, cb - ca, rb - ra)
                shared = any(ra < b and a < rb and ca < d and c_ < cb for a, b, c_, d in filled)
                filled.append((ra, rb, ca, cb))
                parts.append((path, sha, win, (ra, rb, ca, cb), shared))
        return parts

    def __enter__(self) -> ChunkReader:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        pass


def _present(results: Sequence[ChunkResult], lv: int) -> dict[tuple[int, int], tuple[str, int]]:
    return {
        (r.cy, r.cx): (r.sha256, r.flags) for r in results if r.level == lv and r.sha256 is not None
    }


# ---------------------------------------------------------------------------------------------
# Sources


def _window_undulation(
    datum: str,
    grid: str | None,
    west: float,
    north: float,
    d: float,
    w: int,
    h: int,
    box: tuple[slice, slice] = (slice(None), slice(None)),
) -> np.ndarray:
    """N (m, float32) of geoid ``datum`` on a window's nodes: lon west + j*d, lat
    north - i*d (degrees), or on the nodes ``box`` (rows, columns) of it (the same
    coordinates, so the same values). EGM96 from the shipped grid; EGM2008 from ``grid``, of
    which only the window's part is read (`vdatum.undulation_on_grid`)."""
    lons = (west + d * np.arange(w))[box[1]]
    lats = (north - d * np.arange(h))[box[0]]
    return undulation_on_grid(datum, grid, lons, lats).astype(np.float32)


def _finite_box(*parts: np.ndarray) -> tuple[slice, slice] | None:
    """The smallest box (rows, columns) holding every finite node of the arrays (one
    shape), None if none is."""
    finite = np.isfinite(parts[0])
    for p in parts[1:]:
        finite |= np.isfinite(p)
    rows = np.flatnonzero(finite.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(finite.any(axis=0))
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)


def _lon_overlaps(a0: float, a1: float, b: tuple[float, float, float, float], wraps: bool) -> bool:
    """Whether the longitude interval [a0, a1] (a1 >= a0, may exceed 180) meets a footprint."""
    if wraps:
        return True
    w, _, e, _ = b
    width = (e - w) % 360.0 or (360.0 if e != w else 0.0)
    return any(a0 <= w + k + width and w + k <= a1 for k in (-360.0, 0.0, 360.0))


def fill_reads_source(
    grid: LevelGrid,
    gr0: int,
    gc0: int,
    h: int,
    w: int,
    bounds: tuple[float, float, float, float],
    wraps: bool,
    res: float,
) -> bool:
    """Whether a window of a level (global node indices, h x w nodes) reads a source of
    this footprint (degrees) and pixel size ``res`` (degrees, the larger axis): it comes
    within a node spacing and a pixel of the window. A source's nodes reach past its
    footprint's bounds by half a pixel (GDAL's footprint of a pixel-is-point grid) and one
    node (the ring its data edge is continued over, `Dem.read_grid_parts`)."""
    d = grid.d
    reach = d + res
    west = -180.0 + gc0 * d
    north = 90.0 - gr0 * d
    south = north - (h - 1) * d
    _, bs, _, bn = bounds
    if south > bn + reach or north < bs - reach:
        return False
    return _lon_overlaps(west - reach, west + (w - 1) * d + reach, bounds, wraps)


def fill_from_sources(
    sources: Sequence[SourceSpec],
    out: np.ndarray,
    grid: LevelGrid,
    gr0: int,
    gc0: int,
    max_source_level: int,
) -> None:
    """Fill NaN nodes of ``out`` (global node window at gr0, gc0) from the sources with
    L_s <= max_source_level, finest first (``sources`` are sorted so), in place.

    The sources of one level fill with their data first, then with the rings their data
    edges are continued over (`Dem.read_grid_parts`), then the next coarser level's: so a
    source's data wins over another's ring (tiles of a mosaic), and a finer source's ring
    over a coarser one's data (the finer surface keeps all four corners of every cell that
    meets its data)."""
    h, w = out.shape
    d = grid.d
    west = -180.0 + gc0 * d
    north = 90.0 - gr0 * d
    west_n = (west + 180.0) % 360.0 - 180.0
    rings: list[np.ndarray] = []  # the edge rings of the level being filled
    level = None
    for s in sources:
        # The cheap footprint test first: with thousands of sources (SRTM tiles) a window
        # meets a handful, and the NaN scan of the window (~0.2 ms) is then paid only for
        # those, not for every source (C's measurement: 257 vs 0.5 core-hours for a planet).
        if s.level > max_source_level or not fill_reads_source(
            grid, gr0, gc0, h, w, s.bounds, s.wraps, s.res
        ):
            continue
        if s.level != level:
            _fill_nan(out, rings)
            rings, level = [], s.level
        missing = np.isnan(out)
        if not missing.any():
            return
        parts = s.dem().read_grid_parts(west_n, north, d, d, w, h)
        data, edge = parts.data, parts.edge
        if s.datum != "ellipsoid":  # each source with its own datum's geoid
            # N only where the source gave a value (NaN stays NaN elsewhere): a window at a
            # DEM's edge, or one of the tiles of a mosaic, holds its data in a part. (The
            # shipped EGM96 grid only: an external grid is read by window, and N's last bits
            # follow the window read, so those keep the whole window.)
            whole = (slice(0, h), slice(0, w))
            box = _finite_box(data, edge) if s.grid is None else whole
            if box is not None:
                n = _window_undulation(s.datum, s.grid, west, north, d, w, h, box)
                data[box] += n
                edge[box] += n
        np.copyto(out, data, where=missing)  # ``out`` unchanged since ``missing``
        rings.append(edge)
    _fill_nan(out, rings)


def _fill_nan(out: np.ndarray, values: Sequence[np.ndarray]) -> None:
    """Fill the NaN nodes of ``out`` in place from ``values``, the first with a value winning."""
    for v in values:
        np.copyto(out, v, where=np.isnan(out))


# ---------------------------------------------------------------------------------------------
# Tasks


def pole_task(plan: BuildPlan, sources: Sequence[SourceSpec]) -> dict[str, float | None]:
    """Mean of the finest level's pole rows (one point each on the globe): {"north": h or
    None, "south": h or None}, metres."""
    g = plan.grids[plan.max_level]
    pole: dict[str, float | None] = {"north": None, "south": None}
    with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB * 1024 * 1024):
        for name, grow in (("north", 0), ("south", g.nrows * g.tile_nodes)):
            if g.raster_rows(np.array([grow]))[0] < 0:
                continue
            # The row goes all the way round (format 7's levels are global): read it only
            # when a source reaches it.
            if not any(fill_reads_source(g, grow, 0, 1, 2, s.bounds, True, s.res) for s in sources):
                continue
            # One node row across the extent: small (a few MB even for a global level 12).
            row = np.full((1, g.width), np.nan, dtype=np.float32)
            fill_from_sources(sources, row, g, grow, g.gc0, plan.max_level)
            if np.isfinite(row).any():
                pole[name] = float(np.nanmean(row.astype(np.float64)))
    return pole


def _window_values(
    plan: BuildPlan,
    sources: Sequence[SourceSpec],
    grid: LevelGrid,
    fine_ds: ChunkReader | None,
    gr0: int,
    gc0: int,
    h: int,
    w: int,
    pole: dict[str, float | None],
) -> np.ndarray:
    """Closed window of nodes of a level (global node indices), float32."""
    if fine_ds is None:
        out = np.full((h, w), np.nan, dtype=np.float32)
    else:
        fine = plan.grids[grid.level + 1]
        hl = plan.halo
        padded = read_level_nodes(
            fine_ds,  # a ChunkReader reads like a dataset
            fine,
            2 * gr0 - hl,
            2 * gc0 - hl,
            2 * h - 1 + 2 * hl,
            2 * w - 1 + 2 * hl,
            mirror=hl,
        )
        out = approximate_window(padded, hl, plan.wavelet)
        # Coarse nodes whose own fine node is outside the finer raster carry no data.
        rows_out = fine.raster_rows(2 * (gr0 + np.arange(h))) < 0
        cols_out = fine.raster_cols(2 * (gc0 + np.arange(w))) < 0
        out[rows_out, :] = np.nan
        out[:, cols_out] = np.nan
    fill_from_sources(sources, out, grid, gr0, gc0, grid.level)
    # Poles: one value per pole (finite nodes only: a partial pole row stays partial).
    if pole.get("north") is not None and gr0 == 0:
        out[0, np.isfinite(out[0])] = pole["north"]
    south_row = grid.nrows * grid.tile_nodes - gr0
    if pole.get("south") is not None and 0 <= south_row < h:
        out[south_row, np.isfinite(out[south_row])] = pole["south"]
    return out


def chunk_task(
    plan: BuildPlan,
    sources: Sequence[SourceSpec],
    lv: int,
    cy: int,
    cx: int,
    write_no: int,
    pole: dict[str, float | None] | None,
    fine: Sequence[ChunkResult],
    first: ChunkResult | None,
    extra: int = 0,
) -> ChunkResult:
    """Compute, write and summarise chunk (cy, cx) of level lv.

    ``pole``: the pole task's result where the window holds a pole row (else None);
    ``fine``: the results of the level-(lv+1) chunks the window's wavelet reads (their
    files are in the building folder); ``first``: for the last chunk of a row of a level
    that goes all the way round, chunk (cy, 0)'s result (its first column becomes this
    chunk's east edge: lon 180 is lon -180). ``write_no``: the window's number in the serial
    order (fault injection). ``extra``: `layout.EXTRA_ROW` / `EXTRA_COL` when the chunk
    below / east of it has no data, so this one stores its closing row / column.
    """
    grid = plan.grids[lv]
    s_n = grid.tile_nodes
    by, bx, kty, ktx = plan.window(lv, cy, cx)
    h, w = kty * s_n + 1, ktx * s_n + 1
    with contextlib.ExitStack() as stack:
        stack.enter_context(rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB * 1024 * 1024))
        fine_ds = None
        if lv < plan.max_level:
            fine_ds = stack.enter_context(ChunkReader(plan, lv + 1, _present(fine, lv + 1)))
        arr = _window_values(
            plan, sources, grid, fine_ds, grid.gr0 + by * s_n, grid.gc0 + bx * s_n, h, w, pole or {}
        )
    first_col = None
    if grid.global_lon:
        # The east edge (lon 180) is the west edge (lon -180): make it identical.
        if bx == 0:
            first_col = arr[:, 0].copy()
        if bx + ktx == grid.nx:
            edge = first_col if bx == 0 else (first.first_col if first is not None else None)
            # No first chunk in the row (no data there): its column reads as NaN.
            arr[:, -1] = np.nan if edge is None else edge
    # Stride deltas: delta_s = max |S_s - S_1| over the tile, where S_s is the bilinear
    # surface on every s-th node and S_1 the tile's own (exact at the nodes; a running max
    # over the strides keeps the bounds monotone): see tile_errors.stride_deltas. On the
    # tiles that hold data only (tile_errors.tile_stats).
    hmin, hmax, delta = tile_stats(arr, s_n, STRIDES)
    # The chunk is the window's half-open part; the last row of chunks also holds the south
    # pole row (column W, one turn east, is column 0: never stored, `layout.chunk_window`).
    _, _, hh, ww = chunk_window(
        lv, plan.tile_n, cy, cx, bool(extra & EXTRA_ROW), bool(extra & EXTRA_COL)
    )
    fault_point(write_no)
    with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB * 1024 * 1024):
        written = write_chunk(
            Path(plan.folder), lv, plan.tile_n, cy, cx, arr[:hh, :ww], plan.gdal_threads, extra
        )
    sha, size = written if written is not None else (None, 0)
    keep_first = first_col if grid.global_lon and bx == 0 and bx + ktx < grid.nx else None
    stored = stored_part_facts(arr, hh, ww, s_n)  # all NaN without a file
    return ChunkResult(lv, cy, cx, hmin, hmax, delta, sha, keep_first, size, extra, stored)


def _tile_table(results: Sequence[ChunkResult], plan: BuildPlan, lv: int) -> dict:
    """hmin blocks of a level's chunk results by chunk (cy, cx)."""
    return {(r.cy, r.cx): r.hmin for r in results if r.level == lv}


def error_task(
    plan: BuildPlan, lf: int, cy: int, cx: int, deps: Sequence[ChunkResult]
) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """Exact tile errors of every level coarser than lf against level lf's nodes in window
    (cy, cx) of level lf (where lf is the finest data there): a list of (level, iy, ix, err)
    (tile slots of the level's extent and their maxima, metres) for the driver to fold with
    fmax. ``deps``: the results of the chunks read (level lf's window and its right/lower
    neighbours, the level-(lf+1) chunks that say where finer data exists, and the coarser
    levels' chunks under the window).
    """
    gf = plan.grids[lf]
    s_n = gf.tile_nodes
    by, bx, kty, ktx = plan.window(lf, cy, cx)
    h, w = kty * s_n + 1, ktx * s_n + 1
    gr0, gc0 = gf.gr0 + by * s_n, gf.gc0 + bx * s_n
    owned = None
    block = s_n
    if lf < plan.max_level:
        # Blocks (quadrants of level-lf tiles) whose level-(lf+1) tile has data are judged
        # against that finer level (in its own pass); here only the rest.
        block = s_n // 2
        ty = gr0 // block + np.arange((h - 1) // block)
        tx = gc0 // block + np.arange((w - 1) // block)
        has = _has_data(plan, lf + 1, ty[:, None], tx[None, :], deps)
        if has.all():
            return []
        owned = ~has
    out: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
    with contextlib.ExitStack() as stack:
        stack.enter_context(rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB * 1024 * 1024))
        reader = stack.enter_context(ChunkReader(plan, lf, _present(deps, lf)))
        fine = reader.read(1, window=Window(bx * s_n, by * s_n, w, h))
        if not np.isfinite(fine).any():
            return []
        # The passes run on the box of blocks that hold data and are judged here: the
        # others would give their tiles NaN, which the whole window's result keeps.
        box = _error_box(fine, block, owned)
        win = None
        if box is not None:
            br, bc = box
            fine = fine[
                br.start * block : br.stop * block + 1, bc.start * block : bc.stop * block + 1
            ]
            owned = None if owned is None else owned[br, bc]
            sr0, sc0 = gr0 + br.start * block, gc0 + bc.start * block
            # Prepared once for every coarser level; the coarse passes skip the blocks that
            # cannot hold their tile's maximum (branch and bound: the same floats).
            win = error_window(fine)
        for lv in range(lf):
            g = plan.grids[lv]
            span = (1 << (lf - lv)) * s_n
            rv = np.arange(gr0 // span, (gr0 + h - 2) // span + 1)
            cv = np.arange(gc0 // span, (gc0 + w - 2) // span + 1)
            red = np.full((rv.size, cv.size), np.nan)
            if win is not None:
                ry, cx_, part = _box_errors(plan, lf, lv, deps, win, sr0, sc0, block, owned)
                red[np.ix_(ry - rv[0], cx_ - cv[0])] = part
            iy, ix, inside = g.tile_slots(rv[:, None], cv[None, :])
            iy, ix, inside = np.broadcast_arrays(iy, ix, inside)
            out.append((lv, iy[inside], ix[inside], red[inside]))
    return out


def _box_errors(
    plan: BuildPlan,
    lf: int,
    lv: int,
    deps: Sequence[ChunkResult],
    win: ErrorWindow,
    gr0: int,
    gc0: int,
    block: int,
    owned: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-tile errors of level lv against the level-lf nodes of ``win`` (a box of an error
    window, its first node at global node (gr0, gc0) of level lf): the tile rows, columns
    and maxima of `pruned_error_tiles`, reading the level-lv nodes over the box."""
    g = plan.grids[lv]
    f = 1 << (lf - lv)
    h, w = win.fine.shape
    r0, c0 = gr0 // f, gc0 // f
    r1, c1 = -(-(gr0 + h - 1) // f), -(-(gc0 + w - 1) // f)
    with ChunkReader(plan, lv, _present(deps, lv)) as ds:
        coarse = read_level_nodes(ds, g, r0, c0, r1 - r0 + 1, c1 - c0 + 1)
    s_n = plan.grids[lf].tile_nodes
    return pruned_error_tiles(
        coarse, win, f, gr0 - r0 * f, gc0 - c0 * f, gr0, gc0, f * s_n, block, owned
    )


def _error_box(
    fine: np.ndarray, block: int, owned: np.ndarray | None
) -> tuple[slice, slice] | None:
    """The box of blocks (of ``block`` cells) of an error window that hold a finite node
    and are owned (judged in this window): slices of block indices, None when none."""
    box = data_blocks(fine, block)
    if box is None or owned is None:
        return box
    br, bc = box
    rows = np.flatnonzero(owned[br, bc].any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(owned[br, bc].any(axis=0))
    return (
        slice(br.start + int(rows[0]), br.start + int(rows[-1]) + 1),
        slice(bc.start + int(cols[0]), bc.start + int(cols[-1]) + 1),
    )


def _has_data(
    plan: BuildPlan, lv: int, ty: np.ndarray, tx: np.ndarray, deps: Sequence[ChunkResult]
) -> np.ndarray:
    """Whether tiles (ty, tx) of level lv are in its extent and hold data, from the hmin
    blocks of the chunk results among ``deps`` (every chunk holding one of these tiles)."""
    g = plan.grids[lv]
    iy, ix, inside = g.tile_slots(ty, tx)
    iy, ix, inside = np.broadcast_arrays(iy, ix, inside)
    table = _tile_table(deps, plan, lv)
    out = np.zeros(iy.shape, dtype=bool)
    k = plan.k
    for (ccy, ccx), hmin in table.items():
        sel = inside & (iy // k == ccy) & (ix // k == ccx)
        if sel.any():
            out[sel] = np.isfinite(hmin[iy[sel] - ccy * k, ix[sel] - ccx * k])
    return out
