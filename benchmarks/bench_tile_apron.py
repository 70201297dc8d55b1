"""Tile build time with and without the apron (issue #16, item 5): heights + mesh + normals
for a block of tiles over the White Mountains, cold stack cache then warm (the neighbours a
view loads together). Run: .venv/bin/python benchmarks/bench_tile_apron.py"""

from __future__ import annotations

import time

import numpy as np

from globeview.render.renderer import tile_bounds_tuple
from globeview.render.tile_mesh import build_tile_mesh
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.embedded import embedded_stores
from globeview.terrain.quadtree import key_for_lonlat


def keys(level: int, n: int = 6) -> list[tuple[int, int, int]]:
    kx, ky = key_for_lonlat(level, np.array([-71.3]), np.array([44.15]))
    x0, y0 = int(np.ravel(kx)[0]) - n // 2, int(np.ravel(ky)[0]) - n // 2
    return [(level, x0 + i, y0 + j) for j in range(n) for i in range(n)]


def run(apron: bool, level: int) -> float:
    stack = TerrainStack.from_stores(embedded_stores())
    ks = keys(level)
    for k in ks:  # warm the stores' own caches (disk), not the stack's composed tiles
        stack.heights(k)
    stack._changed()
    t = time.perf_counter()
    for k in ks:
        a = stack.heights_apron(k) if apron else None
        build_tile_mesh(tile_bounds_tuple(k), stack.heights(k), 10.0, apron=a)
    return (time.perf_counter() - t) / len(ks) * 1e3


if __name__ == "__main__":
    for level in (9, 11):
        base = min(run(False, level) for _ in range(3))
        ap = min(run(True, level) for _ in range(3))
        print(
            f"level {level}: {base:.2f} ms/tile without apron, {ap:.2f} ms with "
            f"({100 * (ap / base - 1):+.0f} %)"
        )
