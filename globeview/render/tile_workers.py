"""Tile builds in worker processes: the background loader on every core (issue #27, item 2).

A tile's build is a few hundred numpy calls on 65 x 65 arrays: each holds the GIL for its
dispatch and releases it for microseconds of work, so build threads do not scale past one
core and slow the frames beside them (design/issue27.md 4.2: one builder thread alone 300
tiles/s, beside a busy main thread 72-80). Reading the stores (GDAL) does release the GIL,
but it is a small part of a build from a warm store. So the builds run in processes:

* `TerrainRecipe` is what a worker needs to open the same terrain (each layer's store
  folder or URL, its name, visibility and remote options; the stack's blend flag):
  picklable, taken from a live `TerrainStack`.
* `ProcessBuilder` keeps N worker processes (``forkserver``: never ``fork`` a process that
  holds a GL context and threads), each with its own stack and `TileBuilder`, and builds a
  batch of tiles in one of them: heights, meshes and texels in one vectorised pass
  (`tile_build.TileBuilder.ready`), written into slots of a shared-memory slab the window's
  process owns (`tile_slab`: only keys, centres and coast scales travel pickled), returned
  as `ReadyTile`s viewing their slots, which the render thread uploads as they are (a slot
  is free again once its tile is uploaded or dropped; with no slot free a batch travels
  pickled). The loader's threads (`tile_loader.TileLoader`) only hand batches over and
  wait, with the GIL released.
* Failures: a build that raises fails its call (the loader builds that batch again tile by
  tile, so only the bad tile fails and is retried later). A worker that dies (killed, out of
  memory) breaks the pool: the calls under way fail with `WorkerLost` (their slab slots are
  reused once every process of that pool is seen dead), and the next call starts a fresh
  pool. The slab is the window's: a killed worker leaves no shared memory behind.
  `shutdown` lets the workers send the batch under way (milliseconds) and kills those that
  do not end within a second, so a hung build never holds up a closing window, and unlinks
  the slab.

Units: tile keys (level, x, y); CPU times in seconds.
"""

from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from globeview.render.tile_build import ReadyTile, TileBuilder
from globeview.render.tile_slab import SlabSpec, TileSlab, write_tiles
from globeview.terrain.compose.stack import TerrainLayer, TerrainStack
from globeview.terrain.store.tile_store import TileStore

Key = tuple[int, int, int]

log = logging.getLogger("globeview.render")


class WorkerLost(RuntimeError):
    """A tile worker process ended during a build (its tiles were not built)."""


class WorkerStartError(RuntimeError):
    """A tile worker process could not open the terrain from its recipe (the message says
    why, in one line)."""


@dataclass(frozen=True)
class LayerRecipe:
    """One layer of a `TerrainRecipe`: ``location`` its store folder or URL, ``options`` the
    remote store's `RemoteOptions` (None: local)."""

    location: str
    name: str
    visible: bool
    options: object | None = None


@dataclass(frozen=True)
class TerrainRecipe:
    """What a worker process needs to open the terrain a `TerrainStack` composes."""

    layers: tuple[LayerRecipe, ...]
    blend: bool
    cache_tiles: int
    tile_size: int = 65

    @classmethod
    def of(cls, stack: TerrainStack) -> TerrainRecipe:
        """The recipe of ``stack`` as it is now (its layers in order, visible or not)."""
        layers = []
        for ly in stack.layers:
            st = ly.store
            files = getattr(st, "_files", None)
            remote = st.url is not None
            # The URL of a store read over HTTP; else its folder or what its backend opens.
            where = st.url if st.url is not None else str(getattr(st, "location", st.path))
            layers.append(
                LayerRecipe(
                    location=where,
                    name=ly.name,
                    visible=ly.visible,
                    options=getattr(files, "options", None) if remote else None,
                )
            )
        return cls(tuple(layers), bool(stack.blend), int(stack.cache_tiles), int(stack.tile_size))

    def open(self) -> TerrainStack:
        """The stack this recipe describes, its stores opened here."""
        layers = [
            TerrainLayer(
                TileStore.open(ly.location, remote_options=ly.options),
                ly.name,
                ly.visible,
            )
            for ly in self.layers
        ]
        return TerrainStack(layers, cache_tiles=self.cache_tiles, blend=self.blend)


# -- in the worker process -------------------------------------------------------------------
_builder: TileBuilder | None = None
_start_error: str | None = None


