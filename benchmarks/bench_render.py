"""Render benchmark: triangles, frame_ms and lod_ms for fixed views over the embedded data.

Prints a Markdown table (and writes it with --out). Figures depend on the machine: the
header says which. Performance targets live here, never in timed tests.

    .venv/bin/python benchmarks/bench_render.py [--frames 15] [--size 1280x720] [--lod NAME]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

from globeview.bench.harness import Bench, parse_size
from globeview.bench.views import VIEWS
from globeview.terrain.embedded import embedded_stores
from globeview.terrain.stack import TerrainStack

TARGET_MS = 50.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=15)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--tau", type=float, default=2.0)
    ap.add_argument("--lod", default="chunked-sse", help="LOD provider plugin")
    ap.add_argument("--out", help="also write the Markdown table to this file")
    args = ap.parse_args()
    size = parse_size(args.size)

    # The one harness (globeview.bench.harness): frames through the session's FramePipeline.
    bench = Bench(TerrainStack.from_stores(embedded_stores()), size, lod=args.lod)
    bench.session.tau_px = args.tau
    lines = [
        f"Render benchmark, LOD provider {args.lod}, {size[0]}x{size[1]}, tau = {args.tau} px, "
        f"{args.frames} frames per view, {time.strftime('%Y-%m-%d')}, {bench.gl_renderer}, "
        f"{platform.machine()} ({len(os.sched_getaffinity(0))} cores)",
        "",
        "| view | triangles | tiles | frame_ms (median) | lod_ms (median) | max SSE px | "
        f"<= {TARGET_MS:.0f} ms |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for name, cam in VIEWS.items():
        # A tiny camera turn per frame so every frame really selects and draws.
        r = bench.measure(cam, args.frames, turn_deg=0.01)
        ok = "yes" if r["frame_ms"] <= TARGET_MS else "no"
        lines.append(
            f"| {name} | {r['triangles']} | {r['tiles']} | {r['frame_ms']:.1f} | "
            f"{r['lod_ms']:.2f} | {r['max_sse_px']:.2f} | {ok} |"
        )
    bench.release()
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
