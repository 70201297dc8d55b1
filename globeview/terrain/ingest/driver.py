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
3. Levels are written finest first, one chunk (a window of 1024 nodes a side, one chunk file
   of the store, see `store.schema`) per task of a Dask graph (`schedule`,
   `tasks`). A chunk of level L is the wavelet approximation of level L+1 (read back
   from the chunk files just written, with ``kernel_halo`` nodes of halo); where that is NaN
   (outside level L+1 or no data there) the sources with L_s <= L are read on the level grid
   with `Dem.read_grid_parts`, the finest source winning where it has data. The nodes just
   past a source's data edge that the grid cells meeting its data need as corners get its
   surface continued (`dem.edge`; issue #29), unless a source of its level has data there.
   The finest level is read from the sources only. Pole rows are set to one value (see
   below). Per-tile hmin, hmax and stride errors are computed from each window before it is
   written.
4. Tile errors: for every tile, max |tile bilinear surface - finest data| over the tile's
   footprint, evaluated exactly at the finest nodes (see `tile_errors`). The finest data of a
   place is the finest level that has data there; one task per window of each reference
   level returns the per-tile maxima of every coarser level, folded with fmax.
5. The level VRTs and the manifest (a `schema.StoreManifest`) are written last, then the
   temporary directory is renamed into place.

The graph runs on dask's local threaded scheduler (``workers`` threads), a process pool, or
an existing dask.distributed cluster (``scheduler="tcp://HOST:PORT"``); the store is the same
bit for bit whatever runs it.

Heights: stores hold ellipsoidal heights h (above WGS84). A source on a geoid (its vertical
datum from its CRS, a per-source default or ``vdatum``, see `Dem`: EGM96 for SRTM .hgt,
EGM2008 for Copernicus DEM tiles) is converted h = H + N with its own geoid as it is read on a
level grid, after nodata masking and the impossible-height limits (which apply to the
source's own heights): N is sampled once per window and geoid on the window's regular lon/lat
nodes (`Geoid.undulation_grid`). EGM96's grid is shipped; EGM2008's is the user's
(``geoid_grids``, `$GLOBEVIEW_GEOID_GRIDS` or PROJ's data folders: `vdatum.find_geoid_grid`),
of which a task reads only its window's part. A build whose sources need a grid that is not
on the machine is one line before anything is written. So one build may mix SRTM (EGM96),
Copernicus (EGM2008) and ellipsoidal sources. The manifest records each source's datum and the
grid (file name and sha256) it was converted with; another grid makes the store out of date.

Poles: the pole row of a level (lat = +-90) is a single point on the globe. When a level's
pole row holds data, its finite nodes are all set to the mean of the finest level's pole row
(computed once), at every level. (The odd-mirror wavelet approximation maps a constant pole
row to the same constant, so this is consistent with the pyramid.)
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import shutil
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import rasterio

from globeview.errors import DemError, StoreError
from globeview.terrain.dem.reader import COPERNICUS_NAME, Dem, check_dem_path, open_dem
from globeview.terrain.dem.vdatum import (
    EXTERNAL_GRIDS,
    GEOID_FILE,
    egm96_sha256,
    find_geoid_grid,
    grid_sha256,
    missing_grid_line,
    parse_vdatum,
)
from globeview.terrain.ingest import cost
from globeview.terrain.ingest.coverage import with_coverage
from globeview.terrain.ingest.footprints import (
    DATUMS,
    FootprintTable,
    check_name_footprint,
    footprints_from_names,
    is_tile_name,
    table_from_bounds,
)
from globeview.terrain.ingest.plan import ChunkPlan, chunks_at_least, fill_order, plan_chunks
from globeview.terrain.ingest.safety import (
    build_folder,
    check_target,
    clean_stale_builds,
    clear_folder,
    commit,
    gdal_quiet,
    tty_stderr,
    write_error,
)
from globeview.terrain.ingest.schedule import (
    SchedulerChoice,
    build_graph,
    parse_scheduler,
    probe_scheduler,
    run_graph,
)
from globeview.terrain.ingest.sources import expand_sources
from globeview.terrain.ingest.stored_ranges import tile_ranges
from globeview.terrain.ingest.tasks import (
    FAULT_ENV,
    GDAL_CACHE_MB,
    STRIDES,
    BuildPlan,
    ChunkResult,
    SourceSpec,
    close_thread_sources,
    pole_task,
)
from globeview.terrain.ingest.tasks import fault_point as _fault_point
from globeview.terrain.ingest.update import Update, plan_update, write_facts
from globeview.terrain.ingest.wavelet import DEFAULT_WAVELET, kernel_halo, lowpass_kernel
from globeview.terrain.levels import LevelGrid
from globeview.terrain.quadtree import (
    DEFAULT_TILE_N,
    level_shape,
    tile_size_deg,
    tiles_covering,
)
from globeview.terrain.store.backend import RASTER_ERRORS
from globeview.terrain.store.generations import commit_generation
from globeview.terrain.store.identify import MANIFEST_NAME, StoreIdentity
from globeview.terrain.store.layout import (
    chunk_code,
    chunk_file_name,
    chunk_grid_shape,
    chunk_levels_c0,
    chunk_nodes,
    chunk_tiles,
    shard_roots,
)
from globeview.terrain.store.level_chunks import file_sha256, write_level_vrt
from globeview.terrain.store.schema import (
    FORMAT_VERSION,
    MAX_LEVEL_LIMIT,
    TILE_N_RANGE,
    Extent,
    FileRef,
    IngestParams,
    LevelRecord,
    PoleHeights,
    ShardsRecord,
    SourceRecord,
    StoreHeader,
    StoreManifest,
    level_file_name,
)
from globeview.terrain.store.shards import ChunkRecord, write_tree
from globeview.terrain.store.shards import f16_up as shards_f16_up
from globeview.terrain.store.tile_store import TileStore

__all__ = [
    "FAULT_ENV",
    "FORMAT_VERSION",
    "MANIFEST_NAME",
    "STRIDES",
    "IngestResult",
    "ingest",
]

# GDAL block cache during the build (see tasks.GDAL_CACHE_MB).
_GDAL_CACHE_MB = GDAL_CACHE_MB


@dataclass
class IngestResult:
    """What `ingest` did: the store path and whether it was already up to date."""

    path: Path
    up_to_date: bool
    max_level: int = 0
    seconds: float = 0.0
    #: Source samples read as nodata because they were +-inf or impossible heights (outside
    #: MIN_HEIGHT_M..MAX_HEIGHT_M of `globeview.terrain.dem.reader`), and undeclared fill samples
    #: (-9999 plateaus...), summed over the sources (from each source's value scan).
    masked_samples: int = 0
    fill_samples: int = 0
    #: Chunks (level windows) computed by this build, of how many: fewer than all when an
    #: incremental update kept the chunks that the changed sources do not touch.
    chunks_rebuilt: int = 0
    chunks_total: int = 0
    #: Sources left out because they hold the same bytes as one given earlier (a tile
    #: downloaded twice into two folders): (left out, the one used), in input order.
    duplicates: list[tuple[Path, Path]] = field(default_factory=list)


@dataclass
class _Source:
    path: Path
    dem: Dem
    level: int  # its natural finest level, clamped to L_max
    res: float  # finer pixel size, degrees
    bounds: tuple[float, float, float, float]
    wraps: bool
    record: SourceRecord
    datum: str = "ellipsoid"  # a geoid ("egm96", "egm2008"): converted h = H + N when read
    grid: Path | None = None  # the geoid grid file of an external datum (EGM2008)


@dataclass
class _ChunkStats:
    """Per-tile facts of one chunk's tiles, arrays (kty, ktx) (metres, float64); NaN where a
    tile has no data."""

    hmin: np.ndarray
    hmax: np.ndarray
    error: np.ndarray
    stride_delta: np.ndarray  # (kty, ktx, len(STRIDES)): max |S_s - S_1| per tile, see below
    sha256: str | None = None
    bytes: int = 0
    flags: int = 0  # `layout.EXTRA_ROW` | `EXTRA_COL`


# What a failed build raises (disk full, read-only, a GDAL write error): one StoreError line.
_BUILD_ERRORS: tuple[type[BaseException], ...] = (OSError, *RASTER_ERRORS)

# ---------------------------------------------------------------------------------------------
# Small helpers


def _no_tick(n: int = 1) -> None:
    """The builder's progress callback before the real one is set."""


def _heights_note(datum: str, grid: Path | None = None) -> str:
    """The manifest's account of what ingest did with a source's heights (for people; also
    how a rebuild tells that another geoid grid is given: `_same_grids`)."""
    if datum == "egm96":
        return f"converted to ellipsoidal heights with EGM96 ({GEOID_FILE} sha256 {egm96_sha256()})"
    if grid is not None:
        return (
            f"converted to ellipsoidal heights with {datum.upper()} ({grid.name} sha256 "
            f"{grid_sha256(grid)})"
        )
    return "ellipsoidal heights, stored unchanged"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _natural_level(res_deg: float, tile_n: int, extent_deg: float | None = None) -> int:
    """Level whose node spacing 180/2^L/2^n is closest to res_deg (round of log2).

    ``extent_deg`` (the footprint's smaller side, degrees) raises the level for tiny sources:
    a level's cells are drawn only where all four corner nodes hold data, so a footprint
    narrower than two node spacings (a 2 x 2 raster of 0.5 deg pixels holds one level-2
    node) would ingest fine and draw nothing. The spacing d = 180/2^L/2^n must satisfy
    d <= extent/2, i.e. L >= log2(360 / (2^n * extent)); for any DEM of more than a few
    pixels a side this is below the resolution's level and changes nothing.
    """
    lv = round(math.log2(180.0 / ((1 << tile_n) * res_deg)))
    if extent_deg is not None and extent_deg > 0:
        lv = max(lv, math.ceil(math.log2(360.0 / ((1 << tile_n) * extent_deg))))
    return int(min(max(lv, 0), MAX_LEVEL_LIMIT))


def _footprint_extent(info) -> float:
    """Smaller side of a source's footprint in degrees (longitude span taken across the
    antimeridian when the footprint crosses it)."""
    w, s, e, n = info.bounds_lonlat
    width = 360.0 if info.wraps_longitude else (e - w) % 360.0 or 360.0
    return float(min(width, n - s))


def _column_mask(level: int, bounds: tuple[float, float, float, float], wraps: bool) -> tuple:
    """Columns (bool mask over the level) and row range of tiles a footprint touches."""
    ncols, _ = level_shape(level)
    w, s, e, n = bounds
    if wraps:
        w, e = -180.0, 180.0
    # Columns and rows from two thin bands: the full product (tiles_covering's meshgrid) of
    # a fine global level has hundreds of millions of tiles (GBs) before any size check.
    eps = tile_size_deg(level) * 1e-3
    mid = (s + n) / 2.0
    xs, _ = tiles_covering(level, w, max(mid - eps, -90.0), e, min(mid + eps, 90.0))
    _, ys = tiles_covering(level, w, s, w + min(eps, (e - w) % 360.0 or eps), n)
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
        planned: list[set[tuple[int, int]]],
    ) -> None:
        self.sources = sources
        self.tile_n = tile_n
        self.max_level = max_level
        self.wavelet = wavelet
        self.halo = kernel_halo(wavelet)
        self.out_dir = out_dir
        self.tick = tick
        # Every level is the whole globe's node grid; only the planned chunks are computed.
        self.grids = {
            lv: LevelGrid(lv, tile_n, 0, 0, *level_shape(lv)) for lv in range(max_level + 1)
        }
        # The chunks (cy, cx) of each level that may hold data (`plan.plan_chunks`): every
        # other chunk has no data, no task, no file.
        self.planned = planned
        self.stats: dict[tuple[int, int, int], _ChunkStats] = {}
        self.level_files: dict[int, str] = {}  # level -> its VRT's sha256
        self.pole: dict[str, float | None] = {"north": None, "south": None}
        # input_order[i]: index in `sources` (finest first) of the i-th source as given.
        self.input_order: list[int] = list(range(len(sources)))
        self.update: Update | None = None
        self.writes = 0  # window writes so far (the fault-injection points)

    # -- planning ---------------------------------------------------------------------------

    # -- run --------------------------------------------------------------------------------

    def plan(
        self, token: str, gdal_threads: str, keep_open: bool = True
    ) -> tuple[BuildPlan, list[SourceSpec]]:
        """The build as the graph's tasks see it (small and picklable)."""
        plan = BuildPlan(
            folder=str(self.out_dir),
            tile_n=self.tile_n,
            max_level=self.max_level,
            wavelet=self.wavelet,
            halo=self.halo,
            grids=tuple(self.grids[lv] for lv in range(self.max_level + 1)),
            k=chunk_tiles(self.tile_n),
            gdal_threads=gdal_threads,
            keep_open=keep_open,
        )
        specs = [
            SourceSpec(
                token=f"{token}-{i}",
                dem_state=s.dem.__getstate__(),
                path=str(s.path),
                level=s.level,
                bounds=s.bounds,
                wraps=s.wraps,
                datum=s.datum,
                res=float(max(s.record.res_deg)),
                grid=None if s.grid is None else str(s.grid),
            )
            for i, s in enumerate(self.sources)
        ]
        return plan, specs

    def prepare(self, where: SchedulerChoice, token: str, previous: _Previous | None) -> int:
        """Plan the graph (and, with ``previous``, what an incremental update keeps, linked
        into the building folder); returns the number of tasks to run."""
        # One writer compresses with every core; many writers each with one thread.
        threads = "ALL_CPUS" if where.kind != "distributed" and where.workers == 1 else "1"
        plan, specs = self.plan(token, threads, keep_open=where.kind != "distributed")
        graph = build_graph(plan, specs, self.planned)
        self.graph, self.plan_, self.where = graph, plan, where
        self.update = None
        if previous is not None:
            try:
                pole = pole_task(plan, specs)
            finally:
                close_thread_sources()
            self.update = plan_update(
                previous.path,
                previous.manifest,
                plan,
                specs,
                self.input_order,
                previous.changed,
                graph,
                pole,
            )
            if self.update is None:
                clear_folder(self.out_dir)  # what a refused update linked: build it all
            else:
                graph.keep(self.update.known)
        return graph.tasks

    def build(self) -> None:
        """Run the ingest graph (chunk files and per-tile statistics), then write the level
        VRTs, the metadata shards and the chunks' build facts: everything but the manifest."""
        graph, plan = self.graph, self.plan_

        def done(key: str) -> None:
            self.tick(1)

        ran = run_graph(graph, self.where, done)
        results = {**graph.known, **ran}
        self.pole = results["pole"]
        ranges = self._stored_ranges([results[key] for key in graph.chunk_keys])
        for key in graph.chunk_keys:
            r = results[key]
            hmin, hmax = ranges.get((r.level, r.cy, r.cx), (r.hmin, r.hmax))
            self.stats[(r.level, r.cy, r.cx)] = _ChunkStats(
                hmin=hmin,
                hmax=hmax,
                error=np.where(np.isfinite(hmin), 0.0, np.nan),
                stride_delta=r.stride_delta,
                sha256=r.sha256,
                bytes=r.bytes,
                flags=r.flags,
            )
        if not any(np.isfinite(st.hmin).any() for st in self.stats.values()):
            names = ", ".join(str(s.path) for s in self.sources)
            raise DemError(f"no valid heights in {names}: every sample is nodata")
        # Exact tile errors: max |bilinear tile - finest data| at the finest nodes, each
        # error task's per-tile maxima folded with fmax (order-free: the result is exact).
        k = plan.k
        for key in graph.error_keys:
            for lv, iy, ix, red in results[key]:
                self._fold_errors(lv, iy, ix, red, k)
        for lv in range(self.max_level + 1):
            g = self._bbox_grid(lv)
            files = sorted(
                (cy, cx, chunk_file_name(lv, cy, cx, st.sha256), st.flags)
                for (lv_, cy, cx), st in self.stats.items()
                if lv_ == lv and st.sha256 is not None
            )
            self.level_files[lv] = write_level_vrt(self.out_dir / level_file_name(lv), g, files)
        self.top, self.shard_count = self._write_shards()
        # Build facts of the chunks (or error windows) computed now; the others were linked.
        levels = [self.sources[j].level for j in self.input_order]
        for key in graph.chunk_keys:
            error_key = key.replace("chunk-", "error-", 1)
            errors = results.get(error_key, [])
            # A chunk without data and without error maxima has no facts file (an update
            # reads a missing one as that: `update._read_facts`).
            if (key in ran or error_key in ran) and (
                _has(self.stats[_indices(key)]) or any(len(e[1]) for e in errors)
            ):
                write_facts(self.out_dir, results[key], errors, levels)

    def _stored_ranges(
        self, results: Sequence[ChunkResult]
    ) -> dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]:
        """Each chunk's per-tile (hmin, hmax) over the nodes the store holds (its own file's
        and its south, east and south-east neighbours' first row, column and node: a tile's
        closing row and column are stored there), `stored_ranges.tile_ranges`."""
        plan = self.plan_

        def east_of(lv: int, cy: int, cx: int) -> int | None:
            if cx + 1 < plan.chunk_shape(lv)[1]:
                return cx + 1
            return 0 if plan.grids[lv].global_lon else None

        own = {(r.level, r.cy, r.cx): r.stored for r in results if r.stored is not None}
        return tile_ranges(own, east_of)

    def _fold_errors(
        self, lv: int, iy: np.ndarray, ix: np.ndarray, red: np.ndarray, k: int
    ) -> None:
        """fmax the per-tile maxima ``red`` at tiles (ix, iy) of level lv into their chunks."""
        cy, cx = iy // k, ix // k
        codes = chunk_code(cy, cx)
        for code in np.unique(codes):
            sel = codes == code
            st = self.stats.get((lv, int(code) >> 32, int(code) & 0xFFFFFFFF))
            if st is None:
                continue  # a chunk not planned has no data: its tiles take no error
            ty, tx = iy[sel] % k, ix[sel] % k
            st.error[ty, tx] = np.fmax(st.error[ty, tx], red[sel])

    def _bbox_grid(self, lv: int) -> LevelGrid:
        """The tile bbox of level lv's planned chunks (shortest circular column run): they
        nest, so a level's bbox holds the parents of the next finer one's."""
        k = self.plan_.k
        cols, rows = level_shape(lv)
        keys = sorted(self.planned[lv])
        if not keys:
            return LevelGrid(lv, self.tile_n, 0, 0, 1, 1)
        cy = np.array([a for a, _ in keys])
        mask = np.zeros(-(-cols // k), dtype=bool)
        mask[[b for _, b in keys]] = True
        x0, nx = _extent_from_mask(mask)
        y0 = int(cy.min()) * k
        y1 = min(rows, (int(cy.max()) + 1) * k)
        return LevelGrid(lv, self.tile_n, x0 * k, y0, min(nx * k, cols), y1 - y0)

    def _write_shards(self) -> tuple[FileRef, int]:
        """Write the metadata shards (per-tile errors rounded up, heights outward, so the
        bounds the LOD reads stay bounds); the top shard's file and the count."""
        k = self.plan_.k
        ns = len(STRIDES)
        records: dict[tuple[int, int, int], ChunkRecord] = {}
        for (lv, cy, cx), st in self.stats.items():
            if not _has(st):
                continue
            kty, ktx = st.hmin.shape
            has = np.isfinite(st.hmin)
            err = np.where(has, np.nan_to_num(st.error, nan=0.0), np.nan)
            # The subsampled and full surfaces both stay within [hmin, hmax] (bilinear
            # interpolation of nodes in that range), which caps the chained sum.
            span = (st.hmax - st.hmin)[:, :, None]
            stride = err[:, :, None] + np.minimum(st.stride_delta, span)
            errors = np.full((k, k, ns + 1), np.nan)
            errors[:kty, :ktx, 0] = err
            errors[:kty, :ktx, 1:] = np.where(has[:, :, None], stride, np.nan)
            hmin = np.full((k, k), np.nan)
            hmax = np.full((k, k), np.nan)
            hmin[:kty, :ktx], hmax[:kty, :ktx] = st.hmin, st.hmax
            records[(lv, cy, cx)] = ChunkRecord(
                st.sha256 or "", st.bytes, errors, hmin, hmax, st.flags if st.sha256 else 0
            )
        self.records = records
        name, sha, size, count = write_tree(self.out_dir, self.tile_n, self.max_level, ns, records)
        return FileRef(name, sha, size), count

    def manifest(self, params: IngestParams, sources: Sequence[SourceRecord]) -> StoreManifest:
        """The store's manifest (format 7: level summaries, the top shard, the sources)."""
        levels = []
        for lv in range(self.max_level + 1):
            recs = [r for (l_, _, _), r in self.records.items() if l_ == lv]
            tiles = sum(int(np.isfinite(r.hmin).sum()) for r in recs)
            errs = [float(np.nanmax(r.errors[..., 0])) for r in recs if np.isfinite(r.hmin).any()]
            level_error = float(shards_f16_up(np.array(max(errs)))) if errs else None
            g = self._bbox_grid(lv)
            levels.append(
                LevelRecord(
                    level=lv,
                    node_spacing_deg=g.d,
                    file=level_file_name(lv),
                    sha256=self.level_files[lv],
                    chunks=sum(1 for r in recs if r.sha256),
                    tiles=tiles,
                    bytes=sum(r.bytes for r in recs),
                    bbox=Extent.of(g) if self.planned[lv] else None,
                    level_error=level_error,
                    pole_heights=PoleHeights(**self._level_pole(lv)),
                )
            )
        w, s, e, n = _union_bounds(self.sources)
        return StoreManifest(
            header=StoreHeader.current(),
            sources=tuple(sources),
            params=params,
            tile_n=self.tile_n,
            tile_size=(1 << self.tile_n) + 1,
            chunk_tiles=chunk_tiles(self.tile_n),
            wavelet=self.wavelet,
            max_level=self.max_level,
            strides=STRIDES,
            bounds=(w, s, e, n),
            levels=tuple(levels),
            shards=ShardsRecord(
                roots=shard_roots(self.max_level, self.tile_n),
                count=self.shard_count,
                top=self.top,
            ),
            pole_heights=PoleHeights(**self.pole),
        )

    def _level_pole(self, lv: int) -> dict[str, float | None]:
        """The pole heights a level holds: where one of its chunks with data holds the row."""
        rows, _ = chunk_grid_shape(lv, self.tile_n)
        at = {"north": 0, "south": rows - 1}
        return {
            name: (v if any(l_ == lv and cy == at[name] for (l_, cy, _) in self.records) else None)
            for name, v in self.pole.items()
        }

    def store_megabytes(self) -> int:
        """Uncompressed size of the planned chunks, MB (an upper bound of what the store
        needs)."""
        c = chunk_nodes(self.tile_n)
        n = sum(len(p) for p in self.planned)
        return max(1, math.ceil(n * (c + 1) ** 2 * 4 / 1e6))


def _indices(key: str) -> tuple[int, int, int]:
    """(level, cy, cx) of a graph key "chunk-L-CY-CX"."""
    _, lv, cy, cx = key.split("-")
    return int(lv), int(cy), int(cx)


def _has(st: _ChunkStats) -> bool:
    """Whether a chunk has data: a file, or tiles whose closed windows reach a neighbour's
    finite nodes."""
    return st.sha256 is not None or bool(np.isfinite(st.hmin).any())


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


def _open_sources(
    paths: Sequence[Path],
    crs: str | None,
    vdatum: str | None,
    threads: int,
) -> list[Dem]:
    """`open_dem` of every path (each scans its values once), on ``threads`` threads (GDAL
    reads release the GIL), in input order, each closed again once its `DemInfo` is known:
    the driver needs only that (and `Dem.__getstate__`, which the tasks reopen from), so a
    build of thousands of tiles holds no file handle per source (a desktop's default limit
    is 1 024 open files) nor the dataset's memory (~0.14 MB a source). The first failure in
    input order is raised once all have ended."""

    def one(p: Path) -> Dem:
        with rasterio.Env(GDAL_CACHEMAX=_GDAL_CACHE_MB * 1024 * 1024):  # per thread
            return _opened_info(p, crs, vdatum)

    if threads <= 1 or len(paths) <= 1:
        return [_opened_info(p, crs, vdatum) for p in paths]
    with ThreadPoolExecutor(max_workers=threads) as pool:
        futures = [pool.submit(one, p) for p in paths]
    dems: list[Dem] = []
    first: BaseException | None = None
    for f in futures:
        exc = f.exception()
        if exc is None:
            dems.append(f.result())
        elif first is None:
            first = exc
    if first is not None:
        raise first
    return dems


def _opened_info(path: Path, crs: str | None, vdatum: str | None) -> Dem:
    """A source opened, scanned and closed, its `DemInfo` computed (what the driver reads)."""
    with open_dem(path, crs, vdatum) as dem:
        dem.info  # noqa: B018  computed while the dataset is open
    return dem


def _check_sources(paths: Sequence[Path]) -> None:
    """Every source is a readable file, in `open_dem`'s words (before any hashing)."""
    for p in paths:
        check_dem_path(p)


def ingest(
    sources: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    tile_n: int = DEFAULT_TILE_N,
    max_level: int | None = None,
    wavelet: str = DEFAULT_WAVELET,
    crs: str | None = None,
    vdatum: str | None = None,
    force: bool = False,
    progress: bool = False,
    on_progress: Callable[[int, int], None] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    geoid_grids: Mapping[str, Path] | None = None,
) -> IngestResult:
    """Build (or refresh) the tile store ``out`` from DEM rasters.

    Args:
        sources: DEM paths; several may be combined (e.g. a global base and regional detail:
            where they overlap, the one with the finer pixels wins).
        out: store directory. Built in a temporary sibling and renamed into place when
            complete, so a failure never leaves a store that looks valid; an existing store is
            kept intact until the new one is ready. Only an empty folder or a globeview store
            (holding nothing but store files) is ever replaced.
        tile_n: tiles have (2^tile_n + 1)^2 samples.
        max_level: finest level (default: from the finest source's resolution).
        wavelet: PyWavelets name of the low-pass used for coarser levels.
        crs: CRS for every source (overrides or supplies a missing one).
        vdatum: vertical datum of every source ("ellipsoid", "egm96" or "egm2008"),
            overriding what the CRS or the source's kind says. Stored heights are always
            ellipsoidal; each source is converted with its own datum's geoid.
        force: rebuild even if the store is up to date (or of another format version).
        progress: show a tqdm bar with ETA on stderr.
        on_progress: called as ``on_progress(done, total)`` after each task of the graph (a
            chunk or an error window; for a GUI progress bar), in the calling thread; an
            exception it raises aborts the build (cancel) and, like any failure, leaves no
            store behind.
        workers: local workers (None: every core, os.cpu_count()); ignored on a cluster.
        scheduler: None (dask's local scheduler, threads, see `schedule.DEFAULT_LOCAL`),
            "threads", "processes", or "tcp://HOST:PORT": an existing dask.distributed
            scheduler, whose workers must see ``out``'s folder (a shared filesystem). The
            store is the same, bit for bit, whatever runs it.
        geoid_grids: geoid name -> grid file for the geoids globeview does not ship
            (``--geoid-grid egm2008=PATH``, `vdatum.parse_geoid_grids`); else
            `$GLOBEVIEW_GEOID_GRIDS`, then PROJ's data folders (`vdatum.find_geoid_grid`).

    Raises:
        DemError: a source cannot be used (unreadable, no CRS, all nodata, ...).
        StoreError: bad parameters, an output location that cannot be used, a disk that
            fills up, or a pyramid too large for the memory bound.
    """
    t_start = time.perf_counter()
    where = _check_parameters(sources, tile_n, max_level, wavelet, workers, scheduler)
    out_path = Path(out).absolute()
    ident = _check_output(out_path, force)
    if vdatum is not None:
        vdatum = parse_vdatum(vdatum).value  # one line for a typo, before any work
    src_paths = _source_paths(sources)
    grids = dict(geoid_grids or {})
    _check_named_grids(src_paths, vdatum, grids)  # a missing grid: one line before hashing
    contents = _source_contents(src_paths, where)
    src_paths, contents, duplicates = _drop_duplicates(src_paths, contents)
    params = IngestParams(
        tile_n=tile_n, max_level=max_level, wavelet=wavelet, crs=crs, vdatum=vdatum
    )
    previous: _Previous | None = None
    # A store of this format that opens is replaced by its next generation (readers that
    # have it open keep reading theirs: `generations.commit_generation`), --force included.
    existing = _usable(out_path) if ident.is_current else None
    if existing is not None and not force:
        # Converted with another geoid grid (or its grid is gone): a full rebuild.
        same_grids = _same_grids(existing, grids)
        if (
            same_grids
            and _same_inputs(existing, contents, params)
            and _vrts_current(out_path, existing)
        ):
            return IngestResult(out_path, True, existing.max_level, 0.0, duplicates=duplicates)
        if same_grids:
            previous = _changed_sources(out_path, existing, src_paths, contents, params)

    with contextlib.ExitStack() as stack:
        # A fixed GDAL block cache for everything below, the sources' value scan included.
        stack.enter_context(rasterio.Env(GDAL_CACHEMAX=_GDAL_CACHE_MB * 1024 * 1024))
        threads = _pool_size(src_paths, where)
        dems = _open_sources(src_paths, crs, vdatum, threads)
        _check_named_footprints(src_paths, contents, dems)  # a misnamed tile: one line
        found = _source_grids(dems, grids)  # one line for a grid not on this machine
        srcs = [
            _source(p, size, sha256, dem, tile_n, found)
            for p, (size, sha256), dem in zip(src_paths, contents, dems, strict=True)
        ]
        l_max = _clamp_levels(srcs, max_level)
        table = _footprint_table(srcs)
        _check_size_early(table, srcs, out_path.parent, max_level, tile_n)
        plan = plan_chunks(table, tile_n, max_level)
        _check_size(plan, srcs, out_path.parent, max_level)
        builder = _plan_build(srcs, tile_n, l_max, wavelet, out_path.parent, plan)
        _build_and_commit(
            builder, stack, out_path, params, where, (existing, previous), progress, on_progress
        )
    return IngestResult(
        out_path,
        False,
        l_max,
        time.perf_counter() - t_start,
        masked_samples=sum(int(s.dem.info.masked_samples) for s in srcs),
        fill_samples=sum(int(s.dem.info.fill_samples) for s in srcs),
        chunks_rebuilt=(
            builder.update.rebuilt if builder.update else len(builder.graph.chunk_keys)
        ),
        chunks_total=len(builder.graph.chunk_keys),
        duplicates=duplicates,
    )


# -- the steps of `ingest` ----------------------------------------------------------------------


def _check_parameters(
    sources: Sequence[object],
    tile_n: int,
    max_level: int | None,
    wavelet: str,
    workers: int | None,
    scheduler: str | None,
) -> SchedulerChoice:
    """Every parameter checked before any work (one StoreError line each); where the graph
    will run (a cluster's scheduler asked whether it answers)."""
    if not sources:
        raise StoreError("no source DEM given")
    if not (TILE_N_RANGE[0] <= tile_n <= TILE_N_RANGE[1]):
        raise StoreError(f"--tile-n must be in {TILE_N_RANGE[0]}..{TILE_N_RANGE[1]}, got {tile_n}")
    if max_level is not None and not (0 <= max_level <= MAX_LEVEL_LIMIT):
        raise StoreError(f"--max-level must be in 0..{MAX_LEVEL_LIMIT}, got {max_level}")
    if wavelet != DEFAULT_WAVELET:  # the default is good; checking it would load pywt
        lowpass_kernel(wavelet)  # WaveletError (a GlobeviewError) for a bad name
    where = parse_scheduler(workers, scheduler)  # one line for a bad value, before any work
    if where.address is not None:
        probe_scheduler(where.address)  # one line within seconds if no scheduler answers
    return where


def _check_output(out: Path, force: bool) -> StoreIdentity:
    """What ``out`` is (`check_target`: only a globeview store may be replaced), after
    cleaning what dead ingests left beside it; its folder must exist."""
    parent = out.parent
    # First what dead ingests left here: a store that a killed commit had moved aside is put
    # back before anything looks at --out.
    clean_stale_builds(parent)
    ident = check_target(out, force)
    if not parent.is_dir():
        if parent.exists():
            raise StoreError(f"{parent} is not a folder; choose another --out")
        raise StoreError(f"the folder for the store does not exist: {parent}")
    return ident


def _pool_size(paths: Sequence[Path], where: SchedulerChoice) -> int:
    """Threads for hashing and opening the sources: a few, never more than there are."""
    return min(len(paths), where.workers or os.cpu_count() or 1, 16)


def _source_paths(sources: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """The DEM files the sources stand for (a folder: the DEM files in it, `ingest.sources`),
    each checked."""
    src_paths = [p.absolute() for p in expand_sources(sources)]
    _check_sources(src_paths)
    return src_paths


def _source_contents(src_paths: Sequence[Path], where: SchedulerChoice) -> list[tuple[int, str]]:
    """The sources' content identity (size, sha256): the same content elsewhere is the same
    source."""
    # Hashed on a few threads (hashlib releases the GIL): a folder of thousands of tiles is
    # read at disk speed rather than one file at a time.
    with ThreadPoolExecutor(max_workers=max(1, _pool_size(src_paths, where))) as pool:
        return list(pool.map(lambda p: (p.stat().st_size, _sha256(p)), src_paths))


def _drop_duplicates(
    paths: Sequence[Path], contents: Sequence[tuple[int, str]]
) -> tuple[list[Path], list[tuple[int, str]], list[tuple[Path, Path]]]:
    """The sources without those holding the same bytes (size and sha256) as one given
    earlier, which is kept; and the (dropped, kept) pairs. The same path twice never gets
    here (`expand_sources` keeps it once)."""
    first: dict[tuple[int, str], Path] = {}
    kept: list[Path] = []
    kept_contents: list[tuple[int, str]] = []
    dropped: list[tuple[Path, Path]] = []
    for p, c in zip(paths, contents, strict=True):
        if c in first:
            dropped.append((p, first[c]))
            continue
        first[c] = p
        kept.append(p)
        kept_contents.append(c)
    return kept, kept_contents, dropped


def _check_named_footprints(
    paths: Sequence[Path], contents: Sequence[tuple[int, str]], dems: Sequence[Dem]
) -> None:
    """A source named as an SRTM or Copernicus tile must lie where its name says (design
    §4.5): ``ingest --plan`` places such tiles by name, so a tile renamed to another cell would
    plan one place and build another. DemError (one line, `check_name_footprint`) naming both
    places otherwise, before anything is written."""
    named = [
        i for i, (p, (size, _)) in enumerate(zip(paths, contents, strict=True))
        if is_tile_name(p.name, size)
    ]  # fmt: skip
    if not named:
        return
    table = footprints_from_names([str(paths[i]) for i in named], [contents[i][0] for i in named])
    for j, i in enumerate(named):
        check_name_footprint(str(paths[i]), dems[i].info.bounds_lonlat, table, j)


def _source(
    path: Path, size: int, sha256: str, dem: Dem, tile_n: int, grids: Mapping[str, Path]
) -> _Source:
    """An opened source with its natural finest level, its geoid grid (``grids``: name ->
    file, `_source_grids`) and its manifest record."""
    info = dem.info
    grid = grids.get(info.vertical_datum)
    res = float(min(info.res_deg))
    if not (res > 0 and math.isfinite(res)):
        raise DemError(f"{path} has no usable pixel size ({info.res_deg})")
    rec = SourceRecord(
        path=str(path),
        size=size,
        sha256=sha256,
        crs=info.crs,
        bounds=tuple(info.bounds_lonlat),
        res_deg=tuple(info.res_deg),
        vertical_datum=info.vertical_datum,
        vertical_datum_source=info.vertical_datum_source,
        heights=_heights_note(info.vertical_datum, grid),
    )
    return _Source(
        path,
        dem,
        _natural_level(res, tile_n, _footprint_extent(info)),
        res,
        info.bounds_lonlat,
        bool(info.wraps_longitude),
        rec,
        info.vertical_datum,
        grid,
    )


def _grid_or_refuse(name: str, given: Mapping[str, Path], source: Path, why: str) -> Path:
    """The grid of external geoid ``name`` (`find_geoid_grid`), or DemError with the one line
    `missing_grid_line` naming ``source``."""
    path = find_geoid_grid(name, given)
    if path is None:
        raise DemError(missing_grid_line(name, source.name, why))
    return path


def _check_named_grids(paths: Sequence[Path], vdatum: str | None, given: dict[str, Path]) -> None:
    """The grids the sources need by ``--vdatum`` or by their names (Copernicus tiles:
    EGM2008) looked up before any source is opened and scanned: a missing one is one line
    at once. Found grids are added to ``given``."""
    if vdatum is not None:
        if vdatum in EXTERNAL_GRIDS and paths:
            given[vdatum] = _grid_or_refuse(vdatum, given, paths[0], "--vdatum")
        return
    first = next((p for p in paths if COPERNICUS_NAME.match(p.name)), None)
    if first is not None:
        given["egm2008"] = _grid_or_refuse("egm2008", given, first, "Copernicus DEM default")


def _source_grids(dems: Sequence[Dem], given: Mapping[str, Path]) -> dict[str, Path]:
    """name -> grid file of every external geoid the opened sources are on (their CRS may
    declare one: EPSG:3855); DemError (one line) for the first source whose grid is not on
    this machine."""
    out: dict[str, Path] = {}
    for dem in dems:
        name = dem.info.vertical_datum
        if name in EXTERNAL_GRIDS and name not in out:
            why = dem.info.vertical_datum_source
            out[name] = _grid_or_refuse(name, given, dem.path, why)
    return out


def _same_grids(manifest: StoreManifest, given: Mapping[str, Path]) -> bool:
    """Whether every source of the store on an external geoid was converted with the grid
    this build would use (file name and sha256, as its heights note says); False when that
    grid is not on this machine now (the build then says so)."""
    for src in manifest.sources:
        if src.vertical_datum not in EXTERNAL_GRIDS:
            continue
        path = find_geoid_grid(src.vertical_datum, given)
        if path is None or src.heights != _heights_note(src.vertical_datum, path):
            return False
    return True


def _clamp_levels(srcs: Sequence[_Source], max_level: int | None) -> int:
    """L_max (``max_level``, else the finest natural level); each source's level clamped to
    it. Past the finest natural level (--max-level above it) the finest sources supply the
    extra levels, resampled (the levels between would otherwise have no extent at all)."""
    natural = max(s.level for s in srcs)
    l_max = natural if max_level is None else max_level
    for s in srcs:
        s.level = l_max if s.level == natural else min(s.level, l_max)
    return l_max


def _footprint_table(srcs: Sequence[_Source]) -> FootprintTable:
    """The planner's table of the opened sources: their footprints, finer pixel sizes (also
    the reach `tasks.fill_reads_source` grows a footprint by) and datums."""
    return table_from_bounds(
        [str(s.path) for s in srcs],
        [s.bounds for s in srcs],
        [s.res for s in srcs],
        [s.res for s in srcs],
        [s.wraps for s in srcs],
        [s.datum if s.datum in DATUMS else "ellipsoid" for s in srcs],
    )


def _check_size_early(
    table: FootprintTable,
    srcs: Sequence[_Source],
    parent: Path,
    max_level: int | None,
    tile_n: int,
) -> None:
    """`_check_size` on a lower bound of the chunks (`plan.chunks_at_least`: no chunk set
    built), so a build far past the disk is one line at once, not after minutes of planning;
    the exact check follows the plan."""
    at_least = chunks_at_least(table, tile_n, max_level)
    full = chunk_nodes(tile_n) ** 2 * cost.BYTES_PER_NODE + cost.META_BYTES_PER_CHUNK
    c0 = chunk_levels_c0(tile_n)  # levels above it are one small chunk: counted as none
    need = [n * full if lv >= c0 else 0.0 for lv, n in enumerate(at_least)]
    _refuse_if_over(need, sum(at_least), srcs, parent, max_level, at_least=True)


def _check_size(
    plan: ChunkPlan, srcs: Sequence[_Source], parent: Path, max_level: int | None
) -> None:
    """StoreError (one line, before anything is written) when the planned chunks would not
    fit on the disk the store goes to: their nodes at `cost.BYTES_PER_NODE` (an upper bound:
    NaN nodes compress to almost nothing) and their metadata. No tile count caps a build
    (store format 7); the disk does, and `plan.PLAN_MAX_CHUNKS` the plan's memory."""
    need = [
        plan.level_nodes(lv) * cost.BYTES_PER_NODE
        + plan.levels[lv].chunks * cost.META_BYTES_PER_CHUNK
        for lv in range(plan.max_level + 1)
    ]
    _refuse_if_over(need, plan.chunks, srcs, parent, max_level, at_least=False)


def _refuse_if_over(
    need: Sequence[float],
    chunks: int,
    srcs: Sequence[_Source],
    parent: Path,
    max_level: int | None,
    *,
    at_least: bool,
) -> None:
    """StoreError (one line) when ``need`` (bytes per level 0..L_max) is more than the free
    space where ``parent`` is, naming the finest level that fits."""
    where = parent
    while not where.exists() and where != where.parent:
        where = where.parent
    try:
        free = shutil.disk_usage(where).free
    except OSError:
        return  # the output checks say what is wrong with the location
    total = sum(need)
    if total <= free:
        return
    l_max = len(need) - 1
    fit = max((lv for lv in range(l_max + 1) if sum(need[: lv + 1]) <= free), default=0)
    src = min(srcs, key=lambda s: s.res)
    what = (
        f"--max-level {l_max}"
        if max_level is not None
        else f"{src.path} is {src.dem.info.width}x{src.dem.info.height} pixels: its finest "
        f"level {l_max}"
    )
    count = f"at least {chunks:,}" if at_least else f"{chunks:,}"
    raise StoreError(
        f"{what} would have {count} chunk files, about {_size_text(total)}; the limit "
        f"is the free space in {where}: {_size_text(free)}; use --max-level {fit}"
    )


def _size_text(n: float) -> str:
    """Bytes for people: 3.2 GB, 51 TB."""
    for unit, f in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n >= f:
            return f"{n / f:.3g} {unit}"
    return f"{n / 1e3:.3g} kB"


def _plan_build(
    srcs: Sequence[_Source], tile_n: int, l_max: int, wavelet: str, parent: Path, plan: ChunkPlan
) -> _Builder:
    """The builder of the pyramid: its sources finest first (the finest wins where it has
    data), the order they were given kept for the manifest, and the chunks ``plan`` holds
    (`plan.plan_chunks` of the same sources: the one planner of `ingest --plan` and the
    build)."""
    # Finest first; pixel sizes equal to a ppm are ties, kept in input order (`fill_order`).
    ordered = [srcs[i] for i in fill_order(np.array([s.res for s in srcs])).tolist()]
    builder = _Builder(ordered, tile_n, l_max, wavelet, parent, _no_tick, plan.chunk_sets())
    sorted_at = {id(t): j for j, t in enumerate(ordered)}  # not a search per source: 10^4 tiles
    builder.input_order = [sorted_at[id(s)] for s in srcs]
    return builder


def _build_and_commit(
    builder: _Builder,
    stack: contextlib.ExitStack,
    out: Path,
    params: IngestParams,
    where: SchedulerChoice,
    start: tuple[StoreManifest | None, _Previous | None],
    progress: bool,
    on_progress: Callable[[int, int], None] | None,
) -> None:
    """Run the build in a locked building folder beside ``out`` (GDAL's chatter on fd 2
    kept back), write the manifest last and commit the store into place: a new store is
    renamed in; ``start``'s existing store (its manifest) gets the build as its next
    generation, beside the files its readers have open (`commit_generation`); ``start``'s
    `_Previous`: what an incremental update keeps. A failed write is one StoreError line
    (`write_error`), the building folder removed."""
    existing, previous = start
    parent = out.parent
    try:
        tmp, tok = stack.enter_context(build_folder(parent, out.name))
    except OSError as exc:
        raise StoreError(f"cannot write the store in {parent}: {exc.strerror}") from None
    dropped = stack.enter_context(gdal_quiet())
    try:
        with _progress(progress) as bar:
            done = [0]

            def step(n: int = 1) -> None:
                bar.update(n)
                if on_progress is not None:
                    done[0] += n
                    on_progress(done[0], total)

            builder.out_dir, builder.tick = tmp, step
            total = builder.prepare(where, tok, previous)
            bar.total = total
            bar.refresh()
            builder.build()
        _fault_point("manifest")
        _write_manifest(tmp, builder, params)
        # The store's coverage into its top shard (read from the store just written), which
        # the manifest names: written again.
        builder.top = with_coverage(tmp)
        if existing is not None:
            # Sources in the order given (the builder sorts its own list finest first).
            given = [builder.sources[j].record for j in builder.input_order]
            manifest = replace(builder.manifest(params, given), generation=existing.generation + 1)
            commit_generation(tmp, out, existing, manifest, _fault_point)
            return
        _write_manifest(tmp, builder, params)
        commit(tmp, out, tok)
    except _BUILD_ERRORS as exc:
        raise write_error(exc, dropped, out, parent, builder.store_megabytes()) from None


def _write_manifest(tmp: Path, builder: _Builder, params: IngestParams) -> None:
    """The manifest of the store built in ``tmp``, written atomically."""
    part = tmp / (MANIFEST_NAME + ".part")
    with part.open("w", encoding="utf-8") as f:
        # Sources in the order given (the builder sorts its own list finest first).
        given = [builder.sources[j].record for j in builder.input_order]
        builder.manifest(params, given).write(f)
    os.replace(part, tmp / MANIFEST_NAME)


@dataclass(frozen=True)
class _Previous:
    """The committed store an incremental update starts from, and which sources changed
    (indices as given)."""

    path: Path
    manifest: StoreManifest
    changed: list[int]


def _changed_sources(
    out: Path,
    manifest: StoreManifest,
    paths: Sequence[Path],
    contents: Sequence[tuple[int, str]],
    params: IngestParams,
) -> _Previous | None:
    """The store at ``out`` as the start of an incremental update: the same parameters and
    source paths (in order), some sources' content changed; None otherwise."""
    old = manifest.sources
    if manifest.params != params or [s.path for s in old] != [str(p) for p in paths]:
        return None
    changed = [i for i, (s, c) in enumerate(zip(old, contents)) if (s.size, s.sha256) != c]
    return _Previous(out, manifest, changed) if changed else None


def _usable(store: Path) -> StoreManifest | None:
    """The manifest of a store that opens (manifest and level files checked, see
    `TileStore.open`), None otherwise: a damaged store is rebuilt rather than called up to
    date."""
    try:
        with TileStore.open(store) as st:
            return st.manifest
    except StoreError:
        return None


def _vrts_current(store: Path, manifest: StoreManifest) -> bool:
    """Whether the store's level VRTs are its manifest's (an update killed between its switch
    and its VRTs left the previous generation's: then the store is built again)."""
    try:
        return all(file_sha256(store / lv.file) == lv.sha256 for lv in manifest.levels)
    except OSError:
        return False


def _same_inputs(
    manifest: StoreManifest, contents: Sequence[tuple[int, str]], params: IngestParams
) -> bool:
    """Whether the store was built from the same content (size and sha256 of each source,
    in order) with the same parameters: where the sources live does not matter."""
    old = [(s.size, s.sha256) for s in manifest.sources]
    return manifest.params == params and old == list(contents)


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
    from tqdm import tqdm  # deferred: only a terminal ingest draws a bar

    tty = tty_stderr()  # fd 2 is redirected during the build (see gdal_quiet)
    bar = tqdm(total=0, unit="win", desc="ingest", dynamic_ncols=True, file=tty)
    try:
        yield bar
    finally:
        bar.close()
        if tty is not None:
            tty.close()
