"""Background tile loading for interactive use.

Building a tile (reading its heights, meshing, averaging normals) takes milliseconds; a fast
camera move can ask for a hundred new tiles in one frame. In the window the renderer therefore
builds tiles off the UI thread, uploads the finished ones at the next frame, and until a tile
is ready draws its nearest resident ancestor instead — never a hole, never an overlap (the
ancestor replaces every requested tile below it). Headless renders load synchronously so
every image is complete.

Two kinds of workers (issue #27): threads that call the build themselves (the build is
mostly GIL-bound numpy on small arrays, so one thread is all a 2-core machine should give
it), or threads that hand batches to worker processes (`tile_workers.ProcessBuilder`, given
as ``processes``) and wait for them with the GIL released: the builds then use every core.

Scheduling (issue #17: "Go to" -> complete view): the queue is a priority list, not a FIFO.

* Each frame *replaces* the frame tier with the tiles that frame misses, nearest the eye
  first (`tile_priority`): tiles a moving camera no longer wants are dropped before a worker
  spends time on them (a 1 s flight across the globe asks for hundreds of tiles it passes).
* A *prefetch* tier (`prefetch`, e.g. the destination of a camera flight) is built before the
  frame tier and survives frame requests until it is built or replaced, so the destination's
  tiles load while the flight is still under way.
* ``on_ready`` is called (on a worker thread) once per finished batch of tiles (up to
  ``batch`` tiles, failures included; not for a batch discarded by `TileLoader.cancel_all`),
  so a window can schedule a frame when there is something new to draw instead of
  redrawing in a busy loop that takes the CPU from the workers.

Stand-ins (issue #25 item 4: a remote layer added, or a view that jumps): a view whose tiles
have no resident ancestor near them would wait for hundreds of its own tiles (over a network,
seconds of round trips and builds). `coarse_standins` picks a few of their ancestors (at most
8, then at most 32, at the deepest levels that few cover the view), which the renderer asks
for *ahead* of the frame's tiles (`TileLoader.request`'s ``ahead``): they draw the whole view
at once and refine as its own tiles arrive. After the layers change, the tiles of the layers
before are *retired* in the pool, not dropped (`TilePool.retire`), and stand in where no
resident tile does (`substitute_missing`'s ``stale``): the view is never blanked.

A failed tile is not asked for again at once (its nearest ancestor stands in, see
`substitute_missing`), but only for `retry_failed_s` seconds: a store read over HTTP fails
while its server is down or overloaded and serves the tile again later (issue #18), and a
local file that was unreadable stays just as cheap to try again a few times a minute.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Protocol, TypeAlias

import numpy as np

from globeview.geodesy import lonlat_to_ecef
from globeview.lod.render_set import RenderSet
from globeview.lod.tile_indices import IndexVariant
from globeview.render.tile_build import ReadyTile
from globeview.render.tile_mesh import TileMesh

log = logging.getLogger("globeview.render")

Key = tuple[int, int, int]
#: What a build gives: a mesh (its texels baked at upload) or a tile ready for upload.
Built: TypeAlias = TileMesh | ReadyTile

#: Mean Earth radius (m), for the tiles' ground radius in `tile_priority`.
_EARTH_R_M = 6.371e6


def tile_priority(keys: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """Load order key of tiles ``keys`` (N, 3: level, x, y) seen from ``eye`` (ECEF, m):
    the distance (m) from the eye to the tile's nearest ground point, estimated as the
    distance to the tile centre (on the ellipsoid) less the tile's half diagonal (its
    size in degrees times the metres per degree, an over-estimate near the poles: a tile
    there only loads earlier). Smaller loads first; the tile under the camera is 0."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    size_deg = 180.0 / np.exp2(keys[:, 0].astype(np.float64))
    lon = -180.0 + (keys[:, 1] + 0.5) * size_deg
    lat = 90.0 - (keys[:, 2] + 0.5) * size_deg
    centre = lonlat_to_ecef(lon, lat)
    dist = np.linalg.norm(centre - np.asarray(eye, dtype=np.float64), axis=1)
    half_diag = np.radians(size_deg) * _EARTH_R_M * (np.sqrt(2.0) / 2.0)
    return np.maximum(dist - half_diag, 0.0)


