"""Ingest benchmark (issue #18 item 4): today's ingest, the Dask ingest on 1 and all cores, a
2-process `distributed.LocalCluster`, and GDAL's overview build, on the same rasters.

For each raster size (the synthetic-detail DEM of benchmarks/make_big_dem.py, N x N float32
over 1 x 1 degree, cached in benchmarks/cache/) it runs, each in a fresh child process:

- ``today``: the ingest before issue #18 (commit a46750e), extracted once with ``git archive``
  into benchmarks/cache/baseline-a46750e and run with PYTHONPATH pointing there (skipped, with
  a note, outside a git checkout);
- ``dask 1`` / ``dask N``: `globeview.terrain.ingest.driver.ingest(...,
  workers=1 | os.cpu_count())`,
  Dask's local scheduler (threads), and ``dask N processes`` (``scheduler="processes"``);
- ``cluster 2x1``: a `distributed.LocalCluster(n_workers=2, processes=True,
  threads_per_worker=1)`, the ingest given ``scheduler=cluster.scheduler_address``;
- ``gdal ovr``: GDAL's own overview build of a copy of the raster (rasterio
  ``build_overviews``, Resampling.average = ``gdaladdo -r average``), the reference.

Figures: wall (the ingest call alone, in the child), CPU (user + system of every process of
the run: the child and its reaped children via ``os.wait4``; for the cluster the workers' own
``getrusage`` deltas asked with ``client.run``), MB/s (source bytes / wall), peak RSS per
worker (``ru_maxrss``: for an in-process run the whole child, all its threads; for the
cluster the largest worker), store size. Then the per-tile costs that docs/scale.md
extrapolates, the scaling 1 core -> all cores, and the targets, met or not met. The stores
of this checkout's rows must hold the same per-tile errors and height ranges whatever the
scheduler (one that does not is a DIFFER); commit a46750e's store is compared with them for
information: since store format 6 (issue #29) its tiles at the data edges differ by design.
Targets:

- Dask ingest on all cores <= 3x GDAL's overview time;
- peak RSS per worker <= 512 MB at every raster size;
- near-linear scaling: speedup(1 -> N cores) >= 0.8 N.

Stores are built in temporary folders (never benchmarks/cache/store_*) and removed. A script
that prints figures, not a timed test; wall times on a shared machine vary with its load
(printed).

    python benchmarks/bench_ingest.py [--sizes 4096,8192] [--rounds 1] [--skip today,cluster]

Rounds are interleaved (every row once, then again), medians printed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "benchmarks" / "cache"
BASE_COMMIT = "a46750e"
BASELINE = CACHE / f"baseline-{BASE_COMMIT}"
RUNS = ("today", "dask1", "daskN", "daskP", "cluster", "gdal")
SIZE_RANGE = (256, 32768)
#: Targets of issue #18 item 4.
RATIO_TARGET = 3.0  # Dask all cores / GDAL overview wall time
RSS_TARGET_MB = 512.0  # per worker, at any raster size
SCALING_TARGET = 0.8  # speedup / cores counted as "near-linear"


class BenchError(Exception):
    """A bad argument or an unusable environment (one line, exit status 2)."""


# ---------------------------------------------------------------------------------------------
# The children (this file run with --child JSON): each times one ingest and prints one JSON line


def _cpu_self_and_children() -> float:
    import resource

    a = resource.getrusage(resource.RUSAGE_SELF)
    b = resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _worker_usage() -> tuple[float, float]:
    """(CPU seconds, peak RSS MB) of the process it runs in (a dask worker)."""
    import resource

    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime, u.ru_maxrss / 1024.0


def _child(spec: dict) -> None:
    kind, src, out = spec["kind"], spec["src"], spec["out"]
    result: dict[str, object] = {}
    if kind == "gdal":
        import rasterio
        from rasterio.enums import Resampling

        t, c = time.perf_counter(), _cpu_self_and_children()
        with rasterio.open(src, "r+") as ds:
            f = [2**k for k in range(1, 16) if max(ds.shape) >> k >= 256]
            ds.build_overviews(f, Resampling.average)
        result = {"wall": time.perf_counter() - t, "cpu": _cpu_self_and_children() - c}
    elif kind == "cluster":
        from distributed import Client, LocalCluster

        ingest = _ingest_function()

        t0 = time.perf_counter()
        with (
            LocalCluster(
                n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None
            ) as cluster,
            Client(cluster) as client,
        ):
            start = time.perf_counter() - t0
            before = client.run(_worker_usage)
            t, c = time.perf_counter(), _cpu_self_and_children()
            ingest([src], out, force=True, progress=False, scheduler=cluster.scheduler_address)
            wall, cpu_here = time.perf_counter() - t, _cpu_self_and_children() - c
            after = client.run(_worker_usage)
        worker_cpu = sum(after[w][0] - before[w][0] for w in after)
        result = {
            "wall": wall,
            "cpu": cpu_here + worker_cpu,
            "start": start,
            "worker_rss": max(v[1] for v in after.values()),
            "client_rss": _worker_usage()[1],  # this process: the client and the scheduler
            "workers": len(after),
        }
    else:
        ingest = _ingest_function()

        kw = spec.get("kwargs", {})
        t, c = time.perf_counter(), _cpu_self_and_children()
        ingest([src], out, force=True, progress=False, **kw)
        result = {"wall": time.perf_counter() - t, "cpu": _cpu_self_and_children() - c}
    print("RESULT " + json.dumps(result), flush=True)


def _ingest_function():
    """`ingest` of the globeview on the path: this checkout's (`globeview.terrain.ingest.driver`
    since issue #28) or the baseline commit's, where `globeview.terrain.ingest` was a module."""
    try:
        from globeview.terrain.ingest.driver import ingest
    except ImportError:  # the baseline: ingest was one module, not a package
        from globeview.terrain.ingest import ingest  # type: ignore[attr-defined,no-redef]
    return ingest


