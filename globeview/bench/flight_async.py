"""`bench flight --async`: a flight as the user sees it in the window (issue #27, item 2).

The synchronous flight (`harness.fly`) loads every tile a frame needs before drawing it: each
image is complete and deterministic, and a frame that meets a hundred new tiles takes as
long as building them. The window never waits: tiles load in the background
(`render/tile_loader.py`) and coarser resident ancestors stand in until they arrive. This
driver runs the renderer that way and measures what the window's user sees:

- **Clock**: flight time is wall time since the first frame, so a slow frame makes the next
  pose jump, as on screen. Frames are paced at ``fps`` Hz (the driver sleeps to the next
  period; a frame that runs past the end of its period is *missed*); ``fps`` 0 runs them
  back to back.
- **Motion**: each frame gets the flight's pose at that time and its flight time as the
  pipeline's time stamp (the camera speed LOD providers see); the first pose is loaded
  synchronously before the clock starts (the flight starts from a complete view).
- **Settling**: after the last keyframe the camera holds still and frames go on until the
  view is complete (no tile missing, no ancestor standing in, nothing building, no LOD
  facts pending); the **detail lag** is that frame's end minus the flight's end, or
  infinite when it did not come within ``timeout_s``.

Times: ``frame_ms`` is the wall time of `GlobeSession.render` (selection, uploads, draw,
overlays, glFinish) in milliseconds; ``cpu_ms`` the render thread's CPU time for it;
``wall_s`` seconds since the first frame. The loader's CPU is its workers' own clocks
(`TileLoader.cpu_seconds`).
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

from globeview.bench.flight import Flight, Pose
from globeview.bench.harness import CSV_COLUMNS, Bench, FrameRecord, frame_fields

if TYPE_CHECKING:
    from globeview.render.frame_pipeline import FrameResult
    from globeview.render.renderer import GlobeRenderer

#: Seconds a flight's end may take to reach a complete view before the lag is "> timeout".
SETTLE_TIMEOUT_S = 10.0
#: The window's frame rate the driver paces at by default (Hz).
DEFAULT_FPS = 60.0


@dataclass
class AsyncFrameRecord(FrameRecord):
    """One frame of an asynchronous flight (one CSV row): the synchronous flight's figures
    and what the window's user sees of the loading.

    Attributes (beyond `FrameRecord`'s):
        phase: ``flight`` while the camera follows the path, ``settle`` after its end.
        wall_s: seconds since the first frame began, at this frame's start.
        missed: the frame ended after its period (paced runs only).
        cpu_ms: render-thread CPU milliseconds of the frame.
        tiles_asked: tiles of the provider's render set.
        tiles_missing: of those, not resident (an ancestor or nothing drawn instead).
        tiles_standin: ancestors drawn for missing tiles.
        tiles_building: tiles queued or being built after the frame.
        upload_ms: wall milliseconds of the frame's uploads.
        lod_facts_pending: tiles the LOD could not refine for want of facts (0 where the
            provider does not report it).
        gpu_ms: GPU milliseconds of the frame where the renderer measures it, else NaN.
    """

    phase: str
    wall_s: float
    missed: bool
    cpu_ms: float
    tiles_asked: int
    tiles_missing: int
    tiles_standin: int
    tiles_building: int
    upload_ms: float
    lod_facts_pending: int
    gpu_ms: float


ASYNC_CSV_COLUMNS = CSV_COLUMNS + [
    f.name for f in fields(AsyncFrameRecord) if f.name not in set(CSV_COLUMNS)
]


@dataclass
class AsyncFlight:
    """An asynchronous flight's frames and what its loader did.

    Attributes:
        rows: every frame, flight then settle.
        duration_s: the path's length (s).
        fps: the pacing rate (Hz; 0: unpaced).
        detail_lag_s: seconds from the path's end to the first complete frame's end; inf
            when none came within the timeout.
        tiles_built: tiles the loader built (or failed) during the run.
        loader_cpu_s: the loader workers' CPU seconds during the run.
        loader: the loader's kind and workers, e.g. ``thread x1``.
    """

    rows: list[AsyncFrameRecord]
    duration_s: float
    fps: float
    detail_lag_s: float
    tiles_built: int
    loader_cpu_s: float
    loader: str


def set_loader(
    renderer: GlobeRenderer, kind: str | None = None, workers: int | None = None
) -> None:
    """Make ``renderer``'s background loader ``kind`` ("thread" or "process"; None: the
    machine's default, `tile_workers.default_loader`) with ``workers`` (None: 1 thread, or
    all cores but two processes, at least 1); a loader already made is shut down. Batches of
    4 tiles for threads, 8 for processes (issue #27)."""
    import os

    from globeview.render.tile_workers import default_loader

    kind = kind or default_loader()[0]
    if workers is None:
        workers = 1 if kind == "thread" else max(1, (os.cpu_count() or 1) - 2)
    if renderer.loader is not None:
        renderer.loader.shutdown()
        renderer.loader = None
    renderer.load_kind, renderer.load_workers = kind, int(workers)
    renderer.load_batch = 4 if kind == "thread" else 8


def fly_async(
    bench: Bench,
    flight: Flight,
    fps: float = DEFAULT_FPS,
    timeout_s: float = SETTLE_TIMEOUT_S,
    clock: Callable[[], float] = time.perf_counter,
    sleep: Callable[[float], None] = time.sleep,
) -> AsyncFlight:
    """Fly ``flight`` in wall time with background loading (module docstring) and return its
    frames. ``fps``: pacing (Hz, 0 unpaced); ``timeout_s``: the longest settle."""
    if not (math.isfinite(fps) and fps >= 0.0):
        raise ValueError(f"fps must be a finite number >= 0, not {fps}")
    session = bench.session
    renderer = session.renderer
    t0 = float(flight.t[0])
    bench.set_pose(flight.pose(t0), cut=True)
    renderer.async_loading = False
    start, _ = bench.frame(t0)  # the start, complete: the flight begins from a loaded view
    renderer.async_loading = True
    renderer.on_tile_ready = None  # frames are continuous: no wake-up needed
    procs = renderer._ensure_loader().processes
    if procs is not None:  # worker processes started and warm before the clock, as a
        # window's are after its first view: the start's tiles built in each
        procs.warm(start.render_set.keys)  # type: ignore[attr-defined]
    motion = session.pipeline.motion
    motion.reset()
    try:
        return _run(bench, flight, fps, timeout_s, clock, sleep)
    finally:
        renderer.async_loading = False


def _run(
    bench: Bench,
    flight: Flight,
    fps: float,
    timeout_s: float,
    clock: Callable[[], float],
    sleep: Callable[[float], None],
) -> AsyncFlight:
    renderer = bench.session.renderer
    loader = renderer._ensure_loader()
    built0, cpu0 = loader.tiles_built, loader.cpu_seconds()
    t0, duration = float(flight.t[0]), flight.duration
    period = 1.0 / fps if fps > 0 else 0.0
    rows: list[AsyncFrameRecord] = []
    lag = math.inf
    start = clock()
    while True:
        wall = clock() - start
        settling = wall >= duration
        pose = flight.pose(t0 + min(wall, duration))
        bench.set_pose(pose)
        c0 = time.thread_time()
        result, frame_ms = bench.frame(t0 + wall)
        cpu_ms = (time.thread_time() - c0) * 1e3
        end = clock() - start
        missed = period > 0 and end > (math.floor(wall / period) + 1) * period
        row = _record(len(rows), (wall, frame_ms, cpu_ms), pose, result, settling, missed, bench)
        rows.append(row)
        if settling and _complete(row):
            lag = end - duration
            break
        if settling and end - duration > timeout_s:
            break
        if period > 0:  # sleep to the next period boundary
            wait = (math.floor(end / period) + 1) * period - (clock() - start)
            if wait > 0:
                sleep(wait)
    return AsyncFlight(
        rows=rows,
        duration_s=duration,
        fps=fps,
        detail_lag_s=lag,
        tiles_built=loader.tiles_built - built0,
        loader_cpu_s=loader.cpu_seconds() - cpu0,
        loader=loader.describe(),
    )


def _complete(row: AsyncFrameRecord) -> bool:
    """Whether a frame shows the complete view: every tile asked for drawn, nothing loading."""
    return (
        row.tiles_missing == 0
        and row.tiles_standin == 0
        and row.tiles_building == 0
        and row.lod_facts_pending == 0
    )


def _record(
    i: int,
    timing: tuple[float, float, float],
    pose: Pose,
    result: FrameResult,
    settling: bool,
    missed: bool,
    bench: Bench,
) -> AsyncFrameRecord:
    """Frame i's row; timing is (wall clock since the start in s, frame ms, render-thread
    CPU ms)."""
    wall, frame_ms, cpu_ms = timing
    st = result.stats
    extra = st.extra
    loader = bench.session.renderer.loader
    return AsyncFrameRecord(
        **frame_fields(bench, i, wall, pose, result, frame_ms),
        phase="settle" if settling else "flight",
        wall_s=round(wall, 4),
        missed=bool(missed),
        cpu_ms=cpu_ms,
        tiles_asked=len(result.render_set),
        tiles_missing=int(extra.get("tiles_missing", 0)),
        tiles_standin=int(extra.get("tiles_standin", 0)),
        tiles_building=0 if loader is None else loader.building,
        upload_ms=float(extra.get("upload_ms", 0.0)),
        lod_facts_pending=int(result.render_set.stats.get("lod_facts_pending", 0)),
        gpu_ms=float(extra.get("gpu_ms", math.nan)),
    )


def async_summary(run: AsyncFlight) -> dict[str, float]:
    """The flight's figures: frame time percentiles (ms) over the frames while the camera
    moves, missed frames, the share of them drawn with stand-ins and the mean share of asked
    tiles missing, the detail lag (s), tiles built and the loader's CPU per tile (ms), the
    render thread's CPU per frame (ms), and how many frames settling took."""
    moving = [r for r in run.rows if r.phase == "flight"] or run.rows
    fm = np.array([r.frame_ms for r in moving])
    asked = np.array([max(r.tiles_asked, 1) for r in moving])
    missing = np.array([r.tiles_missing for r in moving])
    built = run.tiles_built
    return {
        "frames": len(moving),
        "settle_frames": len(run.rows) - len(moving),
        "frame_ms_p50": float(np.percentile(fm, 50)),
        "frame_ms_p95": float(np.percentile(fm, 95)),
        "frame_ms_p99": float(np.percentile(fm, 99)),
        "missed": sum(r.missed for r in moving),
        "standin_share": float(np.mean([r.tiles_standin > 0 for r in moving])),
        "missing_share": float(np.mean(missing / asked)),
        "detail_lag_s": run.detail_lag_s,
        "tiles_built": built,
        "loader_cpu_ms_per_tile": run.loader_cpu_s * 1e3 / built if built else math.nan,
        "cpu_ms_per_frame": statistics.median(r.cpu_ms for r in moving),
        "triangles_median": statistics.median(r.triangles for r in moving),
    }


def lag_text(lag_s: float, timeout_s: float = SETTLE_TIMEOUT_S) -> str:
    """The detail lag for people: seconds, or "> timeout" when the view never completed."""
    return f"{lag_s:.2f} s" if math.isfinite(lag_s) else f"> {timeout_s:g} s"


#: The Markdown table's header for `markdown_row` (one row per flight).
MARKDOWN_HEADER = (
    "| flight | size | loader | fps | frames | p50 ms | p95 ms | p99 ms | missed "
    "| frames with stand-ins | tiles missing | detail lag | tiles built | loader CPU ms/tile "
    "| main CPU ms/frame |\n"
    "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
)


def markdown_row(
    name: str, size: tuple[int, int], run: AsyncFlight, timeout_s: float = SETTLE_TIMEOUT_S
) -> str:
    """One flight's figures as a row of `MARKDOWN_HEADER`'s table."""
    s = async_summary(run)
    fps = f"{run.fps:g}" if run.fps > 0 else "unpaced"
    per_tile = s["loader_cpu_ms_per_tile"]
    return (
        f"| {name} | {size[0]}x{size[1]} | {run.loader} | {fps} | {s['frames']} "
        f"| {s['frame_ms_p50']:.1f} | {s['frame_ms_p95']:.1f} | {s['frame_ms_p99']:.1f} "
        f"| {s['missed']} | {s['standin_share']:.0%} | {s['missing_share']:.1%} "
        f"| {lag_text(run.detail_lag_s, timeout_s)} | {s['tiles_built']} "
        f"| {per_tile:.2f} | {s['cpu_ms_per_frame']:.1f} |"
    )
