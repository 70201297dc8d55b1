"""Collapse cost: frame_ms, lod_ms and draw_ms of the same views with and without the
terrain collapse (median of N frames, a tiny camera turn per frame so every frame selects and
draws). Prints a Markdown table. The collapse's displacement runs in the vertex shader; on the
CPU it only moves tile bounding points (9 per tile corner lattice), never vertices.

    .venv/bin/python benchmarks/bench_collapse.py [--frames 9] [--size 1280x720]
"""

from __future__ import annotations

import argparse
import statistics
import time

from globeview.model.camera import Camera
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.session import GlobeSession
from globeview.plugins.settings import MemorySettings
from globeview.render.offscreen import OffscreenTarget, create_headless_context
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


def measure(session: GlobeSession, target, size, cam, frames: int) -> dict[str, float]:
    session.camera = Camera.from_lonlat(*cam)
    session.render(target.fbo, size)
    fm, lm, dm, tri = [], [], [], []
    for i in range(frames):
        session.camera.fly_yaw(0.01 * (-1) ** i)
        t0 = time.perf_counter()
        r = session.render(target.fbo, size)
        fm.append((time.perf_counter() - t0) * 1e3)
        lm.append(r.stats.lod_ms)
        dm.append(r.stats.draw_ms)
        tri.append(r.stats.triangles)
    med = statistics.median
    return {"frame": med(fm), "lod": med(lm), "draw": med(dm), "tri": med(tri)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=9)
    ap.add_argument("--size", default="1280x720")
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    ctx = create_headless_context()
    target = OffscreenTarget(ctx, size)
    terrain = TerrainStack.from_stores(embedded_stores())
    session = GlobeSession(ctx, terrain, registry=PluginRegistry(MemorySettings()).discover())
    tool = session.tools()["collapse"]
    print(f"Collapse cost, {size[0]}x{size[1]}, chunked-sse, tau 2 px, {ctx.info['GL_RENDERER']}")
    print()
    print("| view | collapse | triangles | frame_ms | lod_ms | draw_ms |")
    print("|---|---|---:|---:|---:|---:|")
    for name, (cam, pair) in VIEWS.items():
        session.activate_tool(None)
        off = measure(session, target, size, cam, args.frames)
        tool.set_points(*pair[:4], pair[4])
        session.activate_tool("collapse")
        on = measure(session, target, size, cam, args.frames)
        for label, m in (("off", off), ("on", on)):
            print(
                f"| {name} | {label} | {m['tri']:.0f} | {m['frame']:.1f} | {m['lod']:.1f} | "
                f"{m['draw']:.1f} |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