def _api_child() -> None:
    """Print which knobs today's `ingest` takes (the Dask API of issue #18 may not be there)."""
    import inspect

    ingest = _ingest_function()
    print("RESULT " + json.dumps(sorted(inspect.signature(ingest).parameters)))


# ---------------------------------------------------------------------------------------------
# The parent: stays small (no numpy): a forked child's ru_maxrss starts at the parent's RSS.


def _wait_child(spec: dict, env: dict[str, str] | None = None) -> dict:
    """Run one child (this file with --child); its JSON result plus ``rss`` (MB: ru_maxrss of
    the child and its reaped children) and ``cpu_rusage`` (s, their user + system), from
    os.wait4 (Popen would reap the child first: its pipes are read by threads instead)."""
    import threading

    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", json.dumps(spec)]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT
    )
    chunks: dict[str, str] = {}

    def drain(name: str, stream) -> None:
        chunks[name] = stream.read()

    readers = [
        threading.Thread(target=drain, args=("out", proc.stdout)),
        threading.Thread(target=drain, args=("err", proc.stderr)),
    ]
    for r in readers:
        r.start()
    try:
        _, status, usage = os.wait4(proc.pid, 0)
    except BaseException:  # Ctrl-C, or SIGTERM made SystemExit by main(): no orphan child
        proc.terminate()
        proc.wait(timeout=30)
        raise
    proc.returncode = os.waitstatus_to_exitcode(status)
    for r in readers:
        r.join()
    out, err = chunks.get("out", ""), chunks.get("err", "")
    if proc.returncode:
        last = (err.strip().splitlines() or ["no message"])[-1]
        raise RuntimeError(f"{spec['kind']} failed (exit {proc.returncode}): {last}")
    line = next((ln for ln in out.splitlines() if ln.startswith("RESULT ")), None)
    if line is None:
        raise RuntimeError(f"{spec['kind']} printed no result")
    res = json.loads(line[len("RESULT ") :])
    if isinstance(res, dict):
        res["rss"] = usage.ru_maxrss / 1024.0
        res["cpu_rusage"] = usage.ru_utime + usage.ru_stime
    return res


