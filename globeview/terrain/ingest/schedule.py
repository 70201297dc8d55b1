"""The ingest as a Dask task graph, and running it on a local or a distributed scheduler.

The graph (see `tasks` for what each task does):

- ``pole``: the pole heights (the mean of the finest level's pole rows); only the chunks
  holding a pole row depend on it.
- ``chunk-L-CY-CX`` for every chunk of every level: level L's window (cy, cx), computed from
  the sources (finest level) or from the wavelet approximation of level L+1 (so it depends
  on the level-(L+1) chunks its window reads, halo included, and on nothing else); on a level
  that goes all the way round, the last chunk of a row also depends on the row's first chunk
  (whose first node column is its east edge: lon 180 = lon -180), deterministically.
- ``error-L-CY-CX`` for every chunk of levels 1..L_max: the exact tile errors of every
  coarser level against level L's nodes there; it depends on the chunks it reads and on the
  level-(L+1) chunks that say where finer data takes over.

Every task returns a few KB (per-tile statistics); the bulk goes through the chunk files in
the building folder, so a task's memory is bounded by one chunk and the same graph runs on a
cluster whose workers share that folder. The driver (`globeview.terrain.ingest.driver`) folds the
results, writes the level VRTs and the manifest, and commits.

An incremental update (`update`) runs the same graph with the results of the tasks
that the changed sources do not reach supplied as data (`Graph.keep`).

Schedulers: threads (dask's local threaded scheduler, our own pool so that a failure can
wait for every task in flight before the building folder is removed), processes (dask's
multiprocessing scheduler over a spawned process pool), or an existing ``dask.distributed``
scheduler at tcp://HOST:PORT (futures, `as_completed` for progress), asked for its
identity first with a hard deadline (`probe_scheduler`). On each, the graph runs in waves
(`stages`: the pole, each level's chunks, the error windows), so dask orders one flat wave at
a time, never the whole pyramid.
"""

from __future__ import annotations

import os
import re
import threading
import time
from collections.abc import Callable, Hashable, Sequence
from collections.abc import Set as AbstractSet
from concurrent.futures import Executor, ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from globeview.errors import StoreError
from globeview.terrain.ingest.memory import run_task
from globeview.terrain.ingest.tasks import (
    BuildPlan,
    SourceSpec,
    chunk_task,
    error_task,
    pole_task,
)
from globeview.terrain.store.layout import EXTRA_COL, EXTRA_ROW

__all__ = [
    "CONNECT_TIMEOUT_S",
    "Graph",
    "SchedulerChoice",
    "build_graph",
    "parse_scheduler",
    "probe_scheduler",
    "run_graph",
]

#: Most local workers (the CLI's bound too): each thread may hold a chunk task's arrays.
MAX_WORKERS = 4096
#: How long to wait for a dask.distributed scheduler to answer before giving up (seconds).
CONNECT_TIMEOUT_S = 5.0
#: How long a failed distributed build waits for the tasks still running on the workers to
#: finish (they cannot be interrupted) before the building folder is removed (seconds).
DRAIN_TIMEOUT_S = 120.0

_ADDRESS = re.compile(r"^(tcp|tls)://[^\s/]+:\d{1,5}/?$")


@dataclass(frozen=True)
class SchedulerChoice:
    """Where the graph runs: kind "threads" | "processes" | "distributed" (at ``address``),
    with ``workers`` local workers (threads or processes; unused on a cluster)."""

    kind: str
    workers: int
    address: str | None = None


# Local default: threads, not processes. Measured on benchmarks/cache/big_dem_8192.tif
# (8192^2 float32, 15 levels, 61 chunk + 60 error tasks) on this 2-core machine shared with
# five other sessions, 3 interleaved rounds each, medians (22:43 UTC, load 2.9-3.7): 1 thread
# 12.0 s wall / 12.0 s CPU; 2 threads 10.5 s / 13.0 s / 368 MB; 2 spawned processes 10.9 s /
# 13.4 s / 327 MB each (+ interpreter start and imports per process: a small DEM ingests in
# 0.6 s on threads, 2.8 s on processes). At load 4-6.6 (earlier): 2 threads 23.4 s, 2
# processes 32.6 s. The tasks spend their time in GDAL (warp, deflate, inflate), which
# releases the GIL (a thread polling every 1 ms during a 400 ms warp, a chunk write or read
# waited at most 4-8 ms), and large numpy operations, so threads share one process's imports
# and GDAL cache at no loss.
DEFAULT_LOCAL = "threads"


