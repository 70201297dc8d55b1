"""A large GIS vector layer (issue #26 item 3: "a 1 M-vertex layer opens in seconds and keeps
the frame rate"): the time to open it through the ``gis`` layer type and the frame time with
and without it. Prints a Markdown table.

The layer is generated here, never committed: ``--lines`` random-walk polylines (contour-like,
``--vertices`` in all, default 1 000 000) over the White Mountains (71.9..70.7 W,
43.7..44.8 N), written by GDAL as a GeoPackage in UTM 19N (EPSG:32619, so opening includes the
reprojection) with a numeric field ``elev`` the layer is coloured by (5 quantile classes).

Opening is split into its steps, each as wall time and the process's CPU time:
``read`` (`read_vector_file`: OGR, WKB, reprojection, classes), ``build`` (the host's layer
models: densification and the coarser line levels), ``first frame`` (heights on the drawn
mesh and the GPU upload). Frames: the median of ``--frames`` frames with a tiny camera turn
(the harness's `Bench.measure`) at a close and a regional view of the layer, with and without
it; ``cpu_ms`` is the process's CPU time per frame (all threads, llvmpipe's included: a loaded
machine disturbs it less than wall time, but does not leave it alone).

    .venv/bin/python benchmarks/bench_gis_vectors.py [--vertices 1000000] [--lines 2000]
        [--frames 9] [--size 1280x720]
"""

from __future__ import annotations

import argparse
import os
import struct
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from globeview.bench.harness import Bench, machine, parse_size
from globeview.errors import GlobeviewError
from globeview.model.overlay_layers import host_layer
from globeview.model.vector_files import read_vector_file
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.embedded import embedded_stores

#: Where the lines are (degrees): west, south, east, north.
AREA = (-71.9, 43.7, -70.7, 44.8)
#: The views (lon, lat, height m, heading, pitch): close over Mount Washington, and the
#: whole layer from 150 km.
VIEWS = {
    "close oblique (9 km)": (-71.3, 44.15, 9.0e3, 0.0, -30.0),
    "whole layer (150 km, down)": (-71.3, 44.25, 1.5e5, 0.0, -90.0),
}


def write_layer(path: Path, vertices: int, lines: int, seed: int = 7) -> None:
    """``lines`` random-walk polylines of ``vertices`` vertices in all (UTM 19N) with a field
    ``elev``, written by GDAL (pyogrio) as a GeoPackage."""
    from pyogrio.raw import write
    from pyproj import Transformer

    rng = np.random.default_rng(seed)
    per = max(vertices // lines, 2)
    w, s, e, n = AREA
    start_lon = rng.uniform(w, e, lines)
    start_lat = rng.uniform(s, n, lines)
    steps = rng.normal(0.0, 1.5e-4, (lines, per, 2)).cumsum(axis=1)  # ~15 m steps
    lon = start_lon[:, None] + steps[..., 0]
    lat = start_lat[:, None] + steps[..., 1]
    x, y = Transformer.from_crs(4326, 32619, always_xy=True).transform(lon, lat)
    head = struct.pack("<BII", 1, 2, per)
    xy = np.stack([x, y], axis=-1).astype("<f8")
    geoms = np.array([head + xy[i].tobytes() for i in range(lines)], dtype=object)
    elev = rng.uniform(200.0, 1900.0, lines)
    write(
        str(path),
        geoms,
        [elev],
        ["elev"],
        layer="contours",
        crs="EPSG:32619",
        geometry_type="LineString",
        driver="GPKG",
    )


def timed(fn, *args, **kw):
    """(result, wall s, CPU s of this process)."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t0, time.process_time() - c0


def measured(bench: Bench, pose: tuple, frames: int) -> tuple[float, float]:
    """Median frame ms (wall) and mean CPU ms per frame after a warm frame."""
    bench.set_pose(pose, cut=True)
    bench.frame()
    c0 = time.process_time()
    m = bench.measure(pose, frames, turn_deg=0.01)
    return m["frame_ms"], (time.process_time() - c0) * 1e3 / (frames + 1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--vertices", type=int, default=1_000_000)
    ap.add_argument("--lines", type=int, default=2_000)
    ap.add_argument("--frames", type=int, default=9)
    ap.add_argument("--size", default="1280x720")
    args = ap.parse_args()
    size = parse_size(args.size)
    if not 1_000 <= args.vertices <= 5_000_000 or not 1 <= args.lines <= args.vertices // 2:
        raise GlobeviewError("--vertices must lie in 1000..5000000, --lines in 1..vertices/2")
    if not 1 <= args.frames <= 1_000:
        raise GlobeviewError(f"--frames must lie in 1..1000, not {args.frames}")

    with tempfile.TemporaryDirectory(prefix="gv-bench-gis-") as tmp:
        path = Path(tmp) / "contours.gpkg"
        write_layer(path, args.vertices, args.lines)
        mb = path.stat().st_size / 1e6
        bench = Bench(TerrainStack.from_stores(embedded_stores()), size)
        load = os.getloadavg()
        print(
            f"GIS vector layer: {args.lines} lines, {args.vertices:,} vertices, GeoPackage "
            f"{mb:.0f} MB in UTM 19N, coloured by a field (5 classes); {size[0]}x{size[1]}"
        )
        print(f"{machine(bench.gl_renderer)}; load {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
        print()
        drawables, read_s, read_cpu = timed(read_vector_file, path, color_by="elev")
        (layer, problem), build_s, build_cpu = timed(host_layer, drawables, path.name)
        if problem is not None:
            raise GlobeviewError(problem)
        n_dense = sum(len(p.lines.lon) for p in getattr(layer, "parts", [layer]))
        print("| step | wall s | CPU s |")
        print("|---|---:|---:|")
        print(f"| read (OGR, WKB, reprojection, classes) | {read_s:.2f} | {read_cpu:.2f} |")
        print(
            f"| build (densify to {n_dense:,} vertices, coarser levels) | {build_s:.2f} "
            f"| {build_cpu:.2f} |"
        )
        rows = []
        for name, pose in VIEWS.items():
            base_ms, base_cpu = measured(bench, pose, args.frames)
            bench.session.globe.add_overlay(layer)
            bench.set_pose(pose, cut=True)
            _, first_s, first_cpu = timed(bench.frame)
            with_ms, with_cpu = measured(bench, pose, args.frames)
            r = bench.session.render(bench.target.fbo, bench.size)
            segs = r.stats.extra.get("vector_segments", 0)
            bench.session.remove_overlay(layer)
            bench.session.render(bench.target.fbo, bench.size)  # releases the GPU twin
            rows.append((name, segs, base_ms, with_ms, base_cpu, with_cpu))
            print(
                f"| first frame at {name} (drape heights, upload) | {first_s:.2f} "
                f"| {first_cpu:.2f} |"
            )
        print()
        print(
            "| view | segments drawn | frame_ms without | with | ratio | cpu_ms without "
            "| with | cpu_ratio |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        for name, segs, b_ms, w_ms, b_cpu, w_cpu in rows:
            print(
                f"| {name} | {segs:,} | {b_ms:.1f} | {w_ms:.1f} | {w_ms / b_ms:.2f} "
                f"| {b_cpu:.1f} | {w_cpu:.1f} | {w_cpu / b_cpu:.2f} |"
            )
        bench.release()
    return 0


if __name__ == "__main__":
    try:
        raise SystemExit(main())
    except GlobeviewError as exc:  # bad arguments: one line, exit 2 (as the CLI)
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