def _init_worker(recipe: TerrainRecipe) -> None:
    """Worker start: open the terrain once. A failure is kept (one line) and raised by each
    build as `WorkerStartError` (an initializer that raised would break the pool and print
    its traceback)."""
    global _builder, _start_error
    try:
        _builder = TileBuilder(recipe.open())
    except Exception as exc:  # noqa: BLE001  reported by every build, see above
        _start_error = f"{type(exc).__name__}: {exc}".splitlines()[0]


def _worker_builder() -> TileBuilder:
    if _builder is None:
        raise WorkerStartError(f"tile worker could not open the terrain: {_start_error}")
    return _builder


def _build_batch(keys: np.ndarray) -> dict[Key, ReadyTile]:
    """Upload-ready tiles of ``keys`` (N, 3), built in this worker."""
    return _worker_builder().ready(keys)


def _build_batch_shared(
    keys: np.ndarray, spec: SlabSpec, slots: list[int]
) -> list[tuple[Key, np.ndarray, float, np.ndarray | None]]:
    """`_build_batch` with the tiles' arrays written into ``slots`` of the slab ``spec``
    (one per key, in order); returns each tile's (key, centre, coast scale, block stats:
    ~2.5 KB pickled)."""
    ready = _worker_builder().ready(keys)  # a key given twice is built once
    write_tiles(spec, slots[: len(ready)], list(ready.values()))
    return [(k, t.center, t.coast_scale, t.blocks) for k, t in ready.items()]


def _warm_facts(keys: np.ndarray) -> None:
    """The per-tile metadata of ``keys`` (N, 3) (the stack's per-level tables warmed)."""
    _worker_builder().skirt_depths(keys)


def _ready_check() -> bool:
    """A no-op build: the worker has opened its terrain."""
    return _builder is not None


# -- in the window's process -----------------------------------------------------------------


def default_loader(cores: int | None = None) -> tuple[str, int]:
    """(kind, workers) of the background loader for a machine with ``cores`` (default: this
    one's): on up to 2 cores one thread (a process would compete with the render thread and
    a software rasteriser for them), else processes on all cores but two (the render thread
    and the GL driver keep theirs)."""
    n = (os.cpu_count() or 1) if cores is None else cores
    if n <= 2:
        return "thread", 1
    return "process", n - 2


