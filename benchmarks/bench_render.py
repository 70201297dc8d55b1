"""Render benchmark: triangles, frame_ms and lod_ms for fixed views over the embedded data.

Prints a Markdown table (and writes it with --out). Figures depend on the machine: the
header says which. Performance targets live here, never in timed tests.

    .venv/bin/python benchmarks/bench_render.py [--frames 15] [--size 1280x720] [--lod NAME]
        [--compare] [--ladder]

--compare adds a table of every LOD provider's triangles and max SSE per view beside the
default's, and the default's ratio to the fewest triangles any provider draws within tau
(target: <= COMPARE_TARGET). --ladder adds the default's triangles over a tau ladder per
view (they must never grow as tau grows).
"""

from __future__ import annotations

import argparse
import itertools
import os
import platform
import time
from pathlib import Path

from globeview.bench.harness import Bench, parse_size
from globeview.bench.views import VIEWS
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.embedded import embedded_stores

TARGET_MS = 50.0
#: The default provider's triangles over the fewest any provider draws with max SSE <= tau.
COMPARE_TARGET = 2.0
#: A provider's max SSE counts as within tau up to this relative slack (float rounding).
SSE_SLACK = 1.001
LADDER = (0.5, 1.0, 2.0, 4.0, 8.0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=15)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--tau", type=float, default=2.0)
    ap.add_argument("--lod", default="chunked-sse", help="LOD provider plugin")
    ap.add_argument("--out", help="also write the Markdown table to this file")
    ap.add_argument("--compare", action="store_true", help="every provider's triangles too")
    ap.add_argument("--ladder", action="store_true", help="the default's triangles over tau")
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
    if args.compare:
        lines += ["", *compare(bench, args.lod, args.tau)]
    if args.ladder:
        lines += ["", *ladder(bench, args.lod)]
    bench.release()
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


def compare(bench: Bench, default: str, tau: float) -> list[str]:
    """Markdown lines: per view, each provider's triangles (max SSE px), and the default's
    ratio to the fewest triangles drawn within tau (one selecting frame each)."""
    providers = bench.providers()
    figures: dict[str, dict[str, tuple[int, float]]] = {}
    for lod in providers:
        bench.use(lod, tau)
        for name, cam in VIEWS.items():
            r = bench.measure(cam, 1)
            figures.setdefault(name, {})[lod] = (r["triangles"], r["max_sse_px"])
    out = [
        f"Triangles (max SSE px) per provider at tau = {tau} px; ratio = {default} over the "
        f"fewest within tau (target <= {COMPARE_TARGET:.0f}x)",
        "",
        "| view | " + " | ".join(providers) + " | ratio | met |",
        "|---|" + "---:|" * len(providers) + "---:|---|",
    ]
    for name, row in figures.items():
        within = [t for t, e in row.values() if e <= tau * SSE_SLACK]
        best = min(within) if within else 0
        mine, err = row[default]
        ratio = mine / best if best else float("inf")
        ok = "yes" if ratio <= COMPARE_TARGET and err <= tau * SSE_SLACK else "no"
        cells = " | ".join(f"{t} ({e:.2f})" for t, e in row.values())
        out.append(f"| {name} | {cells} | {ratio:.2f} | {ok} |")
    bench.use(default, tau)
    return out


def ladder(bench: Bench, lod: str) -> list[str]:
    """Markdown lines: ``lod``'s triangles per view over the tau `LADDER` and whether they
    never grow as tau grows."""
    out = [
        f"{lod} triangles over tau (px)",
        "",
        "| view | " + " | ".join(f"{t:g}" for t in LADDER) + " | monotone |",
        "|---|" + "---:|" * len(LADDER) + "---|",
    ]
    for name, cam in VIEWS.items():
        counts = []
        for tau in LADDER:
            bench.use(lod, tau)
            counts.append(bench.measure(cam, 1)["triangles"])
        mono = all(b <= a for a, b in itertools.pairwise(counts))
        out.append(
            f"| {name} | " + " | ".join(map(str, counts)) + f" | {'yes' if mono else 'no'} |"
        )
    return out


if __name__ == "__main__":
    raise SystemExit(main())
