"""Where a 1-worker ingest's CPU goes by kind, against GDAL's overview build (issue #25 item 6).

The ingest of one raster (default: the 8192^2 benchmark DEM of `make_big_dem.py`) with one
local worker, in this process, its CPU split by what spends it:

- **chunk decode**: `tasks.ChunkReader.read` (GDAL's ZSTD + floating-point predictor decode of
  the chunk files a task reads: the children a parent's wavelet needs, with halos, a chunk's
  own error window, the coarse levels of the error passes);
- **chunk encode**: `level_chunks.write_chunk` (GDAL's encode into memory, the sha256, the
  file), in the task's thread and in GDAL's compression threads (process CPU during the
  call, less the task thread's: nothing else runs meanwhile with one worker);
- **kernels and Python**: the rest of the task thread (resampling, the EGM96 correction,
  the data-edge continuation, wavelet, exact errors, stride deltas, NaN masks, copies);
- **client**: the rest of the process (imports, the source's value scan and sha256, the
  graph, the build facts, metadata shards, VRTs, dask's scheduling).

Then GDAL's overview build of a copy of the raster (`build_overviews`, average: ``gdaladdo
-r average``), timed the same way, and what each part is in units of it: the codec and the
client alone are the floor under any ratio the kernels could reach. Process CPU
(``getrusage``: user + system, all threads), so the machine's load inflates it less than
wall time; print ``uptime`` with it.

    python benchmarks/profile_ingest_floor.py [RASTER] [--rounds 3]
"""

from __future__ import annotations

import argparse
import resource
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "benchmarks" / "cache" / "big_dem_8192.tif"
PARTS = ("chunk decode", "chunk encode", "kernels and Python", "client")


def _process_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


class _Split:
    """CPU seconds of the ingest's parts, gathered by wrapping the functions that spend them."""

    def __init__(self) -> None:
        self.task_thread = 0.0
        self.decode = 0.0
        self.encode = 0.0

    def install(self) -> None:
        from globeview.terrain.ingest import memory, schedule, tasks

        def run_task(func: Callable[..., Any], *args: Any) -> Any:
            t = time.thread_time()
            try:
                return func(*args)
            finally:
                self.task_thread += time.thread_time() - t
                memory.release_if_grown()

        read = tasks.ChunkReader.read

        def timed_read(reader: Any, *args: Any, **kw: Any) -> Any:
            c = _process_cpu()
            try:
                return read(reader, *args, **kw)
            finally:
                self.decode += _process_cpu() - c

        write = tasks.write_chunk

        def timed_write(*args: Any, **kw: Any) -> Any:
            c, t = _process_cpu(), time.thread_time()
            try:
                return write(*args, **kw)
            finally:
                self.encode += _process_cpu() - c
                # GDAL's compression threads' CPU is outside the task thread: add it there
                # so that `parts` can take the task thread apart.
                self.task_thread += (_process_cpu() - c) - (time.thread_time() - t)

        schedule.run_task = run_task
        tasks.ChunkReader.read = timed_read  # type: ignore[method-assign]
        tasks.write_chunk = timed_write

    def parts(self, total: float) -> dict[str, float]:
        return {
            "chunk decode": self.decode,
            "chunk encode": self.encode,
            "kernels and Python": self.task_thread - self.decode - self.encode,
            "client": total - self.task_thread,
        }


def _ingest_round(src: Path, split: _Split) -> dict[str, float]:
    from globeview.terrain.ingest.driver import ingest

    split.task_thread = split.decode = split.encode = 0.0  # this round's only
    with tempfile.TemporaryDirectory(prefix="gv-floor-") as tmp:
        c = _process_cpu()
        ingest([src], Path(tmp) / "store", force=True, progress=False, workers=1)
        total = _process_cpu() - c
    return {"total": total, **split.parts(total)}


def _gdal_round(src: Path) -> float:
    import rasterio
    from rasterio.enums import Resampling

    with tempfile.TemporaryDirectory(prefix="gv-floor-gdal-") as tmp:
        copy = Path(tmp) / src.name
        shutil.copyfile(src, copy)
        c = _process_cpu()
        with rasterio.open(copy, "r+") as ds:
            f = [2**k for k in range(1, 16) if max(ds.shape) >> k >= 256]
            ds.build_overviews(f, Resampling.average)
        return _process_cpu() - c


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("raster", nargs="?", type=Path, default=DEFAULT)
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds (medians)")
    args = ap.parse_args(argv)
    if not args.raster.is_file():
        print(f"no {args.raster}: python benchmarks/make_big_dem.py --size 8192", file=sys.stderr)
        return 2
    import os

    from globeview.terrain.ingest import driver  # noqa: F401  imported before the clock

    split = _Split()
    split.install()
    rows: list[dict[str, float]] = []
    gdal: list[float] = []
    for _ in range(max(1, args.rounds)):
        rows.append(_ingest_round(args.raster, split))
        gdal.append(_gdal_round(args.raster))
    g = statistics.median(gdal)
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(
        f"Ingest CPU by part, {args.raster.name}, 1 worker, {len(rows)} rounds (medians), "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load {load}"
    )
    print()
    print("| part | CPU s | / GDAL overviews |")
    print("|---|---:|---:|")
    for name in ("total", *PARTS):
        v = statistics.median(r[name] for r in rows)
        print(f"| {name} | {v:.2f} | {v / g:.1f}x |")
    print(f"| GDAL overviews (build_overviews average) | {g:.2f} | 1x |")
    floor = statistics.median(r["chunk decode"] + r["chunk encode"] + r["client"] for r in rows)
    print()
    print(
        f"codec + client alone: {floor:.2f} s = {floor / g:.1f}x GDAL; a 10x target leaves "
        f"{max(0.0, 10 * g - floor):.2f} s for the kernels and Python (now "
        f"{statistics.median(r['kernels and Python'] for r in rows):.2f} s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
