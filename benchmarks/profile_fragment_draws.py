"""Where the fragment benchmark's geometry floor goes (issue #27): per benchmark view, the
constant-colour terrain pass of `benchmarks/bench_fragment.py` (terrain vertices, no shading)
as drawn, and the same pass with every draw of its multi-draw call cut to one triangle: the
difference is the rasterisation of the view's triangles (with their vertex shading), the
rest the per-draw and per-pass cost. Medians of alternating rounds of process CPU time (all
threads: llvmpipe rasterises on worker threads), with the trivial full-screen pass for scale.

    .venv/bin/python benchmarks/profile_fragment_draws.py [--rounds 5] [--size 1280x720]
"""

from __future__ import annotations

import argparse
import statistics
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import moderngl
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # bench_fragment, beside this one

from bench_fragment import Passes, timed

from globeview.bench.harness import Bench, machine, parse_size
from globeview.bench.report import load_average
from globeview.bench.views import VIEWS
from globeview.lod.render_set import FrameStats
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.embedded import embedded_stores

#: Bytes of one indirect command (count, instances, first index, base vertex, base instance).
COMMAND_BYTES = 20


@contextmanager
def one_triangle_draws(on: list[bool]) -> Iterator[None]:
    """While ``on[0]``, every indirect draw call draws at most one triangle per command (the
    commands buffer is rewritten before the call)."""
    original = moderngl.VertexArray.render_indirect

    def render_indirect(
        self: moderngl.VertexArray, buffer: moderngl.Buffer, *args: Any, **kwargs: Any
    ) -> Any:
        count = int(kwargs.get("count", -1))
        if on[0] and count > 0:
            raw = np.frombuffer(buffer.read(size=count * COMMAND_BYTES), np.uint32)
            cmds = raw.reshape(-1, 5).copy()
            cmds[:, 0] = np.minimum(cmds[:, 0], 3)
            buffer.write(cmds.tobytes())
        return original(self, buffer, *args, **kwargs)

    moderngl.VertexArray.render_indirect = render_indirect  # type: ignore[method-assign]
    try:
        yield
    finally:
        moderngl.VertexArray.render_indirect = original  # type: ignore[method-assign]


def measure(passes: Passes, pose: Any, rounds: int, cut: list[bool]) -> dict[str, float]:
    """Median CPU ms of the geometry pass as drawn and with one-triangle draws, and the
    trivial pass, at one view; with its tiles and triangles."""
    bench = passes.bench
    bench.set_pose(pose, cut=True)
    result, _ = bench.frame()
    view = result.view
    render_set = bench.session.renderer.load(result.render_set, FrameStats())
    passes.geometry(view, render_set)  # warm
    drawn, one, trivial = [], [], []
    for _ in range(rounds):
        cut[0] = False
        drawn.append(timed(passes.geometry, view, render_set)[1])
        cut[0] = True
        one.append(timed(passes.geometry, view, render_set)[1])
        cut[0] = False
        trivial.append(timed(passes.trivial, True)[1])
    med = statistics.median
    return {
        "tiles": len(render_set),
        "triangles": int(result.stats.triangles),
        "drawn": med(drawn),
        "one": med(one),
        "trivial": med(trivial),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="alternating rounds per view")
    ap.add_argument("--size", default="1280x720")
    args = ap.parse_args(argv)
    size = parse_size(args.size)
    bench = Bench(TerrainStack.from_stores(embedded_stores()), size)
    passes = Passes(bench)
    cut = [False]
    print(
        f"Geometry pass by parts, {size[0]}x{size[1]}, {machine(bench.gl_renderer)}, load "
        f"{load_average()[0]:.2f}; CPU ms (process, all threads), medians of {args.rounds}"
    )
    print()
    print("| view | tiles (draws) | triangles | geometry CPU | one triangle a draw | trivial |")
    print("|---|---:|---:|---:|---:|---:|")
    try:
        with one_triangle_draws(cut):
            for name, pose in VIEWS.items():
                r = measure(passes, pose, max(1, args.rounds), cut)
                print(
                    f"| {name} | {r['tiles']} | {r['triangles']} | {r['drawn']:.1f} "
                    f"| {r['one']:.1f} | {r['trivial']:.1f} |",
                    flush=True,
                )
    finally:
        passes.release()
        bench.release()
    print(f"\nload after {load_average()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