def parse_scheduler(workers: object, scheduler: object) -> SchedulerChoice:
    """Check ``workers`` / ``scheduler`` (StoreError, one line) and say where to run.

    workers: None (every core, os.cpu_count()) or an int >= 1. scheduler: None (dask's local
    scheduler, `DEFAULT_LOCAL`), "threads", "processes", or "tcp://HOST:PORT" (an existing
    dask.distributed scheduler; the store folder must be on a filesystem its workers share).
    """
    if workers is None:
        n = os.cpu_count() or 1
    elif isinstance(workers, bool) or not isinstance(workers, int):
        raise StoreError(f"--workers must be a whole number >= 1, got {str(workers)[:40]!r}")
    elif workers < 1:
        raise StoreError(f"--workers must be >= 1, got {workers}")
    elif workers > MAX_WORKERS:
        raise StoreError(f"--workers must be in 1..{MAX_WORKERS}, got {workers}")
    else:
        n = workers
    if scheduler is None:
        return SchedulerChoice(DEFAULT_LOCAL, n)
    if not isinstance(scheduler, str):
        raise StoreError(f"--scheduler must be tcp://HOST:PORT, got {str(scheduler)[:60]!r}")
    text = scheduler.strip()
    if text in ("threads", "processes"):
        return SchedulerChoice(text, n)
    if _ADDRESS.match(text):
        port = int(text.rstrip("/").rsplit(":", 1)[1])
        if not 0 < port < 65536:
            raise StoreError(f"--scheduler {text[:60]}: port {port} is out of range")
        return SchedulerChoice("distributed", n, text.rstrip("/"))
    raise StoreError(
        f"--scheduler must be tcp://HOST:PORT (a dask.distributed scheduler), got {text[:60]!r}"
    )


# ---------------------------------------------------------------------------------------------
# The graph


@dataclass
class Graph:
    """A dask graph (a dict of legacy task tuples) and its keys by kind.

    deps: the chunk keys each chunk or error task depends on (and "pole"); known: results
    supplied instead of computed (an incremental update's unaffected chunks and error
    windows), see `keep`.
    """

    dsk: dict[Hashable, Any]
    chunk_keys: list[str]  # in the serial order: levels finest first, chunks row-major
    error_keys: list[str]
    deps: dict[str, list[str]] = field(default_factory=dict)
    known: dict[str, Any] = field(default_factory=dict)

    @property
    def keys(self) -> list[str]:
        """Every task to run: the pole, the chunks, the errors (less the `known` ones)."""
        return [k for k in ("pole", *self.chunk_keys, *self.error_keys) if k not in self.known]

    @property
    def tasks(self) -> int:
        """Chunk and error tasks to run (what progress counts)."""
        return len(self.keys) - ("pole" not in self.known)

    def keep(self, known: dict[str, Any]) -> None:
        """Use these results instead of running their tasks (chunk results stay in the graph
        as data for the tasks that depend on them; error windows simply drop out)."""
        self.known.update(known)
        for key, value in known.items():
            if key in self.dsk:
                if key.startswith("error-"):
                    del self.dsk[key]
                else:
                    self.dsk[key] = value


def _chunk_key(lv: int, cy: int, cx: int) -> str:
    return f"chunk-{lv}-{cy}-{cx}"


