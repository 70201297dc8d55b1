"""Fragment-cost benchmark: a full-screen terrain pass against a trivial full-screen pass on
the same GL context, per benchmark view (globeview.bench.views), alternating in one run.

Issue #17, item 1: the terrain pass should cost at most TARGET_RATIO times the trivial pass.
On llvmpipe (no GPU) every fragment runs on the CPU, so this ratio measures how close the
terrain shading is to the cheapest possible full-screen frame.

Passes, each ending with glFinish, timed alternately ``--rounds`` times per view:

- ``terrain``: `GlobeRenderer.draw_terrain` of the view's (resident) render set, exactly as a
  frame draws it (clear, one multi-draw call), without LOD selection or uploads;
- ``geometry``: the same draw with the terrain vertex shader and a constant-colour fragment
  shader: the floor that vertex shading, rasterisation and the depth test set for any
  terrain shading (the part no fragment-shader change can remove);
- ``one fetch``: the same with a fragment shader that only samples the tile's albedo
  texture once: the floor of any shading that reads a per-tile texture;
- ``trivial``: the reference: clear colour and depth, one full-screen triangle, constant
  colour, depth test on (the cheapest frame that writes every pixel as the terrain does);
- ``trivial (colour only)``: the same with no depth buffer work, for reference.

Both wall time and process CPU time (all threads: llvmpipe rasterises on worker threads) are
medians; CPU time is less sensitive to other processes on a busy machine. Figures depend on
the machine: the header says which, with the load average. Targets live here, never in
timed tests.

    .venv/bin/python benchmarks/bench_fragment.py [--rounds 15] [--size 1280x720] [--out F]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import moderngl

from globeview.bench.harness import Bench, machine, parse_size
from globeview.bench.views import VIEWS
from globeview.errors import GlobeviewError
from globeview.lod.render_set import FrameStats
from globeview.render.shader_source import build_shader
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.embedded import embedded_stores

TARGET_RATIO = 4.0  # terrain pass / trivial pass (CPU time), issue #17 item 1

_FULLSCREEN_VS = """#version 330
void main() {  // one triangle covering the viewport
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    gl_Position = vec4(p * 2.0 - 1.0, 0.5, 1.0);
}
"""
_CONSTANT_FS = """#version 330
out vec4 f_color;
void main() { f_color = vec4(0.2, 0.3, 0.4, 1.0); }
"""
# Texture unit 0 holds the tile pool's albedo array while the terrain draws.
_ONE_FETCH_FS = """#version 330
uniform sampler2DArray u_albedo;
in vec2 v_uv;
flat in float v_layer;
out vec4 f_color;
void main() { f_color = vec4(texture(u_albedo, vec3(v_uv, v_layer)).rgb, 1.0); }
"""


class Passes:
    """The timed passes of one bench (see the module docstring)."""

    def __init__(self, bench: Bench) -> None:
        self.bench = bench
        self.ctx = bench.ctx
        self.fbo = bench.target.fbo
        self.renderer = bench.session.renderer
        ctx = self.ctx
        self._trivial = ctx.program(vertex_shader=_FULLSCREEN_VS, fragment_shader=_CONSTANT_FS)
        self._trivial_vao = ctx.vertex_array(self._trivial, [])
        # The terrain vertex shader with a constant fragment shader, in the renderer's VAOs.
        vert = build_shader("terrain.vert").text
        self._geometry = ctx.program(vertex_shader=vert, fragment_shader=_CONSTANT_FS)
        self._geometry_vaos = self.renderer._make_vaos(self._geometry)
        self._fetch = ctx.program(vertex_shader=vert, fragment_shader=_ONE_FETCH_FS)
        self._fetch_vaos = self.renderer._make_vaos(self._fetch)

    def trivial(self, depth: bool = True) -> None:
        self.fbo.use()
        self.fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
        if depth:
            self.ctx.enable(moderngl.DEPTH_TEST)
        else:
            self.ctx.disable(moderngl.DEPTH_TEST)
        self._trivial_vao.render(moderngl.TRIANGLES, vertices=3)
        self.ctx.finish()

    def terrain(self, view, render_set) -> None:
        self.renderer.draw_terrain(view, render_set, self.fbo)
        self.ctx.finish()

    def geometry(self, view, render_set) -> None:
        self._draw_with(self._geometry, self._geometry_vaos, view, render_set)

    def one_fetch(self, view, render_set) -> None:
        self._draw_with(self._fetch, self._fetch_vaos, view, render_set)

    def _draw_with(self, program, vaos, view, render_set) -> None:
        r = self.renderer
        saved = (r.program, r.vao, r.custom_vao)
        # draw_terrain sets the uniforms the program has (the vertex shader's) and draws
        # through r.vao; _use_features keeps r.program while the features are unchanged.
        r.program = program
        r.vao, r.custom_vao = vaos
        try:
            self.terrain(view, render_set)
        finally:
            r.program, r.vao, r.custom_vao = saved

    def release(self) -> None:
        for obj in (
            *self._geometry_vaos,
            self._geometry,
            *self._fetch_vaos,
            self._fetch,
            self._trivial_vao,
            self._trivial,
        ):
            obj.release()


def timed(fn, *args) -> tuple[float, float]:
    """(wall ms, process CPU ms) of one call."""
    w0, c0 = time.perf_counter(), time.process_time()
    fn(*args)
    return (time.perf_counter() - w0) * 1e3, (time.process_time() - c0) * 1e3


def measure_view(passes: Passes, pose, rounds: int) -> dict[str, object]:
    """Medians (wall, cpu) of each pass at one view, the passes alternating each round."""
    bench = passes.bench
    bench.set_pose(pose, cut=True)
    result, _ = bench.frame()  # selects and uploads the view's tiles
    view = result.view
    render_set = bench.session.renderer.load(result.render_set, FrameStats())
    runs: dict[str, list[tuple[float, float]]] = {
        "terrain": [],
        "geometry": [],
        "one_fetch": [],
        "trivial": [],
        "trivial_colour": [],
    }
    passes.terrain(view, render_set)  # warm: first use of a program variant compiles it
    for _ in range(int(rounds)):
        runs["terrain"].append(timed(passes.terrain, view, render_set))
        runs["trivial"].append(timed(passes.trivial, True))
        runs["geometry"].append(timed(passes.geometry, view, render_set))
        runs["one_fetch"].append(timed(passes.one_fetch, view, render_set))
        runs["trivial_colour"].append(timed(passes.trivial, False))
    med = statistics.median
    out: dict[str, object] = {
        k: (med(w for w, _ in v), med(c for _, c in v)) for k, v in runs.items()
    }
    out["tiles"] = len(render_set)
    out["triangles"] = int(result.stats.triangles)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--rounds", type=int, default=15, help="timed rounds per view")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--out", help="also write the Markdown table to this file")
    args = ap.parse_args()
    try:
        size = parse_size(args.size)
        if not 1 <= args.rounds <= 10000:
            raise GlobeviewError(f"--rounds must be 1..10000, not {args.rounds}")
    except GlobeviewError as exc:
        print(f"bench_fragment: {exc}", file=sys.stderr)
        return 2

    bench = Bench(TerrainStack.from_stores(embedded_stores()), size)
    passes = Passes(bench)
    load = os.getloadavg()
    lines = [
        f"Fragment benchmark, {size[0]}x{size[1]}, chunked-sse at its default tau, "
        f"{args.rounds} alternating rounds per view; {machine(bench.gl_renderer)}; "
        f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}",
        "",
        "Medians, ms (CPU: process time, all threads). ratio = terrain / trivial (CPU); "
        f"target <= {TARGET_RATIO:.0f}x. geometry: terrain vertices with a constant-colour "
        "fragment shader (the floor of any shading); one fetch: the same sampling the tile "
        "albedo once (the floor of any textured shading); floors as ratios to trivial.",
        "",
        "| view | triangles | terrain wall | terrain CPU | geometry CPU | one fetch CPU | "
        "trivial CPU | trivial colour-only CPU | ratio | geometry floor | one-fetch floor | "
        f"<= {TARGET_RATIO:.0f}x |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for name, pose in VIEWS.items():
        r = measure_view(passes, pose, args.rounds)
        ter, geo, one = r["terrain"], r["geometry"], r["one_fetch"]
        tri, col = r["trivial"], r["trivial_colour"]
        ratio = ter[1] / tri[1]
        lines.append(
            f"| {name} | {r['triangles']} | {ter[0]:.2f} | {ter[1]:.2f} | {geo[1]:.2f} | "
            f"{one[1]:.2f} | {tri[1]:.2f} | {col[1]:.2f} | {ratio:.1f}x | "
            f"{geo[1] / tri[1]:.1f}x | {one[1] / tri[1]:.1f}x | "
            f"{'yes' if ratio <= TARGET_RATIO else 'no'} |"
        )
    passes.release()
    bench.release()
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