def _baseline_tree() -> Path | None:
    """The package as of BASE_COMMIT, extracted once (None outside a git checkout)."""
    if (BASELINE / "globeview" / "terrain" / "ingest.py").exists():
        return BASELINE
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        return None
    tmp = Path(tempfile.mkdtemp(prefix="baseline-", dir=CACHE))
    try:
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", BASE_COMMIT, "globeview"],
            capture_output=True,
            check=False,
        )
        if archive.returncode != 0:
            return None
        subprocess.run(["tar", "-x", "-C", str(tmp)], input=archive.stdout, check=True)
        tmp.rename(BASELINE)  # atomic: a half-extracted tree is never taken for the baseline
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return BASELINE


def _source(size: int) -> Path:
    """The N x N benchmark DEM (generated once, in a child: a forked child's ru_maxrss starts at
    its parent's RSS, so the parent stays small)."""
    path = CACHE / f"big_dem_{size}.tif"
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        gen = subprocess.run(
            [sys.executable, str(ROOT / "benchmarks" / "make_big_dem.py"), "--size", str(size)],
            capture_output=True,
            text=True,
        )
        if gen.returncode != 0 or not path.exists():
            last = (gen.stderr.strip().splitlines() or ["no message"])[-1]
            raise BenchError(f"cannot make the {size}x{size} benchmark DEM: {last}")
    return path


def _du_mb(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) / 1e6


def _store_facts(store: Path) -> dict[str, float]:
    """Levels, tiles and chunks of a built store (format 7), from its manifest's level records
    through the store's reader (`TileStore.manifest`); nodes_fine counts the finest level's
    tiles with data, 2^(2 tile_n) nodes each (shared edges once)."""
    from globeview.terrain.store.tile_store import TileStore

    with TileStore.open(store) as st:
        m = st.manifest
    fine = m.levels[-1]
    n = 1 << m.tile_n
    return {
        "format": m.header.format_version,
        "max_level": m.max_level,
        "tile_n": m.tile_n,
        "tiles_fine": fine.tiles,
        "tiles": sum(lv.tiles for lv in m.levels),
        "nodes_fine": fine.tiles * n * n,
        "chunks": sum(lv.chunks for lv in m.levels),
        "chunks_fine": fine.chunks,
        "mb": _du_mb(store),
    }


#: A store's per-tile figures by level: {(x, y): (error, hmin, hmax, *stride errors)} for the
#: tiles with data (metres; NaN as None), rounded as store format 7's shards keep them (errors
#: float16 rounded up, heights float32 rounded outward), so that stores of two formats compare.
TileTable = list[dict[tuple[int, int], tuple[float | None, ...]]]


def _facts(error: float, hmin: float, hmax: float, strides: list[float]) -> tuple:
    from globeview.terrain.store.shards import f16_up, f32_down, f32_up

    e = f16_up(np.asarray([error, *strides], dtype=np.float64)).astype(np.float64)
    hs = (f32_down(np.float64(hmin)), f32_up(np.float64(hmax)))
    vals = [float(e[0]), *(float(h) for h in hs), *(float(v) for v in e[1:])]
    return tuple(None if v != v else v for v in vals)


def _tile_table(store: Path) -> TileTable:
    """The per-tile figures of a store: format 7's through its shards (`TileStore.iter_chunks`);
    an older format's (the frozen baseline commit writes one) from its manifest's arrays."""
    m = json.loads((store / "manifest.json").read_text())
    if int(m.get("format_version", 0)) < 7:
        return _tile_table_arrays(m)
    from globeview.terrain.store.tile_store import TileStore

    with TileStore.open(store) as st:
        k = st.manifest.chunk_tiles
        table: TileTable = [{} for _ in range(st.max_level + 1)]
        for lv, cy, cx, f in st.iter_chunks():
            for j, i in zip(*np.nonzero(np.isfinite(f.hmin))):
                e = f.errors[j, i].astype(np.float64)
                table[lv][(cx * k + int(i), cy * k + int(j))] = _facts(
                    e[0], f.hmin[j, i], f.hmax[j, i], list(e[1:])
                )
    return table


