"""`bench soak`: fly the shipped flights in a loop and watch memory and GL objects.

A leak shows as RSS or the renderer's GL object count still growing after the warm-up (the
first pass over every flight, which fills the tile pool and the allocator's arenas).
"""

from __future__ import annotations

import gc
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from globeview.bench.flight import Flight, shipped_flights_dir
from globeview.bench.harness import Bench, fly, load_terrain, machine, rss_mb

if TYPE_CHECKING:
    import moderngl

SOAK_FLIGHTS = ("global_approach.json", "canyon_run.json", "fast_pan.json", "regional_oblique.json")


def _gl(sample: dict) -> dict:
    return {k: sample[k] for k in ("buffers", "textures", "vaos", "programs")}


def run_soak(
    frames: int = 200,
    size: tuple[int, int] = (320, 180),
    lod: str = "chunked-sse",
    tau: float = 2.0,
    per_flight: int = 10,
    log: Callable[[str], object] = print,
) -> dict:
    """Render ``frames`` frames cycling through the embedded flights (``per_flight`` frames
    each); sample RSS and GL object counts after every flight. Returns the samples and the
    drift after warm-up."""
    flights = [Flight.load(shipped_flights_dir() / f) for f in SOAK_FLIGHTS]
    bench = Bench(load_terrain("embedded"), size, lod=lod)
    bench.use(lod, tau)
    log(f"machine: {machine(bench.gl_renderer)}")
    samples: list[dict] = []
    done = 0
    lap = 0
    try:
        while done < frames:
            for fl in flights:
                n = min(per_flight, frames - done)
                if n <= 0:
                    break
                # The harness's flight loop: flight time stamps (the pipeline's speed, no
                # pause between sparse samples); each flight starts at rest.
                fly(bench, fl, fl.times(frames=n), warm=False)
                done += n
                gc.collect()
                objs = bench.gl_objects()
                samples.append({"frame": done, "lap": lap, "rss_mb": rss_mb(), **objs})
            lap += 1
    finally:
        bench.release()
    warm = len(flights)  # first lap = warm-up
    after = samples[warm - 1 :] if len(samples) > warm else samples[-1:]
    rss = np.array([s["rss_mb"] for s in after])
    res = {
        "samples": samples,
        "frames": done,
        "rss_first": float(samples[0]["rss_mb"]),
        "rss_after_warmup": float(rss[0]),
        "rss_last": float(rss[-1]),
        "rss_drift_mb": float(rss[-1] - rss[0]),
        "rss_max_after_warmup": float(rss.max()),
        "gl_objects_stable": all(_gl(s) == _gl(after[0]) for s in after),
        "warmup_complete": len(samples) > warm,
    }
    return res


# -- open-render-close cycles ------------------------------------------------------------------

#: The open-close soak's target: RSS growth (MB) from the warm-up cycle to the last one.
OPEN_CLOSE_DRIFT_TARGET_MB = 1.0


def open_close_cycle(
    store_paths: list,
    size: tuple[int, int] = (160, 90),
    lod: str = "chunked-sse",
    ctx: moderngl.Context | None = None,
) -> dict:
    """One cycle as an application opening and closing a globe would: open the tile stores,
    stack them, make a headless context, a session, render one frame, then release everything
    (session GL objects, offscreen target, context, stores). With ``ctx`` given the cycle
    draws in that context and leaves it open (to tell the context's own cost from the rest).
    Returns what the frame drew and weak references to the cycle's big objects (dead once it
    is really released)."""
    import weakref

    from globeview.app.session import GlobeSession
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.render.gpu_objects import gpu_objects
    from globeview.render.offscreen import (
        OffscreenTarget,
        create_headless_context,
        release_headless_context,
    )
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.sources import open_source

    stores = [open_source(p) for p in store_paths]
    own_ctx = ctx is None
    ctx = create_headless_context() if ctx is None else ctx
    try:
        terrain = TerrainStack.from_stores(stores)
        target = OffscreenTarget(ctx, size)
        tracker = gpu_objects(ctx)  # counts every GL object made from here on
        mark = tracker.mark
        registry = PluginRegistry(MemorySettings()).discover()
        session = GlobeSession(ctx, terrain, registry=registry, lod=lod)
        result = session.render(target.fbo, size)
        refs = {
            "session": weakref.ref(session),
            "renderer": weakref.ref(session.renderer),
            "terrain": weakref.ref(terrain),
            "registry": weakref.ref(registry),
            **{f"store {s.path.name}": weakref.ref(s) for s in stores},
        }
        triangles = int(result.stats.triangles)
        gl_live = sum(1 for t in tracker.live if t.serial > mark)
        session.release_gl()
        gl_left = [str(t) for t in tracker.live if t.serial > mark]
        target.release()
    finally:
        if own_ctx:
            release_headless_context(ctx)
        for s in stores:
            s.close()
    return {"triangles": triangles, "refs": refs, "gl_objects": gl_live, "gl_left": gl_left}


