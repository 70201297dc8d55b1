"""Where a moving frame of `globeview bench flight NAME --async` goes (issue #27): wall and
render-thread CPU milliseconds a frame of each step of the frame, over the flight's moving
frames (the start's synchronous load and the settling frames left out), from timers wrapped
around the steps of one run as `benchmarks/bench_flight_async.py` makes it.

Steps (inclusive; an indented one is part of the one above it): LOD selection
(`GlobeSession.select`), loading (`GlobeRenderer.load`: the uploads of finished tiles
`TilePool.load`, stand-ins `substitute_missing`, the requests to the loader), the terrain
draw (`draw_terrain`: block strides, edge stitching, index patterns, the multi-draw call
`render_indirect`, in which llvmpipe shades the vertices on the calling thread), overlays,
and `ctx.finish` (waiting for llvmpipe's raster threads or the GPU). ``rest`` is the frame's
time outside them (the view, the tool, stats). CPU is `time.thread_time` of the render
thread; the process's other threads (llvmpipe's rasterisers, the tile loader) are reported
as totals, so a loaded machine inflates the CPU columns less than the wall ones.

    .venv/bin/python benchmarks/profile_flight_async.py [canyon_run] [--size 1280x720]
        [--fps 60] [--profile 25]   # + cProfile of the moving frames (render-thread CPU)
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import math
import pstats
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import moderngl

import globeview.lod.tile_cache as tile_cache
import globeview.lod.tile_indices as tile_indices
import globeview.render.renderer as renderer_module
from globeview.bench import flight_async
from globeview.bench.flight import Flight, resolve_flight
from globeview.bench.flight_async import async_summary, fly_async, lag_text
from globeview.bench.harness import Bench, load_terrain, machine, parse_size
from globeview.bench.report import load_average


@dataclass
class Step:
    """One timed step: inclusive wall and render-thread CPU seconds over its calls."""

    label: str
    depth: int
    calls: int = 0
    wall_s: float = 0.0
    cpu_s: float = 0.0


class Timers:
    """Timers wrapped around named callables, counting only while ``on``."""

    def __init__(self) -> None:
        self.steps: dict[str, Step] = {}
        self.on = False
        #: Process CPU seconds (all threads) over the counted frames.
        self.process_s = 0.0
        #: Tiles whose LOD facts were computed (`tile_cache.tile_facts`) in counted frames.
        self.fact_tiles = 0
        #: The tile loader's CPU seconds over the counted frames.
        self.loader_s = 0.0
        self._p0 = self._l0 = 0.0
        self.loader_cpu: Callable[[], float] = lambda: 0.0
        self._undo: list[Callable[[], None]] = []

    def wrap(self, owner: Any, name: str, label: str, depth: int) -> None:
        """Time ``owner.name`` (an instance's, a class's or a module's attribute)."""
        step = self.steps.setdefault(label, Step(label, depth))
        original = getattr(owner, name)
        had_own = name in getattr(owner, "__dict__", {})

        @functools.wraps(original)
        def timed(*args: Any, **kwargs: Any) -> Any:
            if not self.on:
                return original(*args, **kwargs)
            w0, c0 = time.perf_counter(), time.thread_time()
            try:
                return original(*args, **kwargs)
            finally:
                step.calls += 1
                step.wall_s += time.perf_counter() - w0
                step.cpu_s += time.thread_time() - c0

        setattr(owner, name, timed)
        if had_own:
            self._undo.append(lambda: setattr(owner, name, original))
        else:
            self._undo.append(lambda: delattr(owner, name))

    def restore(self) -> None:
        for undo in reversed(self._undo):
            undo()
        self._undo = []


def instrument(bench: Bench) -> Timers:
    """`Timers` around the steps of a frame of ``bench``'s session (module docstring)."""
    t = Timers()
    session = bench.session
    r = session.renderer
    t.wrap(session, "render", "frame (GlobeSession.render)", 0)
    t.wrap(session, "select", "LOD selection (select)", 1)
    t.wrap(tile_cache, "tile_facts", "facts of tiles seen first (tile_facts)", 2)
    counted = tile_cache.tile_facts

    def count_tiles(terrain: Any, level: int, x: Any, *rest: Any) -> Any:
        if t.on:
            t.fact_tiles += len(x)
        return counted(terrain, level, x, *rest)

    tile_cache.tile_facts = count_tiles  # type: ignore[assignment]
    t._undo.append(lambda: setattr(tile_cache, "tile_facts", counted))
    t.wrap(r, "load", "loading (GlobeRenderer.load)", 1)
    t.wrap(r.pool, "load", "tile uploads (TilePool.load)", 2)
    t.wrap(renderer_module, "substitute_missing", "stand-ins (substitute_missing)", 2)
    t.wrap(renderer_module, "coarse_standins", "coarse stand-ins (coarse_standins)", 2)
    t.wrap(renderer_module, "tile_priority", "request order (tile_priority)", 2)
    t.wrap(r, "draw_terrain", "terrain draw (draw_terrain)", 1)
    t.wrap(r, "block_strides", "block strides (block_strides)", 2)
    t.wrap(renderer_module, "stitch_tile_edges", "edge stitching (stitch_tile_edges)", 2)
    t.wrap(r.indices, "patterns", "index patterns (IndexPool.patterns)", 2)
    t.wrap(tile_indices, "_build_grid_indices", "new index variants (grid_indices)", 2)
    t.wrap(moderngl.VertexArray, "render_indirect", "draw call (render_indirect)", 2)
    t.wrap(r, "draw_overlays", "overlays (draw_overlays)", 1)
    t.wrap(moderngl.Context, "finish", "GPU wait (ctx.finish)", 1)
    t.loader_cpu = lambda: 0.0 if r.loader is None else r.loader.cpu_seconds()
    return t


@contextmanager
def moving_frames_only(
    timers: Timers, flight: Flight, profile: cProfile.Profile | None
) -> Iterator[None]:
    """Count (and profile) only the flight's moving frames: `fly_async`'s start frame is
    drawn before `_run` begins counting, and counting stops at the first pose asked for at
    the path's end (the settle frames')."""
    original_run = flight_async._run
    end = float(flight.t[0]) + flight.duration

    def stop() -> None:
        if timers.on:
            if profile is not None:
                profile.disable()
            timers.process_s += time.process_time() - timers._p0
            timers.loader_s += timers.loader_cpu() - timers._l0
        timers.on = False

    def run(*args: Any, **kwargs: Any) -> Any:
        timers.on = True
        timers._p0, timers._l0 = time.process_time(), timers.loader_cpu()
        if profile is not None:
            profile.enable()
        try:
            return original_run(*args, **kwargs)
        finally:
            stop()

    original_pose = flight.pose

    def pose(t: float) -> Any:
        if t >= end:
            stop()
        return original_pose(t)

    flight_async._run = run  # type: ignore[assignment]
    flight.pose = pose  # type: ignore[method-assign]
    try:
        yield
    finally:
        flight_async._run = original_run  # type: ignore[assignment]
        del flight.pose


def report(timers: Timers, frames: int, frame_wall_s: float) -> None:
    """The steps' table: per moving frame, ms wall and render-thread CPU, share of wall."""
    print("| step | calls/frame | wall ms/frame | CPU ms/frame | share of frame wall |")
    print("|---|---:|---:|---:|---:|")
    rest_wall = rest_cpu = 0.0
    for step in timers.steps.values():
        pad = "&nbsp;&nbsp;" * step.depth
        share = step.wall_s / frame_wall_s if frame_wall_s > 0 else math.nan
        print(
            f"| {pad}{step.label} | {step.calls / frames:.2f} | {step.wall_s * 1e3 / frames:.1f} "
            f"| {step.cpu_s * 1e3 / frames:.1f} | {share:.0%} |"
        )
        if step.depth == 1:
            rest_wall += step.wall_s
            rest_cpu += step.cpu_s
    frame = timers.steps["frame (GlobeSession.render)"]
    print(
        f"| &nbsp;&nbsp;rest (view, tool, stats) | | "
        f"{(frame.wall_s - rest_wall) * 1e3 / frames:.1f} "
        f"| {(frame.cpu_s - rest_cpu) * 1e3 / frames:.1f} "
        f"| {(frame.wall_s - rest_wall) / frame_wall_s:.0%} |"
    )


def print_run(run: Any, timers: Timers, size: tuple[int, int], how: str) -> None:
    """The flight's figures, the steps' table, the process's CPU and the settling."""
    s = async_summary(run)
    frames = int(s["frames"])
    moving = [r for r in run.rows if r.phase == "flight"]
    main_cpu = sum(r.cpu_ms for r in moving) / 1e3
    print(
        f"{size[0]}x{size[1]}, {how}, loader {run.loader}: {frames} moving frames, "
        f"p50 {s['frame_ms_p50']:.1f} ms, p95 {s['frame_ms_p95']:.1f} ms, detail lag "
        f"{lag_text(run.detail_lag_s)}, {s['tiles_built']} tiles built, median "
        f"{s['triangles_median']:.0f} triangles"
    )
    print()
    report(timers, frames, timers.steps["frame (GlobeSession.render)"].wall_s)
    print()
    print(
        f"Moving frames: process CPU {timers.process_s * 1e3 / frames:.1f} ms a frame = the "
        f"render thread {main_cpu * 1e3 / frames:.1f} + the tile loader "
        f"{timers.loader_s * 1e3 / frames:.1f} + llvmpipe's raster threads and the rest "
        f"{(timers.process_s - main_cpu - timers.loader_s) * 1e3 / frames:.1f}; loader "
        f"{run.loader_cpu_s * 1e3 / max(s['tiles_built'], 1):.2f} ms CPU a tile (whole run); "
        f"LOD facts of {timers.fact_tiles / frames:.0f} tiles a frame computed; "
        f"median {statistics.median(r.tiles_asked for r in moving):.0f} tiles asked, "
        f"{statistics.median(r.tiles_drawn for r in moving):.0f} drawn; load after "
        f"{load_average()[0]:.2f}"
    )
    settle = [r for r in run.rows if r.phase == "settle"]
    if settle:
        settle_loader_s = run.loader_cpu_s - timers.loader_s
        print(
            f"Settling: at the path's end {settle[0].tiles_missing} of {settle[0].tiles_asked} "
            f"tiles missing; {len(settle)} frames to the complete view "
            f"({lag_text(run.detail_lag_s)}), the tile loader {settle_loader_s:.2f} s CPU "
            "meanwhile"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("flight", nargs="?", default="canyon_run")
    ap.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT (default 1280x720)")
    ap.add_argument("--fps", type=float, default=60.0, help="pacing, Hz (default 60; 0 off)")
    ap.add_argument("--lod", default="chunked-sse")
    ap.add_argument("--tau", type=float, default=2.0)
    ap.add_argument("--profile", type=int, default=0, help="cProfile: print the N top functions")
    ap.add_argument("--dump", help="with --profile: also write the pstats file here")
    args = ap.parse_args(argv)

    size = parse_size(args.size)
    flight = Flight.load(resolve_flight(args.flight))
    load0 = load_average()
    bench = Bench(load_terrain(flight.terrain), size, lod=args.lod)
    # The render thread's CPU clock: a loaded machine's waits are not charged to a function.
    profile = cProfile.Profile(time.thread_time) if args.profile else None
    try:
        bench.use(args.lod, args.tau)
        timers = instrument(bench)
        with moving_frames_only(timers, flight, profile):
            run = fly_async(bench, flight, fps=args.fps)
        timers.restore()
        gl = bench.gl_renderer
    finally:
        bench.release()
    print(f"Moving frames of {args.flight} --async, {machine(gl)}, load {load0[0]:.2f}")
    print_run(run, timers, size, f"{args.lod}, tau {args.tau:g} px, {args.fps:g} Hz")
    if profile is not None:
        print()
        stats = pstats.Stats(profile, stream=sys.stdout)
        if args.dump:
            stats.dump_stats(args.dump)
        stats.sort_stats("tottime").print_stats(args.profile)
        stats.sort_stats("cumulative").print_stats(args.profile)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