def _tile_table_arrays(m: dict) -> TileTable:
    """`_tile_table` of a store of format 4..6: per-level extents and per-tile arrays."""
    table: TileTable = []
    for lv, rec in enumerate(m["levels"]):
        ext = rec["extent"]
        x0, y0, nx, ny = (int(ext[key]) for key in ("x0", "y0", "nx", "ny"))
        level: dict[tuple[int, int], tuple[float | None, ...]] = {}
        for r in range(ny):
            for c in range(nx):
                hmin = rec["hmin"][r][c]
                if hmin is None or hmin != hmin:
                    continue
                level[((x0 + c) % (2 << lv), y0 + r)] = _facts(
                    rec["error"][r][c], hmin, rec["hmax"][r][c], rec["stride_error"][r][c]
                )
        table.append(level)
    return table


def _same_errors(a: Path, b: Path) -> bool:
    """Whether two stores hold the same per-tile errors and height ranges (`_tile_table`)."""
    return _tile_table(a) == _tile_table(b)


def _differing_tiles(a: Path, b: Path) -> tuple[int, int] | None:
    """(tiles whose figures differ or that only one store has data for, how many of them are
    inside the data: all 8 neighbours with data in both stores) between two stores of one
    source, or None when their pyramids differ (a different number of levels). The tiles
    with a neighbour without data are where a DEM's data ends: the tiles issue #29's
    data-edge fix (store format 6) changed on purpose."""
    ta, tb = _tile_table(a), _tile_table(b)
    if len(ta) != len(tb):
        return None
    differ = inside = 0
    for lv, (x, y) in enumerate(zip(ta, tb)):
        ncols, nrows = 2 << lv, 1 << lv
        for tx, ty in x.keys() | y.keys():
            if x.get((tx, ty)) == y.get((tx, ty)):
                continue
            differ += 1
            around = [
                ((tx + dx) % ncols, ty + dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dx or dy)
            ]
            inside += all(0 <= t[1] < nrows and t in x and t in y for t in around)
    return differ, inside


def _baseline_verdict(base: Path, ref: Path, ref_name: str) -> str:
    """How the frozen baseline's store compares with this checkout's: equal, different at the
    data edges only (by design since store format 6, issue #29), or different inside too."""
    what = f"commit {BASE_COMMIT}'s store (today) against {ref_name}'s"
    if _same_errors(base, ref):
        return f"{what}: per-tile errors and height ranges equal"
    tiles = _differing_tiles(base, ref)
    if tiles is None:
        return f"{what}: a different pyramid (levels or extents)"
    differ, inside = tiles
    if not inside:
        return (
            f"{what}: differs at the data edges only ({differ} tiles where the data ends), "
            f"by design since store format 6 (issue #29)"
        )
    # Since issue #25 the resampling kernel's scale is the same for every window (the grids'
    # own), where the baseline's GDAL narrowed it in windows reaching past the DEM's end:
    # heights there moved inside the data too (module docstring of terrain/dem/resample.py).
    return (
        f"{what}: differs at {differ} tiles, {inside} of them inside the data, not only at the "
        f"data edges of store format 6 (issue #29): by design since issue #25 where a window "
        f"reached past the DEM (one kernel scale for every window)"
    )


def _one_line_parser() -> argparse.ArgumentParser:
    class Parser(argparse.ArgumentParser):
        def error(self, message: str):  # type: ignore[override]
            raise BenchError(message)

    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="4096,8192", help="raster sizes N (N x N), comma separated")
    ap.add_argument("--rounds", type=int, default=1, help="runs of each row (medians)")
    ap.add_argument("--skip", default="", help=f"rows to leave out, of {','.join(RUNS)}")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--api", action="store_true", help=argparse.SUPPRESS)
    return ap


def _parse(argv: list[str] | None) -> argparse.Namespace:
    args = _one_line_parser().parse_args(argv)
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    except ValueError:
        raise BenchError(
            f"--sizes must be integers separated by commas, not {args.sizes!r}"
        ) from None
    if not sizes or any(not (SIZE_RANGE[0] <= s <= SIZE_RANGE[1]) for s in sizes):
        raise BenchError(f"--sizes must each be in {SIZE_RANGE[0]}..{SIZE_RANGE[1]}: {args.sizes}")
    args.sizes = sizes
    if not (1 <= args.rounds <= 20):
        raise BenchError(f"--rounds must be in 1..20, got {args.rounds}")
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    bad = skip - set(RUNS)
    if bad:
        raise BenchError(f"--skip takes {','.join(RUNS)}, not {sorted(bad)[0]!r}")
    args.skip = skip
    return args


