"""`globeview bench`: scripted camera flights, the papers' experiments, performance budgets
and a memory soak (headless, EGL). Figures depend on the machine: every output names it."""

from __future__ import annotations

import argparse


def positive_int(text: str) -> int:
    """argparse type: a whole number >= 1 (frame counts)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number, not {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (rates)."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, not {text!r}") from None
    if not (math.isfinite(value) and 0.0 < value <= 1000.0):
        raise argparse.ArgumentTypeError(f"must be a finite number in (0, 1000], not {text}")
    return value


def rate(text: str) -> float:
    """argparse type: a frame rate in Hz, a finite number in [0, 1000] (0: unpaced, which
    only an asynchronous flight accepts)."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, not {text!r}") from None
    if not (math.isfinite(value) and 0.0 <= value <= 1000.0):
        raise argparse.ArgumentTypeError(f"must be a finite number in [0, 1000], not {text}")
    return value


def tau(text: str) -> float:
    """argparse type: a screen-space error threshold, checked like the view checks it."""
    from globeview.validate import check_tau

    try:
        return check_tau(float(text))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _check_output_args(args: argparse.Namespace) -> None:
    """Output paths checked before a benchmark runs for minutes (see fileio)."""
    import os

    from globeview.errors import GlobeviewError
    from globeview.fileio import check_output_file, writable_folder_problem

    if getattr(args, "csv", None):
        check_output_file(args.csv, "--csv", (".csv",))
    if args.bench_command == "experiments":
        if os.path.exists(args.out) and not os.path.isdir(args.out):
            raise GlobeviewError(f"--out {args.out} exists and is not a folder")
        problem = writable_folder_problem(args.out)
        if problem is not None:
            raise GlobeviewError(f"--out {args.out}: {problem}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bench_command", metavar="ACTION", required=True)

    p = sub.add_parser("flight", help="render a camera path frame by frame and record figures")
    p.add_argument("path", help="flight JSON file, or a shipped flight's name (canyon_run)")
    p.add_argument("--lod", default="chunked-sse", help="LOD provider plugin")
    p.add_argument("--tau", type=tau, default=2.0, help="screen-space error, pixels")
    p.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT in pixels")
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--frames", type=positive_int, help="frames evenly spaced over the path (default 30)"
    )
    g.add_argument(
        "--fps",
        type=rate,
        help="sample the path at this rate instead; with --async: pace frames at this rate "
        "in wall time (default 60; 0: unpaced)",
    )
    p.add_argument("--csv", help="write one row per frame to this CSV file")
    p.add_argument(
        "--async",
        dest="asynchronous",
        action="store_true",
        help="fly in wall time as the window does: tiles load in the background while "
        "coarser ones stand in; report frame time percentiles, stand-ins and the detail lag",
    )
    p.add_argument(
        "--timeout",
        type=positive_float,
        default=10.0,
        help="--async: seconds after the path's end to wait for a complete view (default 10)",
    )
    p.add_argument(
        "--loader",
        choices=("thread", "process"),
        help="--async: build tiles on loader threads or in worker processes (default: "
        "threads on up to 2 cores, else processes)",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        help="--async: loader threads or processes (default: 1 thread, or cores - 2 processes)",
    )

    p = sub.add_parser("experiments", help="the papers' experiments: CSV, PNG plots, report.md")
    p.add_argument("--out", default="benchmarks/out/experiments", help="output folder")
    p.add_argument("--quick", action="store_true", help="2 taus, 1 frame each, 160x90, embedded")
    p.add_argument("--size", help="WIDTHxHEIGHT (default 640x360; --quick: 160x90)")
    p.add_argument("--frames", type=positive_int, help="timed frames per point (default 3)")
    p.add_argument(
        "--flight",
        help="take the view from this flight's midpoint (default: big_dem; --quick: canyon_run)",
    )
    p.add_argument("--lod", action="append", help="only this provider (repeatable)")

    p = sub.add_parser("check", help="fly the standard flight and compare with the targets")
    p.add_argument("--quick", action="store_true", help="embedded canyon run, 160x90, 3 frames")
    p.add_argument("--frames", type=positive_int, default=30, help="flight frames (default 30)")
    p.add_argument("--strict", action="store_true", help="exit 1 when a target fails")
    p.add_argument("--csv", help="write the flight's per-frame CSV here")

    p = sub.add_parser("soak", help="fly in loops; report RSS drift and GL object counts")
    p.add_argument("--frames", type=positive_int, default=200, help="frames in all (default 200)")
    p.add_argument("--size", default="320x180", help="WIDTHxHEIGHT in pixels")
    p.add_argument("--lod", default="chunked-sse", help="LOD provider plugin")
    p.add_argument(
        "--cycles",
        type=positive_int,
        help="instead of flying: N open-render-close cycles (stores, context, session, one "
        "frame, release); RSS drift after the warm-up (20 cycles), target <= 1 MB",
    )


