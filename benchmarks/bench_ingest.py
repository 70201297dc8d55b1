"""Benchmark `globeview ingest` on a big synthetic-detail DEM against GDAL's overview build.

Prints: source size, ingest wall time, MB/s (source bytes / wall), peak RSS of the ingest
child process (ru_maxrss), store size; then the wall time of GDAL's own overview build
(rasterio build_overviews, Resampling.average = ``gdaladdo -r average``) on a copy of the same
raster, as the reference figure. A script that prints figures, not a timed test.

    python benchmarks/bench_ingest.py [--size 16384]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_big_dem import CACHE, make

INGEST = (
    "import sys; from globeview.terrain.ingest import ingest; "
    "ingest([sys.argv[1]], sys.argv[2], force=True, progress=False)"
)
OVERVIEWS = (
    "import sys, rasterio; from rasterio.enums import Resampling\n"
    "with rasterio.open(sys.argv[1], 'r+') as ds:\n"
    "    f = [2**k for k in range(1, 16) if max(ds.shape) >> k >= 256]\n"
    "    ds.build_overviews(f, Resampling.average)\n"
)


def _child(code: str, *args: str) -> tuple[float, float]:
    """Run python code in a child; return (wall seconds, child's peak RSS in MB)."""
    t = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", code, *args])
    # wait4 gives this child's own rusage (RUSAGE_CHILDREN would be the max over all children).
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise SystemExit(f"child failed with exit code {proc.returncode}")
    return wall, usage.ru_maxrss / 1024.0


def _du(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) / 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=16384)
    args = ap.parse_args()
    # Generate in a child: a fork inherits this process's RSS, which would leak into the
    # children's ru_maxrss figure if the generator ran here.
    subprocess.run(
        [
            sys.executable,
            str(Path(__file__).with_name("make_big_dem.py")),
            "--size",
            str(args.size),
        ],
        check=True,
    )
    src = make(args.size, quiet=True)  # cached now: just the path
    mb = src.stat().st_size / 1e6
    print(
        f"source      {src.name}: {args.size}x{args.size} float32, {mb:.0f} MB "
        "(SRTM3 N44W072 + SYNTHETIC fractal detail)"
    )
    out = CACHE / f"store_{args.size}"
    wall, rss = _child(INGEST, str(src), str(out))
    print(
        f"ingest      {wall:.1f} s wall, {mb / wall:.1f} MB/s, peak RSS {rss:.0f} MB, "
        f"store {_du(out):.0f} MB"
    )
    copy = CACHE / f"ovr_copy_{args.size}.tif"
    shutil.copy(src, copy)
    try:
        wall_o, _ = _child(OVERVIEWS, str(copy))
    finally:
        copy.unlink(missing_ok=True)
        Path(str(copy) + ".ovr").unlink(missing_ok=True)
    print(f"gdal ovr    {wall_o:.1f} s wall (build_overviews average, internal, uncompressed)")
    print(
        f"ratio       ingest / overviews = {wall / wall_o:.2f} (target <= 1); "
        f"peak RSS target <= 512 MB: {'ok' if rss <= 512 else 'MISSED'}"
    )


if __name__ == "__main__":
    main()
