"""Build a store from a synthetic planet (`make_planet.py`) with `globeview ingest` in a child
process and print its figures (issue #25's proof, published in docs/scale.md).

One run: ``globeview ingest SRC... --out STORE --quiet [--workers W] [ARGS]``, timed from
here: wall seconds, CPU seconds of the child and its workers (user + sys, from
``RUSAGE_CHILDREN``: the machine is shared, CPU is the figure that carries over), the peak RSS
of the largest process (``ru_maxrss`` of the children), then from the store: its size and
number of files, the finest level and its tiles with data (manifest), CPU a finest node
(CPU / (finest tiles with data x 64^2 nodes), as docs/scale.md counts nodes) and CPU a node
of the chunk files (every level: what `terrain/ingest/cost.py` counts). ``--keep`` keeps the
store (default: removed after counting, so the next build has the disk), ``--digest FILE``
writes every file's sha256 (to compare two builds). Every ``--every`` seconds (default 60) a
line says how far the build is (Linux): the ingest process's CPU seconds so far (its threads;
not a process pool's workers), its RSS and peak RSS, and the chunk files in its building
folder, so a build stopped before the end (a shared machine, a deadline) still has figures.

    python benchmarks/bench_planet.py --out /tmp/planet/store200 [--workers 2] \\
        -- @benchmarks/cache/planet/srtm3/tiles_200.txt
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GLOBEVIEW = Path(sys.executable).with_name("globeview")


def store_figures(store: Path) -> dict[str, float]:
    """Size, files, finest level, its tiles with data and the chunk files' nodes (manifest)."""
    files = [p for p in store.rglob("*") if p.is_file()]
    manifest = json.loads((store / "manifest.json").read_text(encoding="utf-8"))
    levels = manifest["levels"]
    tile_n = int(manifest.get("tile_n") or manifest.get("header", {}).get("tile_n") or 6)
    finest = max((lv for lv in levels if lv.get("tiles")), key=lambda lv: lv["level"])
    n = 1 << tile_n
    return {
        "bytes": sum(p.stat().st_size for p in files),
        "files": len(files),
        "chunk_files": sum(1 for p in files if p.suffix == ".tif"),
        "max_level": finest["level"],
        "finest_tiles": finest["tiles"],
        "finest_nodes": finest["tiles"] * n * n,
        "chunk_nodes": sum(lv["chunks"] for lv in levels) * (16 * n) ** 2,
    }


def digest(store: Path) -> dict[str, str]:
    """Every file's sha256 by its path in the store."""
    out = {}
    for p in sorted(store.rglob("*")):
        if p.is_file():
            out[p.relative_to(store).as_posix()] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def _proc_figures(pid: int) -> tuple[float, int, int] | None:
    """(CPU seconds, RSS bytes, peak RSS bytes) of a running process from /proc, or None."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        status = Path(f"/proc/{pid}/status").read_text().splitlines()
    except (OSError, IndexError):
        return None
    mem = {ln.split(":")[0]: int(ln.split()[1]) * 1024 for ln in status if ln.startswith("Vm")}
    cpu = (int(stat[11]) + int(stat[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime
    return cpu, mem.get("VmRSS", 0), mem.get("VmHWM", 0)


def _building_chunks(out: Path) -> int:
    """Chunk files so far in the building folder(s) of ``out`` (``.NAME.building-*``)."""
    return sum(1 for d in out.parent.glob(f".{out.name}.building-*") for _ in d.rglob("*.tif"))


def _wait_reporting(proc: subprocess.Popen[bytes], out: Path, every: float, t0: float) -> int:
    """Wait for the ingest, printing a progress line every ``every`` seconds."""
    while True:
        try:
            return proc.wait(timeout=every)
        except subprocess.TimeoutExpired:
            fig = _proc_figures(proc.pid)
            if fig is not None:
                cpu, rss, hwm = fig
                print(
                    f"  {time.perf_counter() - t0:6.0f} s wall: ingest {cpu:7.1f} CPU s, RSS "
                    f"{rss / 2**20:.0f} MiB (peak {hwm / 2**20:.0f}), "
                    f"{_building_chunks(out)} chunk files, load {os.getloadavg()[0]:.1f}",
                    flush=True,
                )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="the store to build (replaced)")
    ap.add_argument("--workers", default=None, help="globeview ingest --workers")
    ap.add_argument("--keep", action="store_true", help="keep the store")
    ap.add_argument("--digest", type=Path, default=None, help="write the files' sha256 here")
    ap.add_argument("--every", type=float, default=60.0, help="seconds between progress lines")
    ap.add_argument("args", nargs="+", help="sources and other ingest arguments (after --)")
    a = ap.parse_args()
    cmd = [str(GLOBEVIEW), "ingest", *a.args, "--out", str(a.out), "--quiet", "--force"]
    if a.workers:
        cmd += ["--workers", a.workers]
    load = os.getloadavg()
    print(f"bench_planet {datetime.now(UTC):%Y-%m-%d %H:%M} UTC, load {load[0]:.2f}")
    print("$ " + " ".join(cmd), flush=True)
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    code = _wait_reporting(subprocess.Popen(cmd), a.out, a.every, t0)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    if code != 0:
        print(f"bench_planet: the ingest failed (exit {code}) after {wall:.0f} s")
        return 1
    f = store_figures(a.out)
    print(
        f"built in {wall:.0f} s wall, {cpu:.1f} CPU s (user+sys, the ingest and its workers), "
        f"peak RSS {r1.ru_maxrss / 1024:.0f} MiB (largest process), load after "
        f"{os.getloadavg()[0]:.2f}\n"
        f"store {f['bytes'] / 1e9:.2f} GB, {f['files']} files ({f['chunk_files']} chunk "
        f"files); finest level {f['max_level']}: {f['finest_tiles']} tiles with data, "
        f"{f['finest_nodes'] / 1e9:.3f} G nodes; CPU {cpu / f['finest_nodes'] * 1e9:.0f} ns a "
        f"finest node, {cpu / f['chunk_nodes'] * 1e9:.0f} ns a node of the chunk files "
        f"({f['chunk_nodes'] / 1e9:.2f} G, every level)"
    )
    if a.digest is not None:
        a.digest.write_text(json.dumps(digest(a.out), indent=0) + "\n", encoding="utf-8")
    if not a.keep:
        shutil.rmtree(a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