def _ordered(keys: np.ndarray, priority: np.ndarray | None) -> list[Key]:
    """``keys`` as tuples, by ``priority`` (ascending), ties coarse level first; without
    priorities coarse first (the order the tiles were asked in, within a level)."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    if priority is None:
        order = np.argsort(keys[:, 0], kind="stable")
    else:
        order = np.lexsort((keys[:, 0], np.asarray(priority, dtype=np.float64)))
    return [(int(k[0]), int(k[1]), int(k[2])) for k in keys[order]]


#: Stand-in tiers (`coarse_standins`): for each, the deepest level at which the missing
#: tiles have at most this many ancestors. 8: a few tiles that draw the whole view at once
#: (for a view of the globe or a region, levels whose chunks are few and whose metadata is in
#: a store's top shard); 32: a sharper second step, still few beside a view's hundreds.
STANDIN_TILES = (8, 32)
#: A missing tile gets a stand-in at a tier's level when it is at least this many levels
#: finer than that level (and what stands in for it now is coarser, or nothing does).
STANDIN_GAP = 3


def coarse_standins(
    missing: np.ndarray, resident: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """Ancestors of the ``missing`` tiles (N, 3) to build before them, coarse tier first
    (K, 3), none resident: when a layer was added or the view jumped, the view's own tiles
    are hundreds and arrive over many seconds (over a network, round trips each), while a
    few coarse ancestors draw the whole view at once and refine as the tiles arrive (the
    coarser ones first: Cesium and Google Earth load the same way).

    For each `STANDIN_TILES` tier, the level is the deepest at which the missing tiles have
    at most that many distinct ancestors (a tile at or above it counting as itself); a
    missing tile at least `STANDIN_GAP` levels deeper gets its ancestor there when its
    nearest resident ancestor is coarser, or it has none. A small view (a few tiles), or
    the edge a moving camera uncovers (whose parents are resident), gets none."""
    missing = np.asarray(missing, dtype=np.int64).reshape(-1, 3)
    if not len(missing):
        return np.empty((0, 3), np.int64)
    anc, found = nearest_ancestors(missing, resident)
    drawn_level = np.where(found, anc[:, 0], -1)
    out: dict[tuple[int, int, int], None] = {}
    for cap in STANDIN_TILES:
        level = _standin_level(missing, cap)
        want = (missing[:, 0] - level >= STANDIN_GAP) & (drawn_level < level)
        if not want.any():
            continue
        shift = missing[want, 0] - level
        at = np.stack(
            [np.full(len(shift), level), missing[want, 1] >> shift, missing[want, 2] >> shift],
            axis=1,
        )
        at = np.unique(at, axis=0)
        at = at[~resident(at)]
        out.update(((int(a), int(b), int(c)), None) for a, b, c in at.tolist())
    return np.array(list(out), dtype=np.int64).reshape(-1, 3)


def _standin_level(keys: np.ndarray, cap: int) -> int:
    """The deepest level at which ``keys`` (N, 3) have at most ``cap`` distinct ancestors
    (a key at or above the level counting as itself); 0 at least."""
    best = 0
    for level in range(1, int(keys[:, 0].max()) + 1):
        lv = np.minimum(keys[:, 0], level)
        shift = keys[:, 0] - lv
        codes = _codes(lv, keys[:, 1] >> shift, keys[:, 2] >> shift)
        if len(np.unique(codes)) > cap:
            break
        best = level
    return best


def _codes(level: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """One int64 per tile (level < 32, x, y < 2^29), as `tile_pool.key_codes`."""
    return (level.astype(np.int64) << 58) | (y.astype(np.int64) << 29) | x.astype(np.int64)


#: How long `TileLoader.shutdown` waits for each worker's build under way (seconds).
JOIN_TIMEOUT_S = 5.0
#: Seconds a failed tile is left alone before a frame's request may build it again.
RETRY_FAILED_S = 15.0


class TileLoader:
    """Builds tile meshes on worker threads; the render thread collects finished ones.

    Args:
        build: ``build(key) -> TileMesh | ReadyTile`` (called on the workers; must be thread-safe).
        workers: worker threads.
        on_ready: called on a worker thread after each batch of tiles finished (built or
            failed); must be cheap and thread-safe (e.g. emit a Qt signal).
        build_many: optional ``build_many(keys (N, 3)) -> {key: TileMesh | ReadyTile}`` that builds
            several tiles in one call (vectorised metadata, fewer hand-overs of the GIL); a
            worker then takes up to ``batch`` tiles at once, in load order. A batch that
            raises is built again tile by tile with ``build`` so only the bad tile fails.
        batch: most tiles per ``build_many`` call.
        retry_failed_s: a failed tile is kept in `failed` (and not built again) for this
            many seconds; the next request or prefetch after that tries it again.
        processes: the worker processes ``build`` and ``build_many`` hand work to (a
            `tile_workers.ProcessBuilder`): `describe`, `cpu_seconds` and `shutdown`
            include them (`shutdown` kills them first, so no thread waits on a build).
    """

    def __init__(
        self,
        build: Callable[[Key], Built],
        workers: int = 2,
        on_ready: Callable[[], None] | None = None,
        build_many: Callable[[np.ndarray], dict[Key, Built]] | None = None,
        batch: int = 8,
        retry_failed_s: float = RETRY_FAILED_S,
        processes: ProcessPart | None = None,
    ) -> None:
        if workers < 1:
            raise ValueError(f"tile loader workers must be at least 1, got {workers}")
        if batch < 1:
            raise ValueError(f"tile loader batch must be at least 1, got {batch}")
        if not retry_failed_s >= 0:  # NaN too
            raise ValueError(f"retry_failed_s must be >= 0 seconds, got {retry_failed_s}")
        self.retry_failed_s = float(retry_failed_s)
        self._build = build
        self._build_many = build_many
        self._batch = batch if build_many is not None else 1
        self.on_ready = on_ready
        self.processes = processes
        self._cv = threading.Condition()
        # Wanted, not started: dicts kept in load order (a dict is an ordered set here).
        self._prefetch: dict[Key, None] = {}
        self._queue: dict[Key, None] = {}
        self._running: set[Key] = set()
        self._ready: dict[Key, Built] = {}
        self.failed: dict[Key, BaseException] = {}
        self._failed_at: dict[Key, float] = {}  # time.monotonic() of each failure
        # Bumped by cancel_all: a build that started before it is discarded when it ends.
        self._generation = 0
        #: Tiles built (or failed) by the workers since the loader started, results
        #: discarded by `cancel_all` included: what `cpu_seconds` was spent on.
        self.tiles_built = 0
        self._stop = False
        self._threads = [
            threading.Thread(target=self._work, name=f"gv-tiles-{i}", daemon=True)
            for i in range(workers)
        ]
        for t in self._threads:
            t.start()

    # -- figures -------------------------------------------------------------------------
    @property
    def pending(self) -> int:
        """Tiles asked for and not handed over yet: queued, being built, or built and
        waiting for `take_ready`."""
        with self._cv:
            queued = len(self._queue) + sum(1 for k in self._prefetch if k not in self._queue)
            return queued + len(self._running) + len(self._ready)

    @property
    def building(self) -> int:
        """Tiles queued or being built (not counting finished ones waiting for upload)."""
        with self._cv:
            return len(self._queue.keys() | self._prefetch.keys()) + len(self._running)

    @property
    def prefetching(self) -> int:
        """Prefetch tiles still queued (not started)."""
        with self._cv:
            return len(self._prefetch)

    @property
    def ready(self) -> int:
        """Finished tiles waiting for `take_ready`."""
        with self._cv:
            return len(self._ready)

    @property
    def workers(self) -> int:
        """Worker threads (each builds one batch at a time)."""
        return len(self._threads)

    def describe(self) -> str:
        """The loader's kind and size for reports, e.g. ``thread x1``, ``process x14``."""
        if self.processes is not None:
            return self.processes.describe()
        return f"thread x{len(self._threads)}"

    def cpu_seconds(self) -> float:
        """CPU time (s) the workers have used so far: the worker threads' own clocks (the
        builds, or handing batches to the processes and taking their results), plus the
        worker processes' (not the render thread's share of the GIL hand-overs); for
        benchmarks."""
        own = sum(_thread_cpu_s(t) for t in self._threads)
        return own + (self.processes.cpu_seconds() if self.processes is not None else 0.0)

    # -- asking ----------------------------------------------------------------------------
    def request(
        self,
        keys: np.ndarray,
        priority: np.ndarray | None = None,
        ahead: np.ndarray | None = None,
    ) -> None:
        """This frame's missing tiles ``keys`` (N, 3), ``priority`` ascending (e.g.
        `tile_priority`; None: coarse first), after the tiles ``ahead`` (K, 3), in their
        order (e.g. `coarse_standins`). Replaces the previous frame's request: queued tiles
        not asked for again are dropped (those being built finish and are kept)."""
        wanted = _ordered(keys, priority)
        if ahead is not None and len(ahead):
            first = [(int(a), int(b), int(c)) for a, b, c in np.asarray(ahead).tolist()]
            wanted = list(dict.fromkeys([*first, *wanted]))
        with self._cv:
            self._expire_failures()
            self._queue = {
                k: None
                for k in wanted
                if k not in self._running and k not in self._ready and k not in self.failed
            }
            if self._queue:
                self._cv.notify_all()

    def prefetch(self, keys: np.ndarray, priority: np.ndarray | None = None) -> None:
        """Tiles to build ahead of every frame's request (a flight's destination); replaces
        the previous prefetch. Tiles already resident should be left out by the caller."""
        wanted = _ordered(keys, priority)
        with self._cv:
            self._expire_failures()
            self._prefetch = {
                k: None
                for k in wanted
                if k not in self._running and k not in self._ready and k not in self.failed
            }
            if self._prefetch:
                self._cv.notify_all()

    def take_ready(self, limit: int) -> list[tuple[Key, Built]]:
        """Up to ``limit`` finished tiles, in the order they finished (removed here)."""
        out: list[tuple[Key, Built]] = []
        with self._cv:
            while self._ready and len(out) < limit:
                key = next(iter(self._ready))
                out.append((key, self._ready.pop(key)))
        return out

    def cancel_all(self) -> None:
        """Forget queued work, finished tiles and failures (e.g. after the terrain layers
        changed): builds under way are discarded when they end."""
        with self._cv:
            self._generation += 1
            self._prefetch.clear()
            self._queue.clear()
            self._running.clear()
            self._ready.clear()
            self.failed.clear()
            self._failed_at.clear()

    def shutdown(self, timeout_s: float = JOIN_TIMEOUT_S) -> None:
        """Stop the workers and wait (up to ``timeout_s`` each) for a build under way to end;
        its result is dropped. A worker's frame holds the loader and so the build callables
        (the renderer, the terrain, their datasets): waiting is what lets a closed window's
        session be freed at once and its stores close with no read in flight."""
        with self._cv:
            self._stop = True
            self._generation += 1
            self._prefetch.clear()
            self._queue.clear()
            self._cv.notify_all()
        if self.processes is not None:
            self.processes.shutdown()  # builds under way fail at once: nothing to wait for
        me = threading.current_thread()
        for t in self._threads:
            if t is not me and t.is_alive():
                t.join(timeout_s)
        self.on_ready = None

    def _expire_failures(self) -> None:
        """Forget failures older than `retry_failed_s` (they may be asked for again). Holds
        _cv. The oldest come first (dicts keep insertion order), so the loop stops at the
        first failure still fresh: no walk over every failure each frame."""
        if not self._failed_at:
            return
        cutoff = time.monotonic() - self.retry_failed_s
        while self._failed_at:
            key, when = next(iter(self._failed_at.items()))
            if when > cutoff:
                break
            del self._failed_at[key]
            self.failed.pop(key, None)

    # -- workers ---------------------------------------------------------------------------
    def _next_keys(self) -> list[Key] | None:
        """Up to ``batch`` tiles to build next (prefetch first, in load order), or None when
        stopping. Holds _cv."""
        while not self._stop:
            out: list[Key] = []
            for tier in (self._prefetch, self._queue):
                while tier and len(out) < self._batch:
                    key = next(iter(tier))
                    del tier[key]
                    # In both tiers, or finished meanwhile: skip.
                    if key in self._running or key in self._ready or key in self.failed:
                        continue
                    if key not in out:
                        out.append(key)
            if out:
                return out
            self._cv.wait()
        return None

    def _build_keys(self, keys: list[Key]) -> dict[Key, Built | BaseException]:
        """Build ``keys``: in one ``build_many`` call when there is one and several keys,
        else (or when the batch raised) one by one, each failure kept as its exception."""
        if self._build_many is not None and len(keys) > 1:
            try:
                meshes = self._build_many(np.array(keys, dtype=np.int64))
                return {k: meshes[k] for k in keys}
            except Exception:  # noqa: BLE001  find the bad tile below, one by one
                pass
        out: dict[Key, Built | BaseException] = {}
        for key in keys:
            if self._stop:  # shutting down: the rest are dropped with the batch
                out[key] = RuntimeError("tile loader shut down")
                continue
            try:
                out[key] = self._build(key)
            except Exception as exc:  # noqa: BLE001  a failed tile is counted, others load
                out[key] = exc
        return out

    def _work(self) -> None:
        while True:
            with self._cv:
                keys = self._next_keys()
                if keys is None:
                    return
                self._running.update(keys)
                generation = self._generation
            results = self._build_keys(keys)
            with self._cv:
                self.tiles_built += len(results)
                if generation != self._generation:
                    continue  # cancelled meanwhile (new layers): the results are stale
                for key, res in results.items():
                    self._running.discard(key)
                    if isinstance(res, BaseException):
                        # Without its traceback: the frames would keep the batch's meshes
                        # (~0.5 MB a failure) alive for as long as the failure is remembered.
                        self.failed[key] = res.with_traceback(None)
                        self._failed_at.pop(key, None)  # re-inserted last: oldest first
                        self._failed_at[key] = time.monotonic()
                    else:
                        self._ready[key] = res
            callback = self.on_ready
            if callback is not None:
                try:
                    callback()
                except Exception:  # a broken listener must not stop loading
                    log.exception("tile loader: on_ready failed")


