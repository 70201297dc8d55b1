"""Motion benchmark (issue #27, item 2): the shipped flights as the window's user sees them.

Each flight runs in a fresh headless session through `globeview.bench.flight_async.fly_async`
(what `globeview bench flight NAME --async` runs): wall-time frames paced at the window's
rate, tiles loaded in the background by the window's loader while coarser ancestors stand
in, then the camera held still until the view is complete. One Markdown row per flight:
frame time percentiles over the moving frames, missed frames, the share of frames drawn with
stand-ins, the mean share of asked tiles missing, the detail lag (path's end -> complete
view), tiles built and the loader's CPU per tile, the render thread's CPU per frame.

Defaults follow the machine: on software GL (llvmpipe) 1280x720 at 60 Hz; on a GPU 3840x2160
at 240 Hz. Targets (printed as PASS/FAIL) for canyon_run: llvmpipe p95 <= 50 ms and detail
lag <= 2 s; GPU p95 <= 16.7 ms and detail lag <= 0.5 s.

    .venv/bin/python benchmarks/bench_flight_async.py [--flights canyon_run,fast_pan]
        [--size 1280x720] [--fps 60] [--csv-dir DIR]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from globeview.bench.flight import Flight, resolve_flight
from globeview.bench.flight_async import (
    ASYNC_CSV_COLUMNS,
    MARKDOWN_HEADER,
    async_summary,
    fly_async,
    lag_text,
    markdown_row,
)
from globeview.bench.harness import Bench, load_terrain, machine, parse_size, write_csv
from globeview.bench.report import load_average, machine_tag

FLIGHTS = ("canyon_run", "fast_pan", "global_approach", "regional_oblique")
#: Per machine kind: (size, fps, p95 target ms, detail lag target s) for canyon_run.
SETTINGS = {
    "cpu": ("1280x720", 60.0, 50.0, 2.0),
    "gpu": ("3840x2160", 240.0, 16.7, 0.5),
}
TARGET_FLIGHT = "canyon_run"


def fly_one(name: str, size: tuple[int, int], fps: float, lod: str, tau: float, csv_dir):
    """One flight in a fresh session; returns its `AsyncFlight`."""
    flight = Flight.load(resolve_flight(name))
    bench = Bench(load_terrain(flight.terrain), size, lod=lod)
    try:
        bench.use(lod, tau)
        run = fly_async(bench, flight, fps=fps)
    finally:
        bench.release()
    if csv_dir is not None:
        write_csv(run.rows, Path(csv_dir) / f"{name}.csv", ASYNC_CSV_COLUMNS)
    return run


def gl_renderer() -> str:
    """The GL renderer the flights will draw with (a throwaway EGL context)."""
    from globeview.render.offscreen import create_headless_context, release_headless_context

    ctx = create_headless_context()
    try:
        return str(ctx.info.get("GL_RENDERER", "?"))
    finally:
        release_headless_context(ctx)


def print_targets(run, size: tuple[int, int], p95_target: float, lag_target: float) -> None:
    """PASS/FAIL lines of the target flight's p95 frame time and detail lag."""
    s = async_summary(run)
    p95, lag = s["frame_ms_p95"], run.detail_lag_s
    where = f"{TARGET_FLIGHT} {size[0]}x{size[1]}"
    print(
        f"{'PASS' if p95 <= p95_target else 'FAIL'}  {where}: frame p95 {p95:.1f} ms "
        f"(target <= {p95_target:g} ms)"
    )
    ok = math.isfinite(lag) and lag <= lag_target
    print(
        f"{'PASS' if ok else 'FAIL'}  {where}: detail lag {lag_text(lag)} "
        f"(target <= {lag_target:g} s)"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", default=",".join(FLIGHTS), help="comma-separated flights")
    ap.add_argument("--size", help="WIDTHxHEIGHT (default: 1280x720 llvmpipe, 3840x2160 GPU)")
    ap.add_argument("--fps", type=float, help="pacing, Hz (default 60 llvmpipe, 240 GPU; 0 off)")
    ap.add_argument("--lod", default="chunked-sse")
    ap.add_argument("--tau", type=float, default=2.0)
    ap.add_argument("--csv-dir", help="write each flight's frames to DIR/NAME.csv")
    args = ap.parse_args()

    load0 = load_average()
    gl = gl_renderer()
    dsize, dfps, p95_target, lag_target = SETTINGS[machine_tag(gl)]
    size = parse_size(args.size or dsize)
    fps = dfps if args.fps is None else args.fps
    print(f"Motion benchmark, {machine(gl)}, load {load0[0]:.2f}")
    print(
        f"{size[0]}x{size[1]}, {args.lod}, tau {args.tau:g} px, frames paced at {fps:g} Hz "
        "in wall time (0: unpaced), tiles loaded in the background by the window's loader; "
        "percentiles over the moving frames"
    )
    print()
    print(MARKDOWN_HEADER)
    target = None
    for name in args.flights.split(","):
        run = fly_one(name, size, fps, args.lod, args.tau, args.csv_dir)
        print(markdown_row(name, size, run), flush=True)
        if name == TARGET_FLIGHT:
            target = run
    print()
    if target is not None:
        print_targets(target, size, p95_target, lag_target)
    print(f"load before/after: {load0[0]:.2f} / {load_average()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
