"""Collapse cost: frame_ms, lod_ms and draw_ms of the same views with and without the
terrain collapse (median of N frames, a tiny camera turn per frame so every frame selects and
draws). Prints a Markdown table. The collapse's displacement runs in the vertex shader; on the
CPU it only moves tile bounding points (9 per tile corner lattice), never vertices.

    .venv/bin/python benchmarks/bench_collapse.py [--frames 9] [--size 1280x720]
"""

from __future__ import annotations

import argparse

from globeview.bench.harness import Bench, parse_size
from globeview.terrain.embedded import embedded_stores
from globeview.terrain.stack import TerrainStack

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
    print(f"Collapse cost, {size[0]}x{size[1]}, chunked-sse, tau 2 px, {bench.gl_renderer}")
    print()
    print("| view | collapse | triangles | frame_ms | lod_ms | draw_ms |")
    print("|---|---|---:|---:|---:|---:|")
    for name, (cam, pair) in VIEWS.items():
        session.activate_tool(None)
        # A tiny camera turn per frame so every frame really selects and draws.
        off = bench.measure(cam, args.frames, turn_deg=0.01)
        tool.set_points(*pair[:4], pair[4])
        session.activate_tool("collapse")
        on = bench.measure(cam, args.frames, turn_deg=0.01)
        for label, m in (("off", off), ("on", on)):
            print(
                f"| {name} | {label} | {m['triangles']:.0f} | {m['frame_ms']:.1f} | "
                f"{m['lod_ms']:.1f} | {m['draw_ms']:.1f} |"
            )
    bench.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