class BytesWarmer:
    """Hands the tiles a frame misses to a terrain's byte prefetch (``warm(keys (N, 3))``,
    e.g. `TerrainStack.prefetch_bytes`) on a thread of its own, so the frame does not wait
    for it: mapping hundreds of tiles to their chunk blocks and starting the prefetch's
    threads took 0.8 s of the first frame over a remote layer at load 20. The latest keys
    win: a list handed over while the thread is busy replaces one still waiting (the
    prefetch skips tiles it was asked for before, so nothing is fetched twice)."""

    def __init__(self, warm: Callable[[np.ndarray], object]) -> None:
        self._warm = warm
        self._cv = threading.Condition()
        self._keys: np.ndarray | None = None
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="gv-warm", daemon=True)
        self._thread.start()

    def submit(self, keys: np.ndarray) -> None:
        """Warm ``keys`` (N, 3), most wanted first, once the thread is free."""
        with self._cv:
            self._keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
            self._cv.notify()

    def shutdown(self, timeout_s: float = JOIN_TIMEOUT_S) -> None:
        """Stop the thread (a list being handed over finishes) and wait for it."""
        with self._cv:
            self._stop = True
            self._keys = None
            self._cv.notify()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._cv:
                while self._keys is None and not self._stop:
                    self._cv.wait()
                if self._stop:
                    return
                keys, self._keys = self._keys, None
            try:
                self._warm(keys)
            except Exception:  # a prefetch is a hint: the loader's reads report failures
                log.debug("tile bytes prefetch failed", exc_info=True)


