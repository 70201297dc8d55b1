"""`globeview ingest --plan`: what a build would do, without building (issue #25, §4.3).

`make_plan` expands the sources (folders, globs, ``@lists``), takes their footprints from
names or headers (`footprints`), checks that every vertical datum can be converted (an
EGM2008 source needs its grid: `vdatum.find_geoid_grid`), and plans the chunk sets
(`plan.plan_chunks`). `format_plan` words it: sources and datums, chunks, source reads,
nodes and bytes per level, tasks, files, bytes and the estimated core-hours from the
measured constants of `cost`. Nothing is written and no lock is taken, so it runs on a full
disk and beside a running build.
"""

from __future__ import annotations

import contextlib
import os
import resource
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from globeview.errors import DemError, StoreError
from globeview.terrain.dem.vdatum import EXTERNAL_GRIDS, find_geoid_grid, missing_grid_line
from globeview.terrain.ingest import cost
from globeview.terrain.ingest.footprints import DATUMS, FootprintTable, footprints
from globeview.terrain.ingest.plan import ChunkPlan, estimated_files, plan_chunks
from globeview.terrain.ingest.sources import expand_sources
from globeview.terrain.store.layout import chunk_nodes, chunk_tiles
from globeview.terrain.store.schema import MAX_LEVEL_LIMIT, TILE_N_RANGE

__all__ = ["PlanReport", "format_plan", "make_plan"]


@dataclass(frozen=True)
class PlanReport:
    """A plan and what it took: footprints, chunk sets, the geoid grids it needs (name ->
    path), planning seconds and peak RSS (bytes)."""

    table: FootprintTable
    plan: ChunkPlan
    grids: Mapping[str, Path]
    seconds: float
    peak_rss: int


def _check(tile_n: int, max_level: int | None) -> None:
    if not (TILE_N_RANGE[0] <= tile_n <= TILE_N_RANGE[1]):
        raise StoreError(f"--tile-n must be in {TILE_N_RANGE[0]}..{TILE_N_RANGE[1]}, got {tile_n}")
    if max_level is not None and not (0 <= max_level <= MAX_LEVEL_LIMIT):
        raise StoreError(f"--max-level must be in 0..{MAX_LEVEL_LIMIT}, got {max_level}")


def needed_grids(table: FootprintTable, given: Mapping[str, Path]) -> dict[str, Path]:
    """The grids of the non-shipped geoids the sources are on (name -> path); DemError with
    `missing_grid_line` for the first source whose grid is not on this machine."""
    out: dict[str, Path] = {}
    for name in EXTERNAL_GRIDS:
        first = table.first_with_datum(name) if name in DATUMS else None
        if first is None:
            continue
        path = find_geoid_grid(name, given)
        if path is None:
            why = table.datum_why[table.paths.index(first)]
            raise DemError(missing_grid_line(name, os.path.basename(first), why))
        out[name] = path
    return out


@contextlib.contextmanager
def _bar(enabled: bool) -> Iterator[Callable[[int, int], None] | None]:
    """``on_progress(done, total)`` drawing a tqdm bar with ETA on stderr (None: no bar)."""
    if not enabled:
        yield None
        return
    from tqdm import tqdm  # deferred: only a terminal plan draws a bar

    bar = tqdm(total=0, unit="file", desc="footprints", dynamic_ncols=True, file=sys.stderr)

    def tick(done: int, total: int) -> None:
        if bar.total != total:
            bar.total = total
        bar.update(done - bar.n)

    try:
        yield tick
    finally:
        bar.close()