def run(args: argparse.Namespace) -> int:
    _check_output_args(args)
    return {
        "flight": _flight,
        "experiments": _experiments,
        "check": _check,
        "soak": _soak,
    }[args.bench_command](args)


def _flight(args: argparse.Namespace) -> int:
    from globeview.errors import GlobeviewError

    if args.asynchronous:
        if args.frames is not None:
            raise GlobeviewError("--frames samples a synchronous flight; --async runs in wall time")
        return _flight_async(args)
    if args.fps == 0:
        raise GlobeviewError("--fps 0 (unpaced) is for --async flights only")
    if args.loader is not None or args.workers is not None:
        raise GlobeviewError("--loader and --workers are for --async flights only")
    from globeview.bench.flight import Flight, resolve_flight
    from globeview.bench.harness import (
        Bench,
        fly,
        load_terrain,
        machine,
        parse_size,
        summary,
        write_csv,
    )

    flight = Flight.load(resolve_flight(args.path))
    size = parse_size(args.size)
    times = flight.times(frames=args.frames if args.fps is None else None, fps=args.fps)
    if args.frames is None and args.fps is None:
        times = flight.times(frames=30)
    bench = Bench(load_terrain(flight.terrain), size, lod=args.lod)
    try:
        bench.use(args.lod, args.tau)
        print(f"machine: {machine(bench.gl_renderer)}")
        print(
            f"flight {flight.name!r}: {len(times)} frames over {flight.duration:g} s, "
            f"{size[0]}x{size[1]}, {args.lod}, tau {args.tau:g} px, terrain {flight.terrain}"
        )
        rows = fly(bench, flight, times)
    finally:
        bench.release()
    if args.csv:
        print(f"wrote {write_csv(rows, args.csv)}")
    s = summary(rows)
    print(
        f"frame_ms median {s['frame_ms_median']:.1f} p95 {s['frame_ms_p95']:.1f} "
        f"({s['fps_median']:.1f} fps); lod_ms median {s['lod_ms_median']:.2f}; "
        f"triangles median {s['triangles_median']:.0f}; tiles median {s['tiles_median']:.0f}; "
        f"max SSE {s['max_sse_px']:.2f} px; RSS {s['rss_mb_last']:.0f} MB"
    )
    return 0


def _flight_async(args: argparse.Namespace) -> int:
    """`bench flight --async`: the flight in wall time with background loading
    (`globeview.bench.flight_async`)."""
    from globeview.bench.flight import Flight, resolve_flight
    from globeview.bench.flight_async import (
        ASYNC_CSV_COLUMNS,
        DEFAULT_FPS,
        MARKDOWN_HEADER,
        async_summary,
        fly_async,
        lag_text,
        markdown_row,
        set_loader,
    )
    from globeview.bench.harness import Bench, load_terrain, machine, parse_size, write_csv

    flight = Flight.load(resolve_flight(args.path))
    size = parse_size(args.size)
    fps = DEFAULT_FPS if args.fps is None else args.fps
    bench = Bench(load_terrain(flight.terrain), size, lod=args.lod)
    try:
        bench.use(args.lod, args.tau)
        set_loader(bench.session.renderer, args.loader, args.workers)
        print(f"machine: {machine(bench.gl_renderer)}")
        paced = f"paced at {fps:g} Hz" if fps > 0 else "unpaced"
        print(
            f"flight {flight.name!r} in wall time ({flight.duration:g} s, {paced}), "
            f"{size[0]}x{size[1]}, {args.lod}, tau {args.tau:g} px, terrain {flight.terrain}, "
            "tiles loaded in the background"
        )
        run = fly_async(bench, flight, fps=fps, timeout_s=args.timeout)
    finally:
        bench.release()
    if args.csv:
        print(f"wrote {write_csv(run.rows, args.csv, ASYNC_CSV_COLUMNS)}")
    s = async_summary(run)
    print(
        f"frame_ms p50 {s['frame_ms_p50']:.1f} p95 {s['frame_ms_p95']:.1f} "
        f"p99 {s['frame_ms_p99']:.1f} over {s['frames']} moving frames "
        f"({s['missed']} missed); frames with stand-ins {s['standin_share']:.0%}, "
        f"tiles missing {s['missing_share']:.1%} of those asked; "
        f"detail lag {lag_text(run.detail_lag_s, args.timeout)} ({s['settle_frames']} frames); "
        f"{s['tiles_built']} tiles built, loader {run.loader} "
        f"{s['loader_cpu_ms_per_tile']:.2f} ms CPU a tile; "
        f"render thread {s['cpu_ms_per_frame']:.1f} ms CPU a frame"
    )
    print()
    print(MARKDOWN_HEADER)
    print(markdown_row(flight.name, size, run, args.timeout))
    return 0