class ProcessPart(Protocol):
    """The worker processes a loader hands builds to (`tile_workers.ProcessBuilder`)."""

    def describe(self) -> str: ...
    def cpu_seconds(self) -> float: ...
    def shutdown(self) -> None: ...


def _thread_cpu_s(thread: threading.Thread) -> float:
    """CPU seconds a live thread has used (its POSIX CPU clock); 0 for a thread that ended
    or where the platform has no per-thread clock."""
    ident = thread.ident
    if ident is None or not thread.is_alive():
        return 0.0
    try:
        return time.clock_gettime(time.pthread_getcpuclockid(ident))
    except (AttributeError, OSError):
        return 0.0


def substitute_missing(
    render_set: RenderSet,
    resident: Callable[[np.ndarray], np.ndarray],
    stale: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[RenderSet, np.ndarray]:
    """Replace tiles that are not resident by their nearest resident ancestor.

    ``resident(keys) -> bool array``. Every requested tile below a chosen ancestor is dropped
    (the ancestor covers it), and so is a chosen ancestor below another (the coarser one
    covers both), so the result has no overlaps. ``stale(keys) -> bool array``: tiles of the
    layers as they were before a change (`TilePool.retire`); a missing tile with no resident
    ancestor is drawn by its stale tile or nearest stale ancestor, so a view does not blank
    while the new layers' tiles load. A missing tile with neither leaves a gap until
    something loads. Returns the new render set and the keys that were missing (to request).
    """
    keys = render_set.keys
    have = resident(keys)
    if have.all():
        return render_set, np.empty((0, 3), np.int64)
    missing = keys[~have]
    anc, found = nearest_ancestors(missing, resident)
    subs = anc[found]
    if stale is not None and not found.all():
        old, old_found = nearest_ancestors(missing[~found], stale, include_self=True)
        subs = np.concatenate([subs, old[old_found]])
    subs = np.unique(subs, axis=0)
    subs = subs[~covered_by(subs, subs, strict=True)]
    # Drop requested tiles that lie under a chosen ancestor (and the missing ones).
    keep = have & ~covered_by(keys, subs)
    return _with_standins(render_set, np.nonzero(keep)[0], subs), missing


def nearest_ancestors(
    keys: np.ndarray, present: Callable[[np.ndarray], np.ndarray], include_self: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """(ancestors (N, 3), found (N,) bool): for each of ``keys`` (N, 3) its nearest strict
    ancestor (or itself, with ``include_self``) for which ``present(keys) -> bool array`` is
    true, where ``found``; one vectorised step per level."""
    anc = np.asarray(keys, dtype=np.int64).reshape(-1, 3).copy()
    found = present(anc) if include_self and len(anc) else np.zeros(len(anc), dtype=bool)
    while not found.all() and (anc[~found, 0] > 0).any():
        step = ~found & (anc[:, 0] > 0)
        anc[step] = np.stack([anc[step, 0] - 1, anc[step, 1] >> 1, anc[step, 2] >> 1], axis=1)
        found[step] = present(anc[step])
    return anc, found


def covered_by(keys: np.ndarray, covers: np.ndarray, strict: bool = False) -> np.ndarray:
    """(N,) bool: whether each of ``keys`` (N, 3) lies under one of ``covers`` (M, 3): is
    one of them (unless ``strict``) or a descendant of one."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    out = np.zeros(len(keys), dtype=bool)
    for level in np.unique(covers[:, 0]) if len(covers) else ():
        at = covers[covers[:, 0] == level]
        codes = at[:, 1] * (1 << 31) + at[:, 2]
        deeper = keys[:, 0] > level if strict else keys[:, 0] >= level
        shift = np.maximum(keys[:, 0] - level, 0)
        ax = np.where(deeper, keys[:, 1] >> shift, -1)
        ay = np.where(deeper, keys[:, 2] >> shift, -1)
        out |= deeper & np.isin(ax * (1 << 31) + ay, codes)
    return out


def _with_standins(render_set: RenderSet, rows: np.ndarray, subs: np.ndarray) -> RenderSet:
    """The rows ``rows`` of ``render_set`` and the stand-in tiles ``subs`` (M, 3), drawn at
    stride 4 with skirts (error unknown: inf; no block strides)."""
    keys = render_set.keys
    variants = list(render_set.variants)
    pole = (subs[:, 2] == 0).astype(np.int64) + 2 * (subs[:, 2] == (1 << subs[:, 0]) - 1)
    poles = (None, "north", "south", "both")
    sub_ids = np.empty(len(subs), dtype=np.int64)
    for code in np.unique(pole):
        variants.append(IndexVariant(stride=4, skirts=True, pole=poles[int(code)]))
        sub_ids[pole == code] = len(variants) - 1
    new_index = {int(r): i for i, r in enumerate(rows)}
    custom = {new_index[r]: idx for r, idx in render_set.custom_indices.items() if r in new_index}
    err = None
    if render_set.error_px is not None:
        # A stand-in tile is coarser than asked for: its error is unknown here (inf).
        err = np.concatenate([render_set.error_px[rows], np.full(len(subs), np.inf)])
    blocks = render_set.block_strides
    if blocks is not None:  # stand-ins are drawn by their variants
        blocks = np.concatenate([blocks[rows], np.full((len(subs), 8, 8), -1, np.int8)])
    return RenderSet(
        np.concatenate([keys[rows], subs]),
        np.concatenate([render_set.variant_ids[rows], sub_ids]),
        variants,
        custom_indices=custom,
        error_px=err,
        stats=dict(render_set.stats),
        block_strides=blocks,
        block_tau_px=render_set.block_tau_px,
    )