def make_plan(
    sources: Sequence[str | os.PathLike[str]],
    *,
    tile_n: int = 6,
    max_level: int | None = None,
    crs: str | None = None,
    vdatum: str | None = None,
    how: str = "auto",
    geoid_grids: Mapping[str, Path] | None = None,
    progress: bool = False,
) -> PlanReport:
    """Plan a build of ``sources`` (see the module docstring); GlobeviewError (one line) for
    bad parameters, an empty glob or list, a missing or unreadable source, a missing geoid
    grid, a plan over the limit."""
    t0 = time.perf_counter()
    _check(tile_n, max_level)
    if not sources:
        raise StoreError("no source DEM given")
    paths = expand_sources(list(sources))
    with _bar(progress) as tick:
        table = footprints(paths, how=how, crs=crs, vdatum=vdatum, on_progress=tick)
    grids = needed_grids(table, geoid_grids or {})
    plan = plan_chunks(table, tile_n, max_level)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return PlanReport(table, plan, grids, time.perf_counter() - t0, rss)


# -- words ------------------------------------------------------------------------------------


def _bytes(n: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("KB", 1e3)):
        if n >= size:
            return f"{n / size:.2f} {unit}"
    return f"{n:.0f} B"


def _source_lines(t: FootprintTable, grids: Mapping[str, Path]) -> list[str]:
    by_name = int((t.how == 0).sum())
    datums = ", ".join(f"{d} {n} ({why})" for (d, why), n in t.datum_counts().items())
    lines = [
        f"sources: {len(t)} ({by_name} by name, {len(t) - by_name} by header); datums: {datums}"
    ]
    lines += [f"geoid grid {name}: {path}" for name, path in grids.items()]
    return lines


def _level_lines(p: ChunkPlan) -> list[str]:
    """The per-level table; tasks: a chunk and an error+meta task a chunk, and the shards
    rooted at the level (the top shard at level 0)."""
    shards = p.shards_by_root()
    head = ("level", "chunks", "tasks", "source reads", "nodes", "est. bytes")
    widths = (5, 10, 10, 12, 9, 10)
    lines = ["  ".join(f"{h:>{w}}" for h, w in zip(head, widths, strict=True))]
    for lv in range(p.max_level, -1, -1):
        lp = p.levels[lv]
        nodes = p.level_nodes(lv)
        cells = (
            f"{lv}",
            f"{lp.chunks:,}",
            f"{2 * lp.chunks + shards.get(lv, 0):,}",
            f"{lp.source_reads:,}",
            f"{nodes:.3g}",
            _bytes(nodes * cost.BYTES_PER_NODE),
        )
        lines.append("  ".join(f"{c:>{w}}" for c, w in zip(cells, widths, strict=True)))
    return lines


def format_plan(r: PlanReport) -> str:
    """The plan in words (see `globeview ingest --plan`), one line a fact."""
    p, t = r.plan, r.table
    k, c = chunk_tiles(p.tile_n), chunk_nodes(p.tile_n)
    n_tile = (1 << p.tile_n) + 1
    chunks, shards = p.chunks, p.shards()
    nodes = sum(p.level_nodes(lv) for lv in range(p.max_level + 1))
    tasks = len(t) + 2 * chunks + shards + 1  # + the pole task
    data, meta = nodes * cost.BYTES_PER_NODE, chunks * cost.META_BYTES_PER_CHUNK
    hours = cost.core_hours(nodes)
    lines = [
        *_source_lines(t, r.grids),
        f"levels 0..{p.max_level}, tiles {n_tile}^2 (tile_n {p.tile_n}), chunks {c}^2 nodes "
        f"({k}x{k} tiles)",
        *_level_lines(p),
        f"total  {chunks:,} chunks, {tasks:,} tasks ({len(t):,} source, {chunks:,} chunk, "
        f"{chunks:,} error+meta, {shards:,} shard, 1 pole), {estimated_files(p):,} files, "
        f"{_bytes(data)} + {_bytes(meta)} metadata",
        f"cost   {hours:.3g} core-hours at {cost.NS_PER_NODE:g} ns a chunk node "
        f"({cost.COST_SOURCE}); x{cost.CLUSTER_FACTOR} on a dask.distributed cluster",
        f"plan   {r.seconds:.2f} s, peak RSS {r.peak_rss / 1e6:.0f} MB (upper bounds from "
        "footprints: the build drops chunks its sources hold no data in)",
    ]
    return "\n".join(lines)
