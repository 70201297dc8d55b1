"""Reproduce the thesis's Fig. 6.2 situation headless and time the collapse (not a test).

Crater Lake (Oregon) and the Salish Sea (Washington/B.C.), ~560 km apart on the embedded
regional data, brought side by side. Writes PNGs (before / after / after-wireframe / wide
views with the fold lines painted from the tool's overlay) and prints frame timings with
and without the collapse for the same view:

    .venv/bin/python tests/collapse/figure_collapse.py OUTDIR
"""

from __future__ import annotations

import itertools
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

from globeview.app.session import GlobeSession
from globeview.model.camera import Camera
from globeview.plugins.api import Polyline
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings
from globeview.render.offscreen import OffscreenTarget, create_headless_context
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.embedded import embedded_stores

A = (-122.1, 43.0)  # just north of Crater Lake
B = (-122.6, 48.05)  # the south end of the Salish Sea topobathy
RATIO = 0.02
SIZE = (480, 360)


def paint_overlay(rgb: np.ndarray, session: GlobeSession, view) -> np.ndarray:
    """Paint the tool's fold lines (displaced like the terrain) as yellow dots."""
    out = rgb.copy()
    tool = session.tool()
    for prim in tool.overlay(view) if tool else []:
        if not isinstance(prim, Polyline):
            continue
        pts = tool.displacement_numpy(prim.points)
        dense = np.concatenate([np.linspace(p, q, 40) for p, q in itertools.pairwise(pts)])
        xyd = view.project(dense)
        ok = (xyd[:, 2] > 0) & (xyd[:, 0] >= 0) & (xyd[:, 0] < SIZE[0] - 1)
        ok &= (xyd[:, 1] >= 0) & (xyd[:, 1] < SIZE[1] - 1)
        x, y = xyd[ok, 0].astype(int), xyd[ok, 1].astype(int)
        col = (np.array(prim.color[:3]) * 255).astype(np.uint8)
        out[y, x] = col
        out[y + 1, x] = col
    return out


def main(outdir: str) -> None:
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    ctx = create_headless_context()
    tgt = OffscreenTarget(ctx, SIZE)
    terrain = TerrainStack.from_stores(embedded_stores())
    reg = PluginRegistry(MemorySettings()).discover()
    session = GlobeSession(ctx, terrain, Camera.from_lonlat(-122.3, 45.5, 1e6), registry=reg)
    session.settings.exaggeration = 2.0
    tool = session.tools()["collapse"]
    near = Camera.from_lonlat(-121.55, 45.47, 2.2e4, 285.0, -28.0)
    wide = Camera.from_lonlat(-122.4, 45.5, 1.3e6)

    def shot(name: str, camera: Camera, collapsed: bool, wire: bool = False) -> None:
        session.activate_tool(None)
        if collapsed:
            tool.set_points(*A, *B, RATIO)
            session.activate_tool("collapse")
        session.settings.wireframe = wire
        session.camera = camera
        res = session.render(tgt.fbo, SIZE)
        rgb = paint_overlay(tgt.read_rgb(), session, res.view) if collapsed else tgt.read_rgb()
        Image.fromarray(rgb).save(out / f"{name}.png")
        print(f"{name}: {res.stats.tiles_drawn} tiles, {res.stats.triangles} triangles")

    shot("wide_before", wide, False)
    shot("wide_after", wide, True)
    shot("near_before", near, False)
    shot("near_after", near, True)
    shot("near_after_wire", near, True, wire=True)
    session.settings.wireframe = False

    # Timing, same view, camera nudged every frame so no provider serves a cached selection.
    for collapsed in (False, True, False, True):
        session.activate_tool(None)
        if collapsed:
            tool.set_points(*A, *B, RATIO)
            session.activate_tool("collapse")
        frame, lod, draw, wall = [], [], [], []
        for i in range(12):
            session.camera = Camera.from_lonlat(-121.55, 45.47, 2.2e4, 285.0 + 0.001 * i, -28.0)
            t = time.perf_counter()
            res = session.render(tgt.fbo, SIZE)
            ctx.finish()
            wall.append((time.perf_counter() - t) * 1e3)
            frame.append(res.stats.frame_ms)
            lod.append(res.stats.lod_ms)
            draw.append(res.stats.draw_ms)
        k = slice(2, None)  # drop warm-up frames
        print(
            f"collapse={collapsed}: frame_ms {np.median(frame[k]):.1f} (lod {np.median(lod[k]):.1f}"
            f", draw {np.median(draw[k]):.1f}), wall {np.median(wall[k]):.1f} ms, "
            f"{res.stats.triangles} triangles"
        )


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "collapse_figures")