def _chunks_of_rows(rr: np.ndarray, c: int, n: int) -> np.ndarray:
    """Chunk indices (sorted, unique) holding raster rows/columns ``rr`` (-1 = outside)."""
    rr = rr[rr >= 0]
    return np.unique(np.minimum(rr // c, n - 1))


def _level_chunks(
    plan: BuildPlan, lv: int, gr: np.ndarray, gc: np.ndarray, planned: AbstractSet[tuple[int, int]]
) -> list[tuple[int, int]]:
    """The planned chunks of level lv holding any node of rows ``gr`` x columns ``gc``
    (global, unwrapped node indices, as `levels.read_level_nodes` reads them)."""
    g = plan.grids[lv]
    rows, cols = plan.chunk_shape(lv)
    cys = _chunks_of_rows(g.raster_rows(gr), plan.chunk_nodes, rows)
    cxs = _chunks_of_rows(g.raster_cols(gc), plan.chunk_nodes, cols)
    return [(int(a), int(b)) for a in cys for b in cxs if (int(a), int(b)) in planned]


def build_graph(
    plan: BuildPlan,
    sources: Sequence[SourceSpec],
    planned: Sequence[AbstractSet[tuple[int, int]]],
) -> Graph:
    """The ingest graph of a planned build (see the module docstring): tasks only for the
    chunks ``planned[level]`` ((cy, cx) of the global chunk grid, `store.layout`); every
    other chunk has no data."""
    dsk: dict[Hashable, Any] = {"plan": plan, "sources": tuple(sources)}
    # Each task through `memory.run_task`: freed temporaries go back to the system, so a
    # worker's RSS does not grow with the number of tasks it has run.
    dsk["pole"] = (run_task, pole_task, "plan", "sources")
    chunk_keys: list[str] = []
    deps_of: dict[str, list[str]] = {}
    write_no = 0
    hl = plan.halo
    for lv in range(plan.max_level, -1, -1):
        grid = plan.grids[lv]
        s_n = grid.tile_nodes
        _, cols = plan.chunk_shape(lv)
        for cy, cx in sorted(planned[lv]):
            by, bx, kty, ktx = plan.window(lv, cy, cx)
            h, w = kty * s_n + 1, ktx * s_n + 1
            gr0, gc0 = grid.gr0 + by * s_n, grid.gc0 + bx * s_n
            fine: list[str] = []
            if lv < plan.max_level:
                fine = [
                    _chunk_key(lv + 1, a, b)
                    for a, b in _level_chunks(
                        plan,
                        lv + 1,
                        2 * gr0 - hl + np.arange(2 * h - 1 + 2 * hl),
                        2 * gc0 - hl + np.arange(2 * w - 1 + 2 * hl),
                        planned[lv + 1],
                    )
                ]
            south_row = grid.nrows * s_n - gr0
            pole = "pole" if gr0 == 0 or 0 <= south_row < h else None
            first = None
            if grid.global_lon and cx == cols - 1 and cx > 0 and (cy, 0) in planned[lv]:
                first = _chunk_key(lv, cy, 0)
            write_no += 1
            key = _chunk_key(lv, cy, cx)
            # A chunk whose neighbour below / east is not planned (no data) stores its
            # closing row / column too (`layout.chunk_window`).
            extra = (EXTRA_ROW if (cy + 1, cx) not in planned[lv] else 0) | (
                EXTRA_COL if (cy, cx + 1) not in planned[lv] else 0
            )
            dsk[key] = (
                run_task,
                chunk_task,
                "plan",
                "sources",
                lv,
                cy,
                cx,
                write_no,
                pole,
                fine,
                first,
                extra,
            )
            chunk_keys.append(key)
            deps_of[key] = [*fine, *([first] if first else []), *([pole] if pole else [])]
    error_keys: list[str] = []
    for lf in range(plan.max_level, 0, -1):
        gf = plan.grids[lf]
        s_n = gf.tile_nodes
        for cy, cx in sorted(planned[lf]):
            by, bx, kty, ktx = plan.window(lf, cy, cx)
            h, w = kty * s_n + 1, ktx * s_n + 1
            gr0, gc0 = gf.gr0 + by * s_n, gf.gc0 + bx * s_n
            deps = {
                _chunk_key(lf, a, b)
                for a, b in _level_chunks(
                    plan, lf, gr0 + np.arange(h), gc0 + np.arange(w), planned[lf]
                )
            }
            if lf < plan.max_level:
                block = s_n // 2
                ty = gr0 // block + np.arange((h - 1) // block)
                tx = gc0 // block + np.arange((w - 1) // block)
                g1 = plan.grids[lf + 1]
                iy, ix, inside = g1.tile_slots(ty[:, None], tx[None, :])
                iy, ix, inside = np.broadcast_arrays(iy, ix, inside)
                pairs = np.unique(
                    np.stack([iy[inside] // plan.k, ix[inside] // plan.k], axis=1), axis=0
                )
                deps |= {
                    _chunk_key(lf + 1, int(a), int(b))
                    for a, b in pairs
                    if (int(a), int(b)) in planned[lf + 1]
                }
            for lv in range(lf):
                f = 1 << (lf - lv)
                r0, c0 = gr0 // f, gc0 // f
                r1, c1 = -(-(gr0 + h - 1) // f), -(-(gc0 + w - 1) // f)
                deps |= {
                    _chunk_key(lv, a, b)
                    for a, b in _level_chunks(
                        plan,
                        lv,
                        r0 + np.arange(r1 - r0 + 1),
                        c0 + np.arange(c1 - c0 + 1),
                        planned[lv],
                    )
                }
            key = f"error-{lf}-{cy}-{cx}"
            dsk[key] = (run_task, error_task, "plan", lf, cy, cx, sorted(deps))
            error_keys.append(key)
            deps_of[key] = sorted(deps)
    return Graph(dsk, chunk_keys, error_keys, deps_of)


# ---------------------------------------------------------------------------------------------
# Running it


def stages(graph: Graph) -> list[list[str]]:
    """The tasks to run in waves, each depending only on earlier waves and on its own tasks:
    the pole, each level's chunks (finest first; a level going all the way round has its
    rows' last chunks depend on their first), then every error window.

    Why waves, not the one graph: dask orders a graph before running it (`dask.order`, on the
    local schedulers and on a distributed scheduler alike), and on the whole pyramid that
    costs memory and CPU superlinear in the chunks (it tracks, per task, the root tasks it
    connects to: a coarse chunk connects to every finest chunk under it, an error window to
    all its coarser chunks). Measured on the 2 000-tile synthetic world (6 188 chunks, 14 480
    tasks): the ordering alone had grown the process by 1.1 GB at 1.1 GB/CPU-minute when it
    was stopped (docs/scale.md). A wave is flat (its tasks read earlier waves' results as
    data), so ordering it is cheap; the waves cost a pool's drain per level (13 for SRTM 3")."""
    todo = set(graph.keys)
    waves: list[list[str]] = [["pole"]] if "pole" in todo else []
    level: str | None = None
    for key in graph.chunk_keys:  # finest level first
        if key not in todo:
            continue
        lv = key.split("-", 2)[1]
        if lv != level:
            waves.append([])
            level = lv
        waves[-1].append(key)
    errors = [k for k in graph.error_keys if k in todo]
    if errors:
        waves.append(errors)
    return waves


def _wave_graph(graph: Graph, wave: Sequence[str], results: dict[str, Any]) -> dict[Hashable, Any]:
    """The graph of one wave: its tasks, the plan and the sources, and the results of the
    earlier waves its tasks read, as data."""
    dsk: dict[Hashable, Any] = {"plan": graph.dsk["plan"], "sources": graph.dsk["sources"]}
    inside = set(wave)
    for key in wave:
        dsk[key] = graph.dsk[key]
        for dep in graph.deps.get(key, ()):
            if dep not in inside:
                dsk[dep] = results[dep]
    return dsk


def run_graph(
    graph: Graph,
    where: SchedulerChoice,
    on_done: Callable[[str], None],
) -> dict[str, Any]:
    """Run every chunk and error task, wave by wave (`stages`); returns their results by
    key. ``on_done(key)`` is called in this thread after each task (progress; an exception
    it raises cancels the build). When this returns or raises, no task of the graph is
    running any more (a failed build may then remove the building folder safely)."""
    if where.kind == "distributed":
        return _run_distributed(graph, where, on_done)
    # dask's schedulers are imported when a graph runs (deferred: the window and the CLI's
    # other commands import this module and never run one).
    from dask.callbacks import Callback

    class _Progress(Callback):
        def _posttask(self, key, result, dsk, state, worker_id) -> None:
            if isinstance(key, str) and key.startswith(("chunk-", "error-")):
                on_done(key)

    pool: Executor
    if where.kind == "processes":
        import multiprocessing

        import dask.multiprocessing

        pool = ProcessPoolExecutor(where.workers, mp_context=multiprocessing.get_context("spawn"))
        get: Callable[..., Any] = dask.multiprocessing.get
    else:
        import dask.threaded

        pool = ThreadPoolExecutor(where.workers, thread_name_prefix="ingest")
        get = dask.threaded.get
    results: dict[str, Any] = dict(graph.known)
    ran: dict[str, Any] = {}
    try:
        for wave in stages(graph):
            # Explicit (not the global Callback.active): other dask work here unaffected.
            values = get(
                _wave_graph(graph, wave, results),
                wave,
                pool=pool,
                callbacks=(_Progress()._callback,),
            )
            done = dict(zip(wave, values))
            results.update(done)
            ran.update(done)
    finally:
        # Tasks still in flight finish (at most one per worker) and queued ones never start,
        # before the caller removes the building folder.
        pool.shutdown(wait=True, cancel_futures=True)
    return ran


def _run_distributed(
    graph: Graph, where: SchedulerChoice, on_done: Callable[[str], None]
) -> dict[str, Any]:
    # Deferred: dask.distributed takes about a second to import and only a cluster needs it.
    from distributed import Client

    address = where.address
    assert address is not None
    probe_scheduler(address)
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise StoreError(
            f"cannot reach the dask scheduler at {address} within {CONNECT_TIMEOUT_S:g} s "
            f"({type(exc).__name__})"
        ) from None
    results: dict[str, Any] = dict(graph.known)
    ran: dict[str, Any] = {}
    try:
        for wave in stages(graph):
            done = _run_wave(client, _wave_graph(graph, wave, results), wave, on_done, address)
            results.update(done)
            ran.update(done)
        return ran
    finally:
        client.close()


def _run_wave(
    client: Any,
    dsk: dict[Hashable, Any],
    keys: list[str],
    on_done: Callable[[str], None],
    address: str,
) -> dict[str, Any]:
    """One wave on the cluster: its results by key; a task that failed (a worker that died
    several times, a cancel) as one StoreError line, after `_drain`."""
    from distributed import as_completed
    from distributed.client import FutureCancelledError
    from distributed.scheduler import KilledWorker

    futures: list[Any] = []
    try:
        futures = client.get(dsk, keys, sync=False)
        by_key = {f.key: k for f, k in zip(futures, keys)}
        results: dict[str, Any] = {}
        for fut in as_completed(futures, loop=client.loop):
            if fut.status != "finished":
                try:
                    fut.result()
                except KilledWorker as exc:
                    raise StoreError(
                        f"a dask worker died running {by_key.get(fut.key, fut.key)} "
                        f"(several times): {str(exc).strip().splitlines()[0][:120]}"
                    ) from None
                except FutureCancelledError:
                    raise StoreError(
                        f"the dask cluster at {address} cancelled the ingest"
                    ) from None
            key = by_key[fut.key]
            results[key] = fut.result()
            on_done(key)
        return results
    finally:
        if futures:
            _drain(client, futures)


def probe_scheduler(address: str) -> None:
    """StoreError (one line) unless a dask.distributed *scheduler* answers at ``address``
    within CONNECT_TIMEOUT_S. `distributed.Client` alone waits forever on a port where
    something else accepts the connection and never answers (an HTTP server: measured), so
    its identity is asked first, on a private event loop with a hard deadline."""
    result: dict[str, Any] = {}

    async def ask() -> Any:
        from distributed.comm import connect  # deferred, as in _run_distributed

        comm = await connect(address, timeout=CONNECT_TIMEOUT_S)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    def run() -> None:
        import asyncio  # here: only a scheduler probe needs it (~0.08 s to import)

        try:
            result["reply"] = asyncio.run(asyncio.wait_for(ask(), CONNECT_TIMEOUT_S))
        except BaseException as exc:  # noqa: BLE001  reported below as one line
            result["error"] = exc

    t = threading.Thread(target=run, name="dask-probe", daemon=True)
    t.start()
    t.join(CONNECT_TIMEOUT_S + 2.0)
    reply = result.get("reply")
    what = f"cannot reach the dask scheduler at {address} within {CONNECT_TIMEOUT_S:g} s"
    if "error" in result or reply is None:
        err = result.get("error")
        raise StoreError(f"{what} ({type(err).__name__ if err else 'no answer'})")
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        raise StoreError(
            f"{address} is not a dask scheduler (it answers as {str(kind)[:40]}); give the "
            "scheduler's address"
        )


def _drain(client: Any, futures: list[Any]) -> None:
    """Cancel what has not run and wait (bounded) until none of our tasks is running on a
    worker, so no worker writes into a building folder about to be removed."""
    pending = [f for f in futures if f.status == "pending"]
    ours = {str(f.key) for f in futures}
    if pending:
        client.cancel(pending, force=True)
    deadline = time.monotonic() + DRAIN_TIMEOUT_S
    while time.monotonic() < deadline:
        try:
            busy = client.processing()
        except Exception:  # noqa: BLE001  a lost scheduler runs nothing of ours any more
            return
        if not any(str(k) in ours for keys in busy.values() for k in keys):
            return
        time.sleep(0.1)
