"""Tile build latency, stage by stage (issue #17, item 3): what one tile costs from a warm
store, and the big-DEM flight's median frame with synchronous loading.

1. Flies the standard flight (`globeview bench check`'s big_dem.json, chunked-sse, tau 2 px)
   and records every tile the renderer builds; prints the flight's frame medians.
2. Replays a sample of those tiles stage by stage, CPU time per tile (``time.thread_time``:
   less sensitive to the load of a shared machine than wall time, printed beside it):

   - read:    the store window reads the tile needs (each layer's tile or finest ancestor),
              the stores' own tile caches emptied first, the files warm in the OS cache;
   - compose: the layers composed and feathered (`TerrainStack.heights`), its cache empty;
   - apron:   the ring of neighbour nodes (`heights_apron`), the tiles of the sample composed;
   - skirts:  the per-tile metadata for the skirt depths, one vectorised call per level;
   - mesh:    vertices and skirts (`build_tile_mesh` less its normals);
   - normals: the apron normals;
   - upload:  the GPU writes of one slot (vertex buffer, the albedo texture layer and the
              RGBA8 normal (+ coast) layer, the albedo baked from the heights there);
   - total:   `GlobeRenderer.build_meshes` + upload over the sample as a frame loads it
              (stack cache empty, stores warm), process CPU time: the figure the target is
              about.

Targets (printed as PASS/FAIL): total <= 1 ms per tile; the flight's median frame <= 100 ms.

    .venv/bin/python benchmarks/bench_tiles.py [--frames 30] [--sample 300] [--rounds 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from globeview.bench.flight import Flight, shipped_flights_dir
from globeview.bench.harness import Bench, fly, load_terrain, machine, summary
from globeview.bench.report import load_average
from globeview.render import tile_mesh
from globeview.render.renderer import tile_bounds_tuple

TILE_MS = 1.0
FRAME_MS = 100.0


def _clock() -> tuple[float, float]:
    return time.thread_time(), time.perf_counter()


def _since(t: tuple[float, float], n: int) -> tuple[float, float]:
    """(CPU ms, wall ms) per item since ``t``."""
    c, w = _clock()
    return (c - t[0]) * 1e3 / n, (w - t[1]) * 1e3 / n


def _clear_stores(terrain) -> None:
    """Empty the stores' tile caches (their decoded blocks, GDAL's block cache and the OS
    page cache stay warm: a warm store)."""
    for layer in terrain.layers:
        with layer.store._lock:
            layer.store._cache.clear()


def _clear_composed(terrain) -> None:
    """Empty the stack's composed-tile cache only (not the one-time metadata tables)."""
    terrain._tiles.clear()


