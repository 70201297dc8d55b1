"""Remote-store benchmark (issue #18 item 4): the White Mountains view drawn from a store served
over HTTP on 127.0.0.1, from a cold disk cache and then a warm one.

The store is built once (cached under benchmarks/cache/remote_store_STEM, re-ingesting an
unchanged source is a no-op) from ``--dem`` (default: the 8192^2 synthetic-detail benchmark
DEM over the White Mountains, benchmarks/make_big_dem.py; ``--dem data/N44W072.hgt`` is the
real SRTM3 tile) or taken as is with ``--store FOLDER``. It is served by
`globeview.bench.http_server.StaticServer` (a static server honouring Range, the one the tests
use) and opened by URL (`TileStore.open("http://127.0.0.1:PORT/...")`) on top of the embedded
terrain, as `globeview render URL` does.

Each run is a fresh child process drawing the view "low-altitude oblique (White Mountains,
9 km)" of `globeview.bench.views.VIEWS` the way the window does (tiles built by the background
loader, frames drawn until none is loading); figures: seconds to open the store (manifest),
seconds from the open to the first complete frame (no tile loading), frames drawn, tiles, and
tiles that failed; the server's log gives the requests and bytes sent. Runs:

- ``local``: the same store opened from its folder (the reference);
- ``cold``: over HTTP with an empty disk cache;
- ``warm``: over HTTP again, a new process, the disk cache as the cold run left it;
- ``cold-slow``: cold again with the server answering every request ``--latency-ms`` late
  (default 50 ms, a far server's round trip; the loopback has none).

Rounds are interleaved (local, cold, warm, cold-slow, local, ...) and medians printed.

Targets printed: every run reaches a complete frame with no failed tile; the warm run asks the
server for nothing but the manifest (every chunk byte from the disk cache). A script that
prints figures, not a timed test; wall times on a shared machine vary with its load (printed).

    python benchmarks/bench_remote.py [--dem PATH | --store FOLDER] [--size 1280x720]
        [--rounds 3] [--latency-ms 50] [--timeout 180]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "benchmarks" / "cache"
#: GLOBEVIEW_CACHE_DIR of the runs: stores/ holds the embedded stores (built once), http/ the
#: remote disk cache (emptied before the cold run).
RUN_CACHE = CACHE / "remote-bench-cache"
VIEW = "low-altitude oblique (White Mountains, 9 km)"
RUN_KINDS = ("local", "cold", "warm")
RUN_LABELS = {
    "local": "local folder",
    "cold": "HTTP, cold disk cache",
    "warm": "HTTP, warm disk cache (new process)",
    "cold-slow": "HTTP, cold, server {ms:g} ms late a request",
}
_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


class BenchError(Exception):
    """A bad argument or an unusable environment (one line, exit status 2)."""


# ---------------------------------------------------------------------------------------------
# The child: opens the store, draws frames until complete, prints one JSON line


def _child(spec: dict) -> None:
    from globeview.bench.harness import Bench
    from globeview.bench.views import VIEWS
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores
    from globeview.terrain.store.tile_store import TileStore

    embedded = embedded_stores()  # local, built by the prepare child: not timed
    if spec["kind"] == "prepare":
        print("RESULT {}", flush=True)
        return
    t0 = time.perf_counter()
    store = TileStore.open(spec["where"])
    t_open = time.perf_counter() - t0
    terrain = TerrainStack.from_stores([*embedded, store])
    bench = Bench(terrain, tuple(spec["size"]))
    try:
        bench.session.renderer.async_loading = True  # the window's path: the loader thread
        bench.set_pose(VIEWS[VIEW], cut=True)
        frames, deadline = 0, t0 + float(spec["timeout"])
        complete = False
        while time.perf_counter() < deadline:
            r, _ = bench.frame()
            frames += 1
            st = r.stats
            if st.tiles_loading == 0:
                complete = True
                break
            time.sleep(0.005)
        t_complete = time.perf_counter() - t0
        loader = bench.session.renderer.loader
        failed = len(loader.failed) if loader is not None else 0
        first_failure = (
            str(next(iter(loader.failed.values()))).splitlines()[0][:200]
            if loader is not None and loader.failed
            else ""
        )
        result = {
            "open_s": t_open,
            "complete_s": t_complete,
            "complete": complete,
            "frames": frames,
            "tiles": st.tiles_drawn,
            "triangles": st.triangles,
            "failed": failed,
            "first_failure": first_failure,
        }
    finally:
        bench.release()
        store.close()
    print("RESULT " + json.dumps(result), flush=True)


# ---------------------------------------------------------------------------------------------
# The parent: builds/serves the store, runs the children, reads the server's log


def _run_child(spec: dict) -> dict:
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(RUN_CACHE)}
    with tempfile.TemporaryDirectory(prefix="gv-bench-remote-cfg-") as cfg:
        env.setdefault("GLOBEVIEW_CONFIG_DIR", cfg)  # removed after the run, not left in /tmp
        proc = subprocess.run(
            [sys.executable, str(Path(__file__).resolve()), "--child", json.dumps(spec)],
            capture_output=True,
            text=True,
            env=env,
            cwd=ROOT,
        )
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if proc.returncode or line is None:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise RuntimeError(f"{spec['kind']} run failed (exit {proc.returncode}): {last}")
    return json.loads(line[len("RESULT ") :])


def _traffic(server, root: Path) -> tuple[int, int, int, dict[int, int]]:
    """(requests, manifest requests, body bytes sent, {status: count}) from the server log."""
    sizes: dict[str, int] = {}
    total = manifest = 0
    by_status: dict[int, int] = {}
    for req in server.requests("*"):
        by_status[req.status] = by_status.get(req.status, 0) + 1
        if req.path.endswith("/manifest.json"):
            manifest += 1
        if req.method != "GET" or req.status not in (200, 206):
            continue
        if req.path not in sizes:
            f = root / req.path.lstrip("/")
            sizes[req.path] = f.stat().st_size if f.is_file() else 0
        size = sizes[req.path]
        m = _RANGE.match((req.range or "").strip())
        if req.status == 206 and m:
            a, b = m.group(1), m.group(2)
            start, end = (
                (int(a), size if not b else min(int(b) + 1, size))
                if a
                else (
                    max(0, size - int(b)),
                    size,
                )
            )
            total += max(0, end - start)
        else:
            total += size
    return len(server.requests("*")), manifest, total, by_status


def _build_store(dem: Path) -> Path:
    """The store of ``dem`` under benchmarks/cache (built once; a no-op when current)."""
    from globeview.terrain.ingest.driver import ingest

    out = CACHE / f"remote_store_{dem.stem}"
    CACHE.mkdir(parents=True, exist_ok=True)  # a fresh clone has no benchmarks/cache yet
    t = time.perf_counter()
    from globeview.terrain.store.identify import identify

    # This script's own store: one of an older format is rebuilt (ingest asks for --force).
    stale = identify(out).is_globeview and not identify(out).is_current
    res = ingest([dem], out, progress=False, force=stale)
    if not res.up_to_date:
        print(f"(built {out.relative_to(ROOT)} in {time.perf_counter() - t:.0f} s, not timed)")
    return out


def _default_dem() -> Path:
    path = CACHE / "big_dem_8192.tif"
    if not path.exists():
        gen = subprocess.run(
            [sys.executable, str(ROOT / "benchmarks" / "make_big_dem.py"), "--size", "8192"],
            capture_output=True,
            text=True,
        )
        if gen.returncode != 0 or not path.exists():
            last = (gen.stderr.strip().splitlines() or ["no message"])[-1]
            raise BenchError(f"cannot make the benchmark DEM: {last}")
    return path


def _parse(argv: list[str] | None) -> argparse.Namespace:
    class Parser(argparse.ArgumentParser):
        def error(self, message: str):  # type: ignore[override]
            raise BenchError(message)

    ap = Parser(description=__doc__.splitlines()[0])
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--dem", help="DEM to build the served store from (default: big_dem_8192)")
    src.add_argument("--store", help="serve this existing store folder instead")
    ap.add_argument("--size", default="1280x720", help="frame size WxH (16..8192)")
    ap.add_argument("--timeout", type=float, default=180.0, help="seconds a run may take")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds (medians)")
    ap.add_argument(
        "--latency-ms",
        type=float,
        default=50.0,
        help="a cold run more with the server answering this late (a WAN; 0: none)",
    )
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        return args
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise BenchError(f"--size must look like 1280x720, not {args.size!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise BenchError(f"--size {args.size} is out of range (16..8192 pixels a side)")
    args.size = (w, h)
    if not (1.0 <= args.timeout <= 3600.0):  # NaN too
        raise BenchError(f"--timeout must be 1..3600 seconds, got {args.timeout}")
    if not (1 <= args.rounds <= 20):
        raise BenchError(f"--rounds must be in 1..20, got {args.rounds}")
    if not (0.0 <= args.latency_ms <= 5000.0):
        raise BenchError(f"--latency-ms must be 0..5000, got {args.latency_ms}")
    for name in ("dem", "store"):
        p = getattr(args, name)
        if p is not None:
            path = Path(p).expanduser().absolute()
            if name == "dem" and not path.is_file():
                raise BenchError(f"--dem {p}: no such file")
            if name == "store" and not (path / "manifest.json").is_file():
                raise BenchError(f"--store {p}: not a store folder (no manifest.json)")
            setattr(args, name, path)
    return args


def _header() -> str:
    cpu = platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(
                (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu
            )
    except OSError:
        pass
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    return (
        f"Remote store benchmark, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {cpu}, "
        f"{os.cpu_count()} cores, load {load}"
    )


def main(argv: list[str] | None = None) -> int:
    try:
        args = _parse(argv)
        if args.child is not None:
            _child(json.loads(args.child))
            return 0
        print(_header())
        print(
            "Targets: every run reaches a complete frame (no tile loading) with no failed tile; "
            "the warm run fetches nothing but the manifest (chunks from the disk cache)"
        )
        from globeview.bench.http_server import StaticServer
        from globeview.errors import GlobeviewError

        try:
            store = (
                args.store if args.store is not None else _build_store(args.dem or _default_dem())
            )
        except GlobeviewError as exc:
            raise BenchError(str(exc).splitlines()[0]) from None
        from globeview.terrain.store.identify import identify
        from globeview.terrain.store.schema import FORMAT_VERSION

        ident = identify(store)
        if not ident.is_current:  # checked before serving: one line, not three failed runs
            raise BenchError(
                f"--store {store}: a store of format {ident.version}, this globeview reads "
                f"{FORMAT_VERSION} (rebuild it with globeview ingest --force)"
            )
        files = [p for p in store.iterdir() if p.is_file()]
        mb = sum(p.stat().st_size for p in files) / 1e6
        RUN_CACHE.mkdir(parents=True, exist_ok=True)
        try:
            _run_child({"kind": "prepare"})  # the embedded stores, outside any timing
        except RuntimeError as exc:
            raise BenchError(str(exc)) from None
        print(
            f"\nStore {store.name}: {len(files)} files, {mb:.0f} MB, served from 127.0.0.1; "
            f"view {VIEW!r}, {args.size[0]}x{args.size[1]}, chunked-sse tau 2, frames drawn "
            "as the window draws them (background loader) until none is loading\n"
        )
        print("| run | open s | complete frame s | frames | tiles | failed | requests | MB sent |")
        print("|---|---:|---:|---:|---:|---:|---:|---:|")
        verdicts: list[tuple[str, bool]] = []
        notes: list[str] = []
        broken = 0  # runs that failed outright (exit status 1: publish.py keeps the old block)
        kinds = [*RUN_KINDS, *(("cold-slow",) if args.latency_ms > 0 else ())]
        runs: dict[str, list[dict]] = {k: [] for k in kinds}
        with StaticServer(store.parent).start() as server:
            url = f"{server.url}/{store.name}"
            for _ in range(args.rounds):  # interleaved: the load changes between rounds
                for kind in kinds:
                    if kind.startswith("cold"):
                        shutil.rmtree(RUN_CACHE / "http", ignore_errors=True)
                    server.clear_faults()
                    if kind == "cold-slow":
                        server.fault("*", delay_s=args.latency_ms / 1e3)
                    server.reset_log()
                    spec = {
                        "kind": kind,
                        "where": str(store) if kind == "local" else url,
                        "size": list(args.size),
                        "timeout": args.timeout,
                    }
                    try:
                        r = _run_child(spec)
                    except RuntimeError as exc:
                        r = {"error": str(exc)}
                    n_req, n_manifest, sent, by_status = _traffic(server, store.parent)
                    r.update(
                        requests=n_req,
                        manifest=n_manifest,
                        sent=sent,
                        by_status=by_status,
                        in_flight=server.max_in_flight,
                    )
                    runs[kind].append(r)
            server.clear_faults()
        for kind in kinds:
            ok = [r for r in runs[kind] if "error" not in r]
            label = RUN_LABELS.get(kind, kind).format(ms=args.latency_ms)
            if len(ok) < len(runs[kind]):
                first = next(r["error"] for r in runs[kind] if "error" in r)
                print(f"| {label} | failed: {first} | | | | | | |")
                verdicts.append((f"{label} completes every round", False))
                broken += 1
                continue

            def med(key: str, rs: list[dict] = ok) -> float:
                return statistics.median(r[key] for r in rs)

            failed = max(r["failed"] for r in ok)
            print(
                f"| {label} | {med('open_s'):.2f} | {med('complete_s'):.2f} | "
                f"{med('frames'):.0f} | {med('tiles'):.0f} | {failed} | {med('requests'):.0f} | "
                f"{med('sent') / 1e6:.2f} |",
                flush=True,
            )
            if failed:
                first = next(r["first_failure"] for r in ok if r["failed"])
                notes.append(f"{label}: first failed tile: {first}")
            verdicts.append(
                (
                    f"{label}: complete frame, no failed tile",
                    all(r["complete"] for r in ok) and not failed,
                )
            )
            if kind == "cold":
                statuses = ", ".join(f"{s}: {n}" for s, n in sorted(ok[-1]["by_status"].items()))
                notes.append(
                    f"cold: answers by status {statuses}; at most "
                    f"{max(r['in_flight'] for r in ok)} requests in flight at once"
                )
            if kind == "warm":
                verdicts.append(
                    (
                        f"warm: only the manifest fetched ({med('requests'):.0f} requests, "
                        f"{med('manifest'):.0f} of the manifest)",
                        all(r["requests"] == r["manifest"] for r in ok),
                    )
                )
        print()
        print(f"Medians of {args.rounds} interleaved round(s).")
        for n in notes:
            print(f"- {n}")
        for what, good in verdicts:
            print(f"- {what}: {'met' if good else 'NOT MET'}")
        return 1 if broken else 0
    except BenchError as exc:
        print(f"bench_remote: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