def _experiments(args: argparse.Namespace) -> int:
    from pathlib import Path

    from globeview.bench.experiments import QUICK_TAUS, TAUS, run_experiments, standard_view
    from globeview.bench.flight import Flight, resolve_flight
    from globeview.bench.harness import Bench, load_terrain, parse_size

    size = parse_size(args.size or ("160x90" if args.quick else "640x360"))
    flight = Flight.load(resolve_flight(args.flight or ("canyon_run" if args.quick else "big_dem")))
    frames = args.frames or (1 if args.quick else 3)
    bench = Bench(load_terrain(flight.terrain), size)
    try:
        res = run_experiments(
            bench,
            standard_view(flight),
            Path(args.out),
            taus=QUICK_TAUS if args.quick else TAUS,
            frames=frames,
            view_name=f"{flight.name} midpoint",
            providers=args.lod,
        )
    finally:
        bench.release()
    for f in ("tau_sweep.csv", "table1.csv", "report.md"):
        print(f"wrote {Path(args.out) / f}")
    for f in res["files"]:
        print(f"wrote {f}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from globeview.bench.check import run_check

    verdicts = run_check(frames=args.frames, quick=args.quick, csv=args.csv)
    for v in verdicts:
        print(v.line())
    failed = sum(not v.holds for v in verdicts)
    print(f"{len(verdicts) - failed} of {len(verdicts)} targets hold")
    return 1 if (args.strict and failed) else 0


def _soak(args: argparse.Namespace) -> int:
    from globeview.bench.harness import parse_size
    from globeview.bench.soak import run_soak

    if args.cycles is not None:
        return _soak_cycles(args)
    res = run_soak(frames=args.frames, size=parse_size(args.size), lod=args.lod)
    print("frame  lap  RSS MB  buffers textures vaos programs resident_tiles")
    for s in res["samples"]:
        print(
            f"{s['frame']:5d} {s['lap']:4d} {s['rss_mb']:7.1f} {s['buffers']:8d} "
            f"{s['textures']:8d} {s['vaos']:4d} {s['programs']:8d} {s['resident_tiles']:14d}"
        )
    if not res["warmup_complete"]:
        print("too few frames to finish the warm-up lap: no drift figure (use more --frames)")
        return 0
    print(
        f"RSS after warm-up {res['rss_after_warmup']:.1f} MB, last {res['rss_last']:.1f} MB, "
        f"drift {res['rss_drift_mb']:+.1f} MB; GL objects "
        f"{'stable' if res['gl_objects_stable'] else 'CHANGED'}"
    )
    return 0


def _soak_cycles(args: argparse.Namespace) -> int:
    """`bench soak --cycles N`: the open-render-close soak (benchmarks/bench_open_close.py)."""
    from globeview.bench.harness import parse_size
    from globeview.bench.soak import run_open_close

    warmup = max(1, min(20, args.cycles - 1))
    res = run_open_close(args.cycles, parse_size(args.size), args.lod, warmup)
    print(
        f"RSS after {warmup} cycles {res['rss_after_warmup']:.1f} MB, after {args.cycles}: "
        f"{res['rss_last']:.1f} MB; drift {res['rss_drift_mb']:+.2f} MB "
        f"({res['per_cycle_mb'] * 1e3:+.1f} kB per cycle)"
    )
    print(f"objects of the last cycle alive after release: {res['alive_after_release'] or 'none'}")
    verdict = "met" if res["target_met"] else "NOT met"
    print(f"target: drift <= {res['target_mb']:g} MB: {verdict}")
    return 0
