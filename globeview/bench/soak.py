"""`bench soak`: fly the shipped flights in a loop and watch memory and GL objects.

A leak shows as RSS or the renderer's GL object count still growing after the warm-up (the
first pass over every flight, which fills the tile pool and the allocator's arenas).
"""

from __future__ import annotations

import gc

import numpy as np

from globeview.bench.flight import Flight, shipped_flights_dir
from globeview.bench.harness import Bench, load_terrain, machine, rss_mb

SOAK_FLIGHTS = ("global_approach.json", "canyon_run.json", "fast_pan.json", "regional_oblique.json")


def _gl(sample: dict) -> dict:
    return {k: sample[k] for k in ("buffers", "textures", "vaos", "programs")}


def run_soak(
    frames: int = 200,
    size: tuple[int, int] = (320, 180),
    lod: str = "chunked-sse",
    tau: float = 2.0,
    per_flight: int = 10,
    log=print,
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
                for t in fl.times(frames=n):
                    bench.set_pose(fl.pose(float(t)))
                    bench.frame()
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
