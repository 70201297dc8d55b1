"""Collapse cost: frame_ms, lod_ms and draw_ms of the same views with and without the
terrain collapse (median of N frames, a tiny camera turn per frame so every frame selects and
draws), still and animating (``anim``: the ratio changes every frame, as while the tool's
collapse animation runs, so nothing displaced can be reused). Prints a Markdown table. The
collapse's displacement runs in the vertex shader; on the CPU it only moves tile bounding
points (9 per tile corner lattice), never vertices.

``cpu_ms`` is the process's CPU time per frame (all threads, llvmpipe's too: steadier than
wall time on a loaded machine). The ``off, still cam`` and ``on, still cam`` rows repeat the
view with the camera not moving at all (a window repainting a still view: the selection is
reused, nothing is re-uploaded), so what is left is the draw; ``on, plain LOD`` draws the
collapse over the tiles and strides of the view without it (the provider is shown no
displacement): the vertex shader's bend by itself, without the triangles the fold adds.

Targets (issue #17, item 5): a still collapse <= +10 % frame time over the same view without
it; an animating collapse's lod_ms <= 5 ms.

    .venv/bin/python benchmarks/bench_collapse.py [--frames 9] [--size 1280x720]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from dataclasses import replace

from globeview.bench.harness import Bench, machine, parse_size
from globeview.errors import GlobeviewError
from globeview.lod.render_set import RenderSet
from globeview.lod.view_state import ViewState
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.embedded import embedded_stores

# name -> (camera lon, lat, height, heading, pitch), (A lon, lat, B lon, lat, ratio)
VIEWS = {
    "Pacific NW from 1 300 km, r 0.05": (
        (-122.3, 45.5, 1.3e6, 0.0, -90.0),
        (-122.1, 43.0, -122.6, 48.05, 0.05),
    ),
    "oblique 500 km, r 0.1": (
        (-120.0, 44.0, 5.0e5, 300.0, -55.0),
        (-123.0, 48.5, -118.0, 44.0, 0.1),
    ),
}


#: Issue #17 item 5: a still collapse's extra frame time (fraction), an animating one's lod_ms.
STILL_TARGET = 0.10
ANIM_LOD_TARGET_MS = 5.0


def animate(bench: Bench, tool, cam: tuple, pair: tuple, frames: int) -> dict[str, float]:
    """Medians over ``frames`` frames of the tool's own collapse animation (A and B set with
    ``animate=True``; the pipeline advances it with each frame's time stamp, ``frames``
    frames spread over its `ANIMATION_S`), a tiny turn per frame. The first frame (ratio 1)
    is not counted."""
    from globeview.plugins.builtin.collapse.tool import ANIMATION_S

    bench.set_pose(cam, cut=True)
    tool.set_points(*pair[:4], pair[4], animate=True)
    t0 = 1000.0
    bench.frame(t0)  # starts the animation (progress 0)
    rows = []
    n = max(int(frames), 1)
    for i in range(n):
        bench.session.camera.fly_yaw(0.01 * (-1) ** i)
        r, ms = bench.frame(t0 + ANIMATION_S * (i + 1) / (n + 1))
        rows.append((ms, r.stats.lod_ms, r.stats.draw_ms, r.stats.triangles))
    bench.frame(t0 + 2.0 * ANIMATION_S)  # ends it
    cols = list(zip(*rows, strict=True))
    med = statistics.median
    return {
        "frame_ms": med(cols[0]),
        "lod_ms": med(cols[1]),
        "draw_ms": med(cols[2]),
        "triangles": med(cols[3]),
    }


def measured(bench: Bench, cam: tuple, frames: int, turn_deg: float) -> dict[str, float]:
    """`Bench.measure` of the view after a warm frame (tiles uploaded), plus ``cpu_ms``: the
    process's CPU time per frame over the measure (its own warm-up frame counted in, as
    `bench_overlays.measured` does)."""
    bench.set_pose(cam, cut=True)
    bench.frame()
    t0 = time.process_time()
    m = bench.measure(cam, frames, turn_deg=turn_deg)
    m["cpu_ms"] = (time.process_time() - t0) * 1e3 / (frames + 1)
    return m


def plain_lod(bench: Bench, cam: tuple, frames: int) -> dict[str, float]:
    """`measured` with the collapse drawn (its shader, uniforms and overlay) over the tiles
    and strides of the view without it (the provider sees no displacement): what the
    vertex shader's bend costs by itself, apart from the triangles the fold adds."""
    session = bench.session
    select = session.select

    def undisplaced(view: ViewState) -> RenderSet:
        return select(replace(view, displace=None, displacement_bend=None, displacement_key=None))

    session.select = undisplaced  # type: ignore[method-assign]
    try:
        return measured(bench, cam, frames, 0.01)
    finally:
        del session.select  # the class's method again


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=9)
    ap.add_argument("--size", default="1280x720")
    args = ap.parse_args()
    size = parse_size(args.size)
    # The one harness (globeview.bench.harness): frames through the session's FramePipeline.
    bench = Bench(TerrainStack.from_stores(embedded_stores()), size)
    session = bench.session
    tool = session.tools()["collapse"]
    load = os.getloadavg()
    print(f"Collapse cost, {size[0]}x{size[1]}, chunked-sse, tau 2 px, {args.frames} frames")
    print(f"{machine(bench.gl_renderer)}; load {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    print()
    print("| view | collapse | triangles | frame_ms | lod_ms | draw_ms | cpu_ms |")
    print("|---|---|---:|---:|---:|---:|---:|")
    still_ratio: list[tuple[float, str, float, float]] = []
    anim_lod: list[tuple[float, str]] = []
    for name, (cam, pair) in VIEWS.items():
        session.activate_tool(None)
        # A tiny camera turn per frame so every frame really selects and draws.
        off = measured(bench, cam, args.frames, 0.01)
        off_still = measured(bench, cam, args.frames, 0.0)
        tool.set_points(*pair[:4], pair[4])
        session.activate_tool("collapse")
        on = measured(bench, cam, args.frames, 0.01)
        on_still = measured(bench, cam, args.frames, 0.0)
        shader_only = plain_lod(bench, cam, args.frames)
        t0 = time.process_time()
        anim = animate(bench, tool, cam, pair, args.frames)
        anim["cpu_ms"] = (time.process_time() - t0) * 1e3 / (args.frames + 2)
        rows = (
            ("off", off),
            ("on", on),
            ("anim", anim),
            ("off, still cam", off_still),
            ("on, still cam", on_still),
            ("on, plain LOD", shader_only),
        )
        for label, m in rows:
            print(
                f"| {name} | {label} | {m['triangles']:.0f} | {m['frame_ms']:.1f} | "
                f"{m['lod_ms']:.1f} | {m['draw_ms']:.1f} | {m['cpu_ms']:.1f} |"
            )
        still_ratio.append(
            (
                on["frame_ms"] / off["frame_ms"],
                name,
                on["cpu_ms"] / off["cpu_ms"],
                on_still["cpu_ms"] / off_still["cpu_ms"],
            )
        )
        anim_lod.append((anim["lod_ms"], name))
    bench.release()
    ratio, where, cpu, cpu_still = max(still_ratio)
    print()
    print(
        f"- target: a still collapse <= +{STILL_TARGET:.0%} frame time: +{ratio - 1:.0%} "
        f"({where}; CPU +{cpu - 1:.0%}, still camera CPU +{cpu_still - 1:.0%}): "
        f"{'met' if ratio <= 1 + STILL_TARGET else 'not met'}"
    )
    lod, where = max(anim_lod)
    print(
        f"- target: an animating collapse's lod_ms <= {ANIM_LOD_TARGET_MS:g} ms: {lod:.1f} ms "
        f"({where}): {'met' if lod <= ANIM_LOD_TARGET_MS else 'not met'}"
    )
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except GlobeviewError as exc:  # bad arguments: one line, exit 2 (as the CLI)
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