class ProcessBuilder:
    """Builds batches of tiles in ``workers`` processes opened from ``recipe``.

    Thread-safe: the loader's threads call `build_many` / `build` at once, one batch each.
    ``fallback(keys) -> {key: ReadyTile}`` builds in this process instead where the workers
    cannot open the terrain (a store they cannot reach, a backend that cannot be reopened):
    logged once, then every build goes there; without one such builds raise
    `WorkerStartError`. ``slab_tiles``: slots of the shared-memory slab results come back
    through (`tile_slab`; 0: pickled, as before the slab).
    """

    def __init__(
        self,
        recipe: TerrainRecipe,
        workers: int,
        fallback: Callable[[np.ndarray], dict[Key, ReadyTile]] | None = None,
        slab_tiles: int = 256,
    ) -> None:
        if workers < 1:
            raise ValueError(f"tile worker processes must be at least 1, got {workers}")
        if slab_tiles < 0:
            raise ValueError(f"slab_tiles must be >= 0, got {slab_tiles}")
        self.recipe = recipe
        self.workers = int(workers)
        self.slab_tiles = int(slab_tiles)
        #: The shared-memory slots (made with the first pool; None: none, or shut down).
        self.slab: TileSlab | None = None
        #: Tiles that came back through the slab, and pickled (no slot was free).
        self.tiles_shared = 0
        self.tiles_pickled = 0
        self._lock = threading.Lock()
        self._pool: cf.ProcessPoolExecutor | None = None
        self._closed = False
        self.fallback = fallback
        #: Why the workers could not start (then builds go to ``fallback``), or None.
        self.start_error: str | None = None
        #: Worker processes started so far (a lost worker's pool is replaced: more than N).
        self.started = 0
        # CPU seconds of the workers: by pid, the last figure each reported, and of pools
        # already gone.
        self._cpu: dict[int, float] = {}
        self._cpu_gone = 0.0

    def describe(self) -> str:
        if self.start_error is not None and self.fallback is not None:
            return f"process x{self.workers} (not started: in-process)"
        return f"process x{self.workers}"

    def _executor(self) -> cf.ProcessPoolExecutor:
        with self._lock:
            if self._closed:
                raise WorkerLost("the tile workers are shut down")
            if self._pool is None:
                if self.slab is None and self.slab_tiles:
                    self.slab = self._new_slab()
                self._pool = cf.ProcessPoolExecutor(
                    self.workers,
                    mp_context=multiprocessing.get_context("forkserver"),
                    initializer=_init_worker,
                    initargs=(self.recipe,),
                )
                self.started += self.workers
            return self._pool

    def _new_slab(self) -> TileSlab | None:
        """The shared-memory slots, or None (one warning; tiles then travel pickled) where
        the system cannot give them (/dev/shm full or missing)."""
        try:
            return TileSlab(self.recipe.tile_size, self.slab_tiles)
        except OSError as exc:
            log.warning("tile workers send their tiles pickled: no shared memory (%s)", exc)
            self.slab_tiles = 0
            return None

    def start(self, wait_s: float = 0.0) -> bool:
        """Start the workers now (they open the terrain: ~1-2 s) rather than at the first
        build; wait up to ``wait_s`` seconds for every one to be ready. Returns whether they
        all are."""
        pool = self._executor()
        futures = [pool.submit(_ready_check) for _ in range(self.workers)]
        if wait_s <= 0:
            return False
        done, _ = cf.wait(futures, timeout=wait_s)
        return len(done) == len(futures) and all(f.exception() is None for f in done)

    def warm(self, keys: np.ndarray, wait_s: float = 60.0, facts_only: bool = False) -> None:
        """Build tiles ``keys`` (N, 3) in the workers (results dropped; ``facts_only``: only
        their per-tile metadata) and wait up to ``wait_s`` seconds. A worker's first builds
        open its store files, and its stack's first metadata on a level builds that level's
        blend-error tables (~0.7 s CPU a level and layer: the stack's cold facts, not a
        tile's cost); a benchmark warms the workers as a window's are after its first
        views."""
        pool = self._executor()
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        batches = [keys[i : i + 8] for i in range(0, len(keys), 8)]
        work = _warm_facts if facts_only else _build_batch
        # Each batch once per worker: idle workers take them, so each sees most of them.
        futures = [pool.submit(work, b) for b in batches for _ in range(self.workers)]
        cf.wait(futures, timeout=wait_s)

    def _lost(self, pool: cf.ProcessPoolExecutor) -> None:
        """Forget a broken pool (the next call starts a fresh one)."""
        with self._lock:
            if self._pool is pool:
                self._pool = None
                self._cpu_gone += sum(self._cpu.values())
                self._cpu.clear()
        pool.shutdown(wait=False, cancel_futures=True)

    def build_many(self, keys: np.ndarray) -> dict[Key, ReadyTile]:
        """Upload-ready tiles of ``keys`` (N, 3), built in one worker in one batch, their
        arrays in the slab's slots where enough are free (release each tile once uploaded).

        Raises:
            whatever the build raised in the worker (the batch is then lost); WorkerLost
            when the worker died or the builder is shut down.
        """
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        if self.start_error is not None and self.fallback is not None:
            return self.fallback(keys)
        pool = self._executor()
        lease = _Lease(self.slab, len(keys))
        try:
            future = lease.submit(pool, keys)
        except RuntimeError as exc:  # broken, or shut down by another thread meanwhile
            lease.free()  # no worker has them
            self._lost(pool)
            raise WorkerLost(f"tile worker lost: {exc}") from None
        procs = _processes(pool)
        try:
            got = future.result()
        except (BrokenProcessPool, cf.CancelledError) as exc:
            self._lost(pool)
            # A worker of the broken pool may still be writing the slots until it ends.
            lease.free_when_dead([*procs, *_processes(pool)])
            raise WorkerLost(f"tile worker lost: {type(exc).__name__}") from None
        except WorkerStartError as exc:
            lease.free()  # the worker's call has ended
            return self._start_failed(exc, keys)
        except BaseException:
            lease.free()
            raise
        if lease.slots is None:
            self.tiles_pickled += len(got)
            return cast(dict[Key, ReadyTile], got)
        self.tiles_shared += len(got)
        return lease.tiles(got)

    def _start_failed(self, exc: WorkerStartError, keys: np.ndarray) -> dict[Key, ReadyTile]:
        """The workers cannot open the terrain: build ``keys`` with the fallback from now on
        (one warning), or raise ``exc`` without one."""
        if self.fallback is None:
            raise exc
        with self._lock:
            first = self.start_error is None
            self.start_error = str(exc)
        if first:
            log.warning("%s; building tiles in this process", exc)
        self.shutdown_workers()
        return self.fallback(keys)

    def build(self, key: Key) -> ReadyTile:
        """One tile (`build_many` of one)."""
        k = (int(key[0]), int(key[1]), int(key[2]))
        return self.build_many(np.array([k]))[k]

    def cpu_seconds(self) -> float:
        """CPU seconds the worker processes used (their `/proc` clocks; pools replaced after
        a lost worker count until they went)."""
        with self._lock:
            pool = self._pool
            pids = list(getattr(pool, "_processes", None) or {}) if pool is not None else []
        for pid in pids:
            cpu = _proc_cpu_s(pid)
            if cpu is not None:
                self._cpu[pid] = cpu
        return self._cpu_gone + sum(self._cpu.values())

    def pids(self) -> list[int]:
        """The live worker processes' ids (for tests and reports)."""
        with self._lock:
            pool = self._pool
            return list(getattr(pool, "_processes", None) or {}) if pool is not None else []

    def shutdown_workers(self) -> None:
        """End the workers (as `shutdown`) but keep building through ``fallback``."""
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            self._end(pool, 1.0)
        self._close_slab()

    def _close_slab(self) -> None:
        """Unlink the slab (tiles still viewing it keep their memory until they go)."""
        with self._lock:
            slab, self.slab = self.slab, None
            self.slab_tiles = 0  # no new slab for this builder
        if slab is not None:
            slab.close()

    def shutdown(self, grace_s: float = 1.0) -> None:
        """Stop for good: queued batches are dropped, the workers end once their batch
        under way is sent (a build takes milliseconds), and any still running after
        ``grace_s`` seconds (a build that hangs) is killed; waits for them. A caller waiting
        on a dropped or killed batch gets WorkerLost.

        Not a kill at once: a worker killed while it writes a result leaves the pool's
        reader thread waiting for the rest of the message forever (this process holds the
        pipe's other end), and the interpreter's exit waits for that thread."""
        with self._lock:
            self._closed = True
            self.fallback = None
            pool, self._pool = self._pool, None
        if pool is not None:
            self._end(pool, grace_s)
        self._close_slab()

    def _end(self, pool: cf.ProcessPoolExecutor, grace_s: float) -> None:
        self.cpu_seconds()
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        end = time.monotonic() + grace_s
        for p in procs:
            p.join(max(0.0, end - time.monotonic()))
        # ProcessPoolExecutor has no public kill before Python 3.14 (terminate_workers).
        for p in procs:
            if p.is_alive():
                p.kill()
        for p in procs:
            p.join(5.0)


