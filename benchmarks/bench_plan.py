"""Planning the SRTM 1" planet from tile names (issue #25: at most 60 s and 1 GB), and the
measured cost per node behind `globeview ingest --plan`'s estimates.

Plan: generates the names of N SRTM 1" tiles (default 14 277, SRTM's count: the 1-degree
cells between 56 S and 60 N with ground above 0 m in the embedded ETOPO 20', 12 532, then
the cells next to them, coast first, until N), no files, and plans them as `--plan` does
from names (`footprints_from_names` with the 1" size, `plan_chunks`, the shard count). Prints
the plan's table, wall and CPU seconds of the planning and the process's peak RSS.

Measure (``--measure``): ingests data/N44W072.hgt (a real SRTM3 tile) with one local worker
into a temporary store and prints the figures `terrain/ingest/cost.py` holds: CPU
nanoseconds a node of the chunk files (format 7's chunks are whole 1024^2 windows, NaN where
no source has data: the nodes `--plan` counts), and store bytes a node with data (NaN
compresses to almost nothing; a planet's land chunks are nearly full).

    .venv/bin/python benchmarks/bench_plan.py [--tiles 14277] [--measure [--rounds 5]]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from scale_planet import land_cells  # noqa: E402  (a sibling script)

from globeview.terrain.ingest.footprints import footprints_from_names  # noqa: E402
from globeview.terrain.ingest.plan import plan_chunks  # noqa: E402
from globeview.terrain.ingest.report import PlanReport, format_plan  # noqa: E402

SRTM_TILES = 14_277


def planet_cells(n: int) -> list[tuple[int, int]]:
    """(lat, lon) south-west corners of ``n`` cells: land first, then rings around it."""
    cells = land_cells(ROOT / "data" / "etopo20.tif")
    band = cells.any(axis=1)
    band[np.flatnonzero(band).min() : np.flatnonzero(band).max() + 1] = True
    chosen = cells.copy()
    order = [np.flatnonzero(chosen.ravel())]
    while int(chosen.sum()) < n:
        grown = chosen.copy()
        grown[1:] |= chosen[:-1]
        grown[:-1] |= chosen[1:]
        grown |= np.roll(chosen, 1, axis=1) | np.roll(chosen, -1, axis=1)
        grown &= band[:, None]
        new = np.flatnonzero((grown & ~chosen).ravel())
        if new.size == 0:
            break
        order.append(new)
        chosen = grown
    flat = np.concatenate(order)[:n]
    rows, cols = np.divmod(flat, 360)
    return [(89 - int(r), int(c) - 180) for r, c in zip(rows, cols, strict=True)]


def srtm_names(cells: list[tuple[int, int]]) -> list[str]:
    return [
        f"{'N' if lat >= 0 else 'S'}{abs(lat):02d}{'E' if lon >= 0 else 'W'}{abs(lon):03d}.hgt"
        for lat, lon in cells
    ]


def bench_plan(n: int) -> None:
    names = srtm_names(planet_cells(n))
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0, c0 = time.perf_counter(), time.process_time()
    table = footprints_from_names(names)  # sizes: SRTM 1" (no files)
    plan = plan_chunks(table, 6)
    shards = plan.shards()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(format_plan(PlanReport(table, plan, {}, wall, rss)))
    print(
        f'planet plan: {n} SRTM 1" names, {plan.chunks} chunks, {shards} shards: '
        f"{wall:.2f} s wall, {cpu:.2f} s CPU, peak RSS {rss / 2**20:.0f} MiB "
        f"({rss0:.0f} MiB before planning: the interpreter, numpy, rasterio)"
    )


def bench_measure(rounds: int) -> None:
    """Median over ``rounds`` builds (a shared machine's load moves one run 1.5x)."""
    runs = sorted((_measure_once() for _ in range(rounds)), key=lambda r: r[0])
    cpu, wall, nodes, finite, size = runs[len(runs) // 2]
    print(
        f"measure: N44W072.hgt, 1 worker, median of {rounds}: {cpu:.2f} CPU s ({wall:.2f} s "
        f"wall; CPU {runs[0][0]:.2f}..{runs[-1][0]:.2f} s), {nodes} nodes in the chunk files "
        f"of every level ({finite} with data), {size} bytes of chunks"
    )
    print(f"NS_PER_NODE = {cpu / nodes * 1e9:.0f}.0  # CPU a node of the planned chunks")
    print(f"BYTES_PER_NODE = {size / finite:.2f}  # bytes a node with data")


def _measure_once() -> tuple[float, float, int, int, int]:
    """(CPU s, wall s, nodes, nodes with data, bytes) of one 1-worker build of
    data/N44W072.hgt: the nodes of its chunk files (what `--plan` counts: format 7's chunks
    are whole, NaN where no source has data) and the finite ones among them."""
    import rasterio

    from globeview.terrain.ingest.driver import ingest

    src = ROOT / "data" / "N44W072.hgt"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "store"
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        t0 = time.perf_counter()
        ingest([src], out, workers=1, force=True)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        files = list(out.glob("chunks/**/*.tif"))  # store format 7's chunk files
        if not files:
            raise SystemExit("bench_plan: the store has no chunks/ folder (not store format 7)")
        nodes = finite = size = 0
        for f in files:
            with rasterio.open(f) as ds:
                a = ds.read(1)
            nodes += a.size
            finite += int(np.isfinite(a).sum())
            size += f.stat().st_size
    return cpu, wall, nodes, finite, size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tiles", type=int, default=SRTM_TILES, help="SRTM names to plan")
    ap.add_argument("--measure", action="store_true", help="also measure the cost a node")
    ap.add_argument("--rounds", type=int, default=5, help="builds measured (median)")
    args = ap.parse_args()
    if not 1 <= args.tiles <= 180 * 360:
        ap.error(f"--tiles must be in 1..{180 * 360} (one-degree cells), not {args.tiles}")
    if args.rounds < 1:
        ap.error(f"--rounds must be >= 1, not {args.rounds}")
    load = os.getloadavg()[0]
    print(f"bench_plan {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, load {load:.2f}")
    bench_plan(args.tiles)
    if args.measure:
        bench_measure(args.rounds)


if __name__ == "__main__":
    main()
