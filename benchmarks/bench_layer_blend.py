"""What the seamless-layer blend (issue #16, item 4) costs: per view over each regional DEM,
the triangles drawn and the time to the first frame from a fresh stack (which builds the
layers' blend masks and band statistics once), with the blend and with the layers pasted
as before (a cliff at each border); then the same view again (warm). Both variants in one
run, alternating, best of ``--repeat``: llvmpipe timings vary with load.

Run: .venv/bin/python benchmarks/bench_layer_blend.py [--repeat 3]
"""

from __future__ import annotations

import argparse

import numpy as np

from globeview.bench.harness import Bench
from globeview.render.offscreen import create_headless_context
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.embedded import embedded_stores

SIZE = (1280, 720)
VIEWS = {
    "SRTM White Mountains, nadir 174 km": (-71.5, 44.5, 174_000.0, 0.0, -90.0),
    "Crater Lake, oblique 45 km": (-122.15, 42.6, 45_000.0, 0.0, -35.0),
    "Salish Sea, nadir 300 km": (-123.2, 49.2, 300_000.0, 0.0, -90.0),
    "SRTM western border, oblique 20 km": (-71.9, 44.5, 20_000.0, 90.0, -30.0),
}


def frame(ctx, blend: bool, pose) -> tuple[float, float, int]:
    stack = TerrainStack.from_stores(embedded_stores())
    stack.blend = blend  # False: layers pasted as before (a cliff at each border)
    # The one harness: a chunked-sse session on this stack, frames through its pipeline.
    bench = Bench(stack, SIZE, lod="chunked-sse", ctx=ctx)
    bench.use("chunked-sse", 2.0)
    bench.set_pose(pose, cut=True)
    result, cold_ms = bench.frame()
    _, warm_ms = bench.frame()
    bench.release()  # the tile pool's GL objects (the context is ours)
    return cold_ms / 1e3, warm_ms / 1e3, result.stats.triangles


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    ctx = create_headless_context()
    print(f"{'view':38} {'variant':10} {'triangles':>9} {'first frame':>12} {'next frame':>11}")
    for name, pose in VIEWS.items():
        best: dict[bool, list] = {True: [np.inf, np.inf, 0], False: [np.inf, np.inf, 0]}
        for _ in range(args.repeat):
            for blend in (False, True):
                cold, warm, tris = frame(ctx, blend, pose)
                b = best[blend]
                b[0], b[1], b[2] = min(b[0], cold), min(b[1], warm), tris
        for blend in (False, True):
            cold, warm, tris = best[blend]
            label = "blend" if blend else "pasted"
            print(f"{name:38} {label:10} {tris:9d} {cold * 1e3:10.0f} ms {warm * 1e3:8.0f} ms")


if __name__ == "__main__":
    main()