class _Lease:
    """The slab slots of one batch (``slots`` None: the batch travels pickled)."""

    def __init__(self, slab: TileSlab | None, n: int) -> None:
        self.slab = slab
        self.slots = slab.take(n) if slab is not None else None

    def submit(self, pool: cf.ProcessPoolExecutor, keys: np.ndarray) -> cf.Future[Any]:
        """The batch's build in the pool: into the slots, or pickled without them."""
        if self.slab is not None and self.slots is not None:
            return pool.submit(_build_batch_shared, keys, self.slab.spec, self.slots)
        return pool.submit(_build_batch, keys)

    def free(self) -> None:
        if self.slab is not None and self.slots is not None:
            self.slab.free(self.slots)

    def free_when_dead(self, procs: list[multiprocessing.Process]) -> None:
        if self.slab is not None and self.slots is not None:
            self.slab.free_when_dead(procs, self.slots)

    def tiles(
        self, got: list[tuple[Key, np.ndarray, float, np.ndarray | None]]
    ) -> dict[Key, ReadyTile]:
        """The batch's tiles viewing their slots (``got``: the worker's keys, centres, coast
        scales and block stats, in the slots' order)."""
        assert self.slab is not None and self.slots is not None
        slab = self.slab
        if slab.closed:  # shut down while the batch was built
            raise WorkerLost("the tile workers are shut down")
        slab.free(self.slots[len(got) :])  # keys given twice: one tile, one slot
        out = {}
        for (k, c, sc, blocks), s in zip(got, self.slots, strict=False):
            tile = out[k] = slab.tile(s, c, sc)
            tile.blocks = blocks
        return out


def _processes(pool: cf.ProcessPoolExecutor) -> list[multiprocessing.Process]:
    """The pool's worker processes now (none once it has forgotten them)."""
    return list((getattr(pool, "_processes", None) or {}).values())


def _proc_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` from /proc (None where unreadable)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    # After the command: state is field 3, utime 14 and stime 15 (1-based).
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