def _header() -> str:
    cpu = platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(
                (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu
            )
    except OSError:
        pass
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    return (
        f"Ingest benchmark, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {cpu}, "
        f"{os.cpu_count()} cores, load {load}"
    )


def _medians(runs: list[dict]) -> dict:
    """Medians over the runs of one row (peak RSS: the largest)."""
    out = {k: statistics.median(r[k] for r in runs) for k in runs[0] if k != "rss"}
    out["rss"] = max(r["rss"] for r in runs)
    if "worker_rss" in runs[0]:
        out["worker_rss"] = max(r["worker_rss"] for r in runs)
    return out


def bench_size(size: int, args: argparse.Namespace, api: list[str], tmp: Path) -> dict:
    """Every row for one raster size; prints its table; returns the figures by row."""
    src = _source(size)
    mb = src.stat().st_size / 1e6
    cores = os.cpu_count() or 1
    has_dask = "workers" in api and "scheduler" in api
    print(f"\n### {size}x{size} float32, {mb:.0f} MB (SRTM3 N44W072 + SYNTHETIC fractal detail)\n")
    print("| run | wall s | CPU s | cores busy | MB/s | peak RSS MB a worker process | store MB |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    rows: dict[str, dict] = {}
    stores: dict[str, Path] = {}
    notes: list[str] = []

    plan: list[tuple[str, str, dict, dict[str, str] | None, int]] = []

    def row(
        name: str, label: str, spec: dict, env: dict[str, str] | None = None, threads: int = 1
    ) -> None:
        if name not in args.skip:
            plan.append((name, label, spec, env, threads))

    if "today" not in args.skip:
        base = _baseline_tree()
        if base is None:
            notes.append(f"today (commit {BASE_COMMIT}): skipped, not in a git checkout")
        else:
            env = {**os.environ, "PYTHONPATH": str(base), "GLOBEVIEW_DATA_DIR": str(ROOT / "data")}
            row("today", f"today (commit {BASE_COMMIT}, serial)", {"kind": "ingest"}, env)
    if has_dask:
        row("dask1", "Dask, 1 worker", {"kind": "ingest", "kwargs": {"workers": 1}})
        row(
            "daskN",
            f"Dask, {cores} workers (threads)",
            {"kind": "ingest", "kwargs": {"workers": cores}},
            threads=cores,
        )
        # Dask's local process pool: the same graph without the GIL shared between workers.
        row(
            "daskP",
            f"Dask, {cores} workers (processes)",
            {"kind": "ingest", "kwargs": {"workers": cores, "scheduler": "processes"}},
        )
        row("cluster", "LocalCluster 2 processes x 1 thread", {"kind": "cluster"})
    else:
        # Until the Dask API lands: the checkout's own ingest, once, so the script still runs.
        row("dask1", "this checkout (no workers= yet)", {"kind": "ingest"})
        notes.append("ingest() takes no workers=/scheduler= yet: Dask and cluster rows skipped")
    copy = tmp / f"ovr_copy_{size}.tif"
    row("gdal", "GDAL overviews (build_overviews average)", {"kind": "gdal"})

    # Rounds interleaved (every row once, then again): the machine's load drifts in minutes.
    runs: dict[str, list[dict]] = {name: [] for name, *_ in plan}
    failed: dict[str, str] = {}
    for _ in range(args.rounds):
        for name, label, spec, env, _threads in plan:
            if name in failed:
                continue
            out = tmp / f"store_{name}_{size}"
            if name == "gdal":  # a fresh copy each time: the build writes into the file
                shutil.copy(src, copy)
                spec = {**spec, "src": str(copy), "out": ""}
            else:
                shutil.rmtree(out, ignore_errors=True)
                spec = {**spec, "src": str(src), "out": str(out)}
            try:
                runs[name].append(_wait_child(spec, env))
            except RuntimeError as exc:
                failed[name] = f"{label}: {exc}"
            finally:
                copy.unlink(missing_ok=True)
                Path(str(copy) + ".ovr").unlink(missing_ok=True)
    notes.extend(failed.values())
    for name, label, _spec, _env, threads in plan:
        if name in failed or not runs[name]:
            continue
        r = _medians(runs[name])
        rss = r.get("worker_rss", r["rss"])
        out = tmp / f"store_{name}_{size}"
        store_mb = _du_mb(out) if name != "gdal" and out.exists() else float("nan")
        rows[name] = {**r, "rss_worker": rss, "store_mb": store_mb}
        if name != "gdal" and out.exists():
            stores[name] = out
        # Threads of one process share its RSS: the figure is the process's, for all of them.
        shared = f" ({threads} threads)" if threads > 1 else ""
        digits = 2 if name == "gdal" else 1
        print(
            f"| {label} | {r['wall']:.{digits}f} | {r['cpu']:.{digits}f} | "
            f"{r['cpu'] / r['wall']:.2f} | {mb / r['wall']:.3g} | {rss:.0f}{shared} | "
            + ("- |" if name == "gdal" else f"{store_mb:.0f} |"),
            flush=True,
        )
    if "cluster" in rows:
        notes.append(
            f"cluster: {rows['cluster']['start']:.1f} s to start it (not in its wall time); "
            "CPU = the client's + both workers' getrusage deltas; RSS = the largest worker "
            f"(the client + scheduler process: {rows['cluster']['client_rss']:.0f} MB)"
        )
    print()
    for n in notes:
        print(f"- {n}")
    # This checkout's stores (every row but today's and GDAL's) must be the same whatever
    # the scheduler: one is the reference, any other that differs is a DIFFER. The baseline
    # commit's store is compared with it for information only: issue #29 (store format 6)
    # changed the tiles at a DEM's data edges on purpose.
    ours = [k for k in stores if k != "today"]
    ref = ours[0] if ours else None  # the baseline's store alone: an older format
    if ref is not None:
        facts = _store_facts(stores[ref])
        rows["facts"] = facts
        same = [k for k in ours if k != ref and _same_errors(stores[ref], stores[k])]
        differ = [k for k in ours if k != ref and k not in same]
        if same or differ:
            print(
                f"- per-tile errors and height ranges equal to {ref}'s: "
                f"{', '.join(same) or 'none'}"
                + (f"; DIFFER: {', '.join(differ)}" if differ else "")
            )
        if "today" in stores and ref != "today":
            print(f"- {_baseline_verdict(stores['today'], stores[ref], ref)}")
        print(
            f"- pyramid: levels 0..{facts['max_level']}, tiles of {(1 << facts['tile_n']) + 1}^2 "
            f"nodes; finest level {facts['tiles_fine']} tiles, {facts['nodes_fine'] / 1e6:.1f} M "
            f"nodes; {facts['tiles']} tiles in all; {facts['chunks']} chunk files "
            f"({facts['chunks_fine']} at the finest); store "
            f"{facts['mb'] * 1e6 / facts['nodes_fine']:.2f} bytes a finest-level node "
            f"({facts['mb'] * 1e6 / (4 * facts['nodes_fine']):.2f} of float32)"
        )
        costs = [
            f"{k} {r['cpu'] / facts['nodes_fine'] * 1e9:.0f} ns / "
            f"{r['cpu'] / facts['tiles'] * 1e3:.2f} ms / {r['cpu'] / facts['chunks']:.2f} s"
            for k, r in rows.items()
            if k in ("today", "dask1", "daskN", "daskP", "cluster")
        ]
        what = "finest-level node / tile / chunk file"
        print(f"- CPU a {what} (every level's work counted): {'; '.join(costs)}")
    for p in stores.values():
        shutil.rmtree(p, ignore_errors=True)
    return rows


def _verdict(ok: bool | None) -> str:
    return "not measured" if ok is None else ("met" if ok else "NOT MET")


def main(argv: list[str] | None = None) -> int:
    try:
        args = _parse(argv)
        if args.child is not None:
            _child(json.loads(args.child))
            return 0
        if args.api:
            _api_child()
            return 0
        # SIGTERM as an exception, so the child under way is ended too (_wait_child).
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
        if not (ROOT / "globeview").is_dir():
            raise BenchError("run from a source checkout (benchmarks/ beside globeview/)")
        print(_header())
        print(
            f"Targets (issue #18): Dask ingest on all cores <= {RATIO_TARGET:g}x GDAL's overview "
            f"time; peak RSS per worker <= {RSS_TARGET_MB:.0f} MB at every size; speedup 1 -> "
            f"N cores >= {SCALING_TARGET:g} N"
        )
        api = _api()
        CACHE.mkdir(parents=True, exist_ok=True)
        results: dict[int, dict] = {}
        with tempfile.TemporaryDirectory(prefix="bench-ingest-", dir=CACHE) as tmp:
            for size in args.sizes:
                results[size] = bench_size(size, args, api, Path(tmp))
        _targets(results)
        return 0
    except BenchError as exc:
        print(f"bench_ingest: error: {exc}", file=sys.stderr)
        return 2


def _api() -> list[str]:
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "--api"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if proc.returncode or line is None:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise BenchError(f"cannot import globeview's ingest: {last}")
    return list(json.loads(line[len("RESULT ") :]))


def _targets(results: dict[int, dict]) -> None:
    cores = os.cpu_count() or 1
    print("\nTargets")
    print()
    for size, rows in results.items():
        gdal, dask_n, dask_1, today = (rows.get(k) for k in ("gdal", "daskN", "dask1", "today"))
        parts = [f"- {size}^2:"]
        if gdal and today:
            parts.append(f"today / GDAL = {today['wall'] / gdal['wall']:.1f}x;")
        if gdal and dask_n:
            ratio = dask_n["wall"] / gdal["wall"]
            parts.append(
                f"Dask {cores} cores / GDAL = {ratio:.1f}x (<= {RATIO_TARGET:g}x: "
                f"{_verdict(ratio <= RATIO_TARGET)});"
            )
        if dask_1 and dask_n:
            speedup = dask_1["wall"] / dask_n["wall"]
            cpu_ratio = dask_n["cpu"] / dask_1["cpu"]
            parts.append(
                f"speedup 1 -> {cores} cores {speedup:.2f}x wall, CPU {cpu_ratio:.2f}x "
                f"of 1 core's (>= {SCALING_TARGET * cores:.1f}x: "
                f"{_verdict(speedup >= SCALING_TARGET * cores)});"
            )
        dask_p = rows.get("daskP")
        if dask_1 and dask_p:
            sp = dask_1["wall"] / dask_p["wall"]
            ratio_p = dask_p["wall"] / gdal["wall"] if gdal else float("nan")
            parts.append(
                f"with processes: speedup {sp:.2f}x "
                f"({_verdict(sp >= SCALING_TARGET * cores)}), / GDAL = {ratio_p:.1f}x "
                f"({_verdict(ratio_p <= RATIO_TARGET) if gdal else 'not measured'});"
            )
        if today and dask_n:
            parts.append(
                f"today's wall / Dask {cores} cores' = {today['wall'] / dask_n['wall']:.2f}"
            )
        print(" ".join(parts))
    # A worker is a process of one thread (Dask 1 worker, each cluster worker); the threaded
    # scheduler's N workers share one process, whose RSS is shown beside (per thread it is
    # less, but it is not one worker's).
    worst = [
        (r["rss_worker"], f"{size}^2 {k}")
        for size, rows in results.items()
        for k, r in rows.items()
        if k in ("dask1", "cluster")
    ]
    shared = [
        f"{r['rss_worker']:.0f} MB at {size}^2"
        for size, rows in results.items()
        for k, r in rows.items()
        if k == "daskN"
    ]
    if worst:
        mb, where = max(worst)
        print(
            f"- peak RSS per worker (a process of 1 thread): at most {mb:.0f} MB ({where}) "
            f"(<= {RSS_TARGET_MB:.0f} MB at every size: {_verdict(mb <= RSS_TARGET_MB)})"
            + (f"; the {cores}-thread process: {', '.join(shared)}" if shared else "")
        )


if __name__ == "__main__":
    raise SystemExit(main())