def stage_times(bench: Bench, keys: list[tuple[int, int, int]]) -> dict[str, tuple[float, float]]:
    """(CPU ms, wall ms) per tile of each stage over ``keys`` (see the module docstring)."""
    terrain = bench.terrain
    renderer = bench.session.renderer
    n = len(keys)
    out: dict[str, tuple[float, float]] = {}
    karr = np.array(keys, dtype=np.int64)

    _clear_stores(terrain)
    t = _clock()
    for key in keys:
        for layer in terrain.visible_layers:
            st = layer.store
            f = max(0, key[0] - st.max_level)
            anc = (key[0] - f, key[1] >> f, key[2] >> f)
            if st.has_tile(*anc):
                st.heights_padded(anc)
    out["read"] = _since(t, n)

    _clear_composed(terrain)  # the stores keep their tiles
    t = _clock()
    heights = [terrain.heights(k) for k in keys]
    out["compose"] = _since(t, n)

    t = _clock()
    aprons = [terrain.heights_apron(k) for k in keys]
    out["apron"] = _since(t, n)

    t = _clock()
    skirts = renderer.skirt_depths(karr)
    out["skirts"] = _since(t, n)

    bounds = [tile_bounds_tuple(k) for k in keys]
    t = _clock()
    for b, h, s in zip(bounds, heights, skirts, strict=True):
        tile_mesh.build_tile_mesh(b, h, float(s))  # without the apron: its own normals ...
    mesh_own = _since(t, n)
    t = _clock()
    for b, h in zip(bounds, heights, strict=True):
        tile_mesh._normals_of(*tile_mesh._Axes(*tile_mesh.node_lonlat(b, h.shape[0])).ecef(h))
    own_normals = _since(t, n)
    # ... less those normals: the vertices and skirts alone.
    out["mesh"] = (mesh_own[0] - own_normals[0], mesh_own[1] - own_normals[1])

    t = _clock()
    for b, a in zip(bounds, aprons, strict=True):
        tile_mesh._vertex_normals_apron(b, a)
    out["normals"] = _since(t, n)

    meshes = [
        tile_mesh.build_tile_mesh(b, h, float(s), apron=a)
        for b, h, s, a in zip(bounds, heights, skirts, aprons, strict=True)
    ]
    pool = renderer.pool
    slots = np.arange(n) % pool.capacity
    bench.ctx.finish()
    t = _clock()
    for slot, m in zip(slots, meshes, strict=True):
        pool._upload(int(slot), m)
    bench.ctx.finish()
    out["upload"] = _since(t, n)
    pool.invalidate()

    _clear_composed(terrain)
    # Process CPU time (GL's too, for the uploads).
    c0, t0 = time.process_time(), time.perf_counter()
    built = renderer.build_meshes(karr)
    for slot, key in zip(slots, keys, strict=True):
        pool._upload(int(slot), built[key])
    bench.ctx.finish()
    out["total"] = ((time.process_time() - c0) * 1e3 / n, (time.perf_counter() - t0) * 1e3 / n)
    pool.invalidate()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=30, help="frames of the flight")
    ap.add_argument("--sample", type=int, default=300, help="tiles replayed per round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--size", default="1280x720")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))

    load_before = load_average()
    flight = Flight.load(shipped_flights_dir() / "big_dem.json")
    bench = Bench(load_terrain(flight.terrain), (w, h))
    try:
        bench.use("chunked-sse", 2.0)
        renderer = bench.session.renderer
        built: list[list[tuple[int, int, int]]] = []  # the tiles each frame built
        inner = renderer.build_meshes

        def recording(keys):
            got = inner(keys)
            built.append(list(got))
            return got

        renderer.build_meshes = recording  # type: ignore[method-assign]
        rows = fly(bench, flight, flight.times(frames=args.frames))
        renderer.build_meshes = inner  # type: ignore[method-assign]
        s = summary(rows)
        uploaded = [r.tiles_uploaded for r in rows] if hasattr(rows[0], "tiles_uploaded") else []

        print(f"Tile build benchmark, {machine(bench.gl_renderer)}, load {load_before[0]:.2f}")
        print(
            f"flight {flight.name!r}, {args.frames} frames, {w}x{h}, chunked-sse, tau 2 px, "
            f"synchronous loading: frame_ms median {s['frame_ms_median']:.1f} (p95 "
            f"{s['frame_ms_p95']:.1f}), lod_ms median {s['lod_ms_median']:.2f}, "
            f"{sum(map(len, built))} tiles built"
            + (f" (median {statistics.median(uploaded):.0f} a frame)" if uploaded else "")
        )

        # Whole frames' loads (a frame's new tiles are neighbours of each other, which the
        # apron stage depends on), from the middle of the flight on, up to --sample tiles.
        sample: list[tuple[int, int, int]] = []
        for frame_keys in built[len(built) // 3 :]:
            if len(sample) >= args.sample:
                break
            sample.extend(frame_keys)
        runs = [stage_times(bench, sample) for _ in range(max(1, args.rounds))]
        print()
        print(f"per tile, {len(sample)} tiles the flight built, median of {len(runs)} rounds:")
        print("| stage | CPU ms | wall ms |")
        print("|---|---:|---:|")
        for stage in runs[0]:
            cpu = statistics.median(r[stage][0] for r in runs)
            wall = statistics.median(r[stage][1] for r in runs)
            print(f"| {stage} | {cpu:.3f} | {wall:.3f} |")
        total = statistics.median(r["total"][0] for r in runs)
    finally:
        bench.release()
    load_after = load_average()
    print()
    print(
        f"{'PASS' if total <= TILE_MS else 'FAIL'}  tile build + upload: {total:.2f} ms CPU "
        f"per tile (target <= {TILE_MS:g} ms)"
    )
    fm = s["frame_ms_median"]
    print(
        f"{'PASS' if fm <= FRAME_MS else 'FAIL'}  big-DEM flight median frame: {fm:.1f} ms "
        f"(target <= {FRAME_MS:g} ms)"
    )
    print(f"load before/after: {load_before[0]:.2f} / {load_after[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