def trim_heap() -> bool:
    """Give freed heap memory back to the system (glibc ``malloc_trim``) so that RSS shows
    what is held, not what the allocator keeps cached after a cycle freed its ~100 MB of tile
    pool (without it the same run drifts anywhere from 0 to 1 MB per cycle). A leak is not
    trimmable. Returns False where there is no glibc."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        libc.malloc_trim(0)
    except (OSError, AttributeError):
        return False
    return True


def gl_context_count() -> int:
    """moderngl contexts alive in this process (released or not; a leak keeps them)."""
    import moderngl

    return sum(1 for o in gc.get_objects() if isinstance(o, moderngl.Context))


def type_counts() -> dict[str, int]:
    """Live gc-tracked objects by type name (for diffs between two cycles)."""
    counts: dict[str, int] = {}
    for o in gc.get_objects():
        name = type(o).__qualname__
        mod = type(o).__module__
        key = f"{mod}.{name}" if mod not in ("builtins",) else name
        counts[key] = counts.get(key, 0) + 1
    return counts


def run_open_close(
    cycles: int = 200,
    size: tuple[int, int] = (160, 90),
    lod: str = "chunked-sse",
    warmup: int = 20,
    every: int = 10,
    log: Callable[[str], object] = print,
) -> dict:
    """``cycles`` open-render-close cycles on the embedded stores; samples RSS every
    ``every`` cycles. The drift is RSS at the last cycle minus RSS after ``warmup`` cycles
    (allocator arenas, GDAL's block cache and Mesa's shader cache fill during the warm-up);
    it also diffs gc object counts by type between those two points and reports which of the
    last cycle's objects are still alive after it was released."""
    from globeview.terrain.embedded import embedded_stores

    stores = embedded_stores()  # ingest once (a no-op when the cache is ready)
    paths = [s.path for s in stores]
    for s in stores:
        s.close()
    del stores
    samples: list[dict] = []
    counts_warm: dict[str, int] = {}
    alive: list[str] = []
    for i in range(1, cycles + 1):
        out = open_close_cycle(paths, size, lod)
        del out["refs"]
        if i == warmup:
            gc.collect()
            counts_warm = type_counts()
        if i % every == 0 or i in (1, warmup, cycles):
            gc.collect()
            raw = rss_mb()
            trim_heap()
            samples.append(
                {"cycle": i, "rss_mb": rss_mb(), "rss_raw_mb": raw, "contexts": gl_context_count()}
            )
            log(
                f"cycle {i:4d}  RSS {samples[-1]['rss_mb']:7.1f} MB (before trimming the heap "
                f"{raw:7.1f})  GL contexts alive {samples[-1]['contexts']}"
            )
    last = open_close_cycle(paths, size, lod)
    gc.collect()
    alive = sorted(name for name, ref in last["refs"].items() if ref() is not None)
    counts_last = type_counts()
    grown = {
        k: counts_last.get(k, 0) - counts_warm.get(k, 0)
        for k in set(counts_last) | set(counts_warm)
        if counts_last.get(k, 0) != counts_warm.get(k, 0)
    }
    at_warm = next(s for s in samples if s["cycle"] >= warmup)
    drift = samples[-1]["rss_mb"] - at_warm["rss_mb"]
    return {
        "samples": samples,
        "cycles": cycles,
        "warmup": warmup,
        "rss_after_warmup": at_warm["rss_mb"],
        "rss_last": samples[-1]["rss_mb"],
        "rss_drift_mb": drift,
        "rss_raw_drift_mb": samples[-1]["rss_raw_mb"] - at_warm["rss_raw_mb"],
        "per_cycle_mb": drift / max(1, cycles - warmup),
        "alive_after_release": alive,
        "gl_objects_per_session": last["gl_objects"],
        "gl_objects_left_after_release": last["gl_left"],
        "object_growth": dict(sorted(grown.items(), key=lambda kv: -abs(kv[1]))[:15]),
        "target_mb": OPEN_CLOSE_DRIFT_TARGET_MB,
        "target_met": drift <= OPEN_CLOSE_DRIFT_TARGET_MB,
    }
