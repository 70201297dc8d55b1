"""Remote-store benchmark (issue #18 item 4, issue #25 item 4): a view drawn from a store served
over HTTP on 127.0.0.1, from a cold disk cache and then a warm one, and over Debian's nginx
answering every request 20 ms late.

The store is built once (cached under benchmarks/cache/remote_store_STEM, re-ingesting an
unchanged source is a no-op) from ``--dem`` (default: the 8192^2 synthetic-detail benchmark
DEM over the White Mountains, benchmarks/make_big_dem.py; ``--dem data/N44W072.hgt`` is the
real SRTM3 tile) or taken as is with ``--store FOLDER``. It is served by
`globeview.bench.http_server.StaticServer` (a static server honouring Range, the one the tests
use) and, for the ``nginx`` run, by nginx (`globeview.bench.nginx_server.NginxServer`), and
opened by URL (`TileStore.open("http://127.0.0.1:PORT/...")`) on top of the embedded terrain,
as `globeview render URL` does.

Each run is a fresh child process drawing the view ``--view`` (default "low-altitude oblique
(White Mountains, 9 km)") of `globeview.bench.views.VIEWS` the way the window does: a running
view (its GL context made, not timed) to which the store is added once opened, tiles built by
the background loader (`GlobeRenderer.load_workers`: 4 threads for a remote layer on 2 cores),
frames drawn until none is loading. The view is drawn complete from the embedded layers first
(not timed: the view the user was looking at). Figures: seconds to open the store (manifest
and top shard), seconds from the open to the first frame with a resident tile of the store's
data and to the first complete frame (no tile loading), CPU seconds of the run's process from
the open to the complete frame (every thread), frames drawn, tiles, and tiles that failed;
the levels of the store's tiles in its first frame and the frames drawn blank after the add
(notes); the server's log gives the requests and bytes sent (nginx's also what came before
the first frame). Runs:

- ``local``: the same store opened from its folder (the reference);
- ``cold``: over HTTP with an empty disk cache;
- ``warm``: over HTTP again, a new process, the disk cache as the cold run left it;
- ``cold-slow``: cold again with the server answering every request ``--latency-ms`` late
  (default 50 ms, a far server's round trip; the loopback has none);
- ``nginx``: cold, over nginx answering ``--latency-ms`` late (its echo module's
  ``echo_sleep``), when nginx is installed (``--no-nginx``: not).

Rounds are interleaved (local, cold, warm, cold-slow, nginx, local, ...) and medians printed.

Targets printed: every run reaches a complete frame with no failed tile; the warm run asks the
server for nothing but the manifest (every chunk byte from the disk cache); over nginx the
first frame with the store's tiles comes within 2 s of the open (issue #25). A script that
prints figures, not a timed test; wall times on a shared machine vary with its load (printed).

    python benchmarks/bench_remote.py [--dem PATH | --store FOLDER] [--view NAME]
        [--size 1280x720] [--rounds 3] [--latency-ms 50] [--timeout 180] [--no-nginx]
        [--runs local,cold,warm,cold-slow,nginx] [--load-workers N]
"""

from __future__ import annotations

import argparse
import contextlib
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
#: Issue #25 item 4: first frame of a store over a static server 20 ms away, seconds.
FIRST_FRAME_TARGET_S = 2.0
RUN_LABELS = {
    "local": "local folder",
    "cold": "HTTP, cold disk cache",
    "warm": "HTTP, warm disk cache (new process)",
    "cold-slow": "HTTP, cold, server {ms:g} ms late a request",
    "nginx": "nginx, cold, {ms:g} ms late a request",
}
_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


class BenchError(Exception):
    """A bad argument or an unusable environment (one line, exit status 2)."""


# ---------------------------------------------------------------------------------------------
# The child: opens the store, draws frames until complete, prints one JSON line


def _store_tiles(bench, store, keys):
    """The resident tiles among the drawn ``keys`` ((N, 3) level, x, y: the frame's tiles
    and the ancestors standing in for the missing ones) that hold the
    store's data (a key finer than the store's levels: its ancestor at the finest level has
    data); retired tiles (built before the store was added) are not resident."""
    import numpy as np

    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    keys = keys[bench.session.renderer.pool.slots_of(keys) >= 0]
    out = []
    for level in np.unique(keys[:, 0]).tolist():
        sel = keys[keys[:, 0] == level]
        up = max(0, level - store.max_level)
        has = np.asarray(store.has_data(level - up, sel[:, 1] >> up, sel[:, 2] >> up), bool)
        out.append(sel[has.reshape(-1)])
    return np.concatenate(out) if out else keys[:0]


def _load_view(bench, deadline_s: float) -> None:
    """Frames until the view is complete (the embedded layers' tiles all resident)."""
    deadline = time.perf_counter() + deadline_s
    while time.perf_counter() < deadline:
        r, _ = bench.frame()
        if r.stats.tiles_drawn and r.stats.tiles_loading == 0:
            return
        time.sleep(0.005)
    raise RuntimeError("the embedded view never completed")


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
    # The window's path: a running view (its GL context made, not timed) to which the store
    # is added once opened; tiles built by the background loader.
    terrain = TerrainStack.from_stores(embedded)
    bench = Bench(terrain, tuple(spec["size"]))
    bench.session.renderer.async_loading = True
    if spec.get("load_workers") is not None:  # else chosen for the layers (4 for a remote one)
        bench.session.renderer.load_workers = int(spec["load_workers"])
    bench.set_pose(VIEWS[spec["view"]], cut=True)
    _load_view(bench, float(spec["timeout"]))  # the view the user was looking at
    store = None
    try:
        t0, cpu0 = time.perf_counter(), time.process_time()
        store = TileStore.open(spec["where"])
        t_open = time.perf_counter() - t0
        terrain.add(store, "remote")
        frames, deadline = 0, t0 + float(spec["timeout"])
        complete = False
        t_first = first_epoch = None
        blank, first_levels = 0, []
        while time.perf_counter() < deadline:
            r, _ = bench.frame()
            frames += 1
            st = r.stats
            blank += st.tiles_drawn == 0
            if t_first is None:
                mine = _store_tiles(bench, store, bench.session.renderer.last_drawn.keys)
                if len(mine):
                    t_first, first_epoch = time.perf_counter() - t0, time.time()
                    first_levels = sorted(set(mine[:, 0].tolist()))
            if st.tiles_loading == 0:
                complete = True
                break
            time.sleep(0.005)
        t_complete = time.perf_counter() - t0
        cpu_s = time.process_time() - cpu0  # every thread of the process
        loader = bench.session.renderer.loader
        failed = len(loader.failed) if loader is not None else 0
        first_failure = (
            str(next(iter(loader.failed.values()))).splitlines()[0][:200]
            if loader is not None and loader.failed
            else ""
        )
        result = {
            "open_s": t_open,
            "first_s": t_first if t_first is not None else float("nan"),
            "first_epoch": first_epoch,
            "complete_s": t_complete,
            "cpu_s": cpu_s,
            "complete": complete,
            "frames": frames,
            "blank": blank,
            "first_levels": first_levels,
            "deepest": int(r.render_set.keys[:, 0].max()) if len(r.render_set.keys) else 0,
            "tiles": st.tiles_drawn,
            "triangles": st.triangles,
            "failed": failed,
            "first_failure": first_failure,
            "loader": loader.describe() if loader is not None else "",
        }
    finally:
        bench.release()
        if store is not None:
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


def _one_run(kind: str, args: argparse.Namespace, store: Path, server, nginx) -> dict:
    """One child run of ``kind`` with its traffic: ``server`` (`StaticServer`) serves the
    HTTP runs but ``nginx`` (`NginxServer`, answering ``--latency-ms`` late) the nginx one."""
    if kind.startswith("cold") or kind == "nginx":
        shutil.rmtree(RUN_CACHE / "http", ignore_errors=True)
    server.clear_faults()
    if kind == "cold-slow":
        server.fault("*", delay_s=args.latency_ms / 1e3)
    server.reset_log()
    if nginx is not None:
        nginx.reset_log()
    base = nginx.url if kind == "nginx" else server.url
    spec = {
        "kind": kind,
        "where": str(store) if kind == "local" else f"{base}/{store.name}",
        "size": list(args.size),
        "timeout": args.timeout,
        "view": args.view,
        "load_workers": args.load_workers,
    }
    try:
        r = _run_child(spec)
    except RuntimeError as exc:
        return {"error": str(exc)}
    if kind == "nginx":
        r.update(_nginx_traffic(nginx, r.get("first_epoch")))
        return r
    n_req, n_manifest, sent, by_status = _traffic(server, store.parent)
    r.update(
        requests=n_req,
        manifest=n_manifest,
        sent=sent,
        by_status=by_status,
        in_flight=server.max_in_flight,
    )
    return r


def _nginx_traffic(nginx, first_epoch: float | None) -> dict:
    """The nginx run's traffic from its access log: requests, bytes, the most in flight, and
    the requests and files asked for before the first frame with the store's tiles."""
    reqs = nginx.requests("*")
    by_status: dict[int, int] = {}
    for q in reqs:
        by_status[q.status] = by_status.get(q.status, 0) + 1
    early = [q for q in reqs if first_epoch is not None and q.start < first_epoch]
    return {
        "requests": len(reqs),
        "manifest": sum(q.path.endswith("/manifest.json") for q in reqs),
        "sent": sum(q.sent for q in reqs),
        "by_status": by_status,
        "in_flight": nginx.max_in_flight("*"),
        "early_requests": len(early),
        "early_files": sorted(
            {
                q.path.rsplit("/", 4)[-1]
                if "/chunks/" not in q.path
                else "chunks/" + q.path.split("/chunks/")[1]
                for q in early
            }
        ),
        "early_bytes": sum(q.sent for q in early),
    }


def _report(
    kind: str,
    rs: list[dict],
    args: argparse.Namespace,
    notes: list[str],
    verdicts: list[tuple[str, bool]],
) -> int:
    """Print the table row of ``kind``'s runs, adding notes and verdicts; 1 when a run
    failed outright, else 0."""
    ok = [r for r in rs if "error" not in r]
    label = RUN_LABELS.get(kind, kind).format(ms=args.latency_ms)
    if len(ok) < len(rs):
        first = next(r["error"] for r in rs if "error" in r)
        print(f"| {label} | failed: {first} | | | | | | | | |")
        verdicts.append((f"{label} completes every round", False))
        return 1

    def med(key: str) -> float:
        return statistics.median(r[key] for r in ok)

    failed = max(r["failed"] for r in ok)
    print(
        f"| {label} | {med('open_s'):.2f} | {med('first_s'):.2f} | {med('complete_s'):.2f} | "
        f"{med('cpu_s'):.1f} | {med('frames'):.0f} | {med('tiles'):.0f} | {failed} | "
        f"{med('requests'):.0f} | {med('sent') / 1e6:.2f} |",
        flush=True,
    )
    last = ok[-1]
    notes.append(
        f"{label}: the first frame drew the store's data at levels "
        f"{', '.join(map(str, last['first_levels'])) or '-'} (the view down to level "
        f"{last['deepest']}); blank frames after the add: "
        f"{', '.join(str(r['blank']) for r in ok)}"
    )
    if failed:
        first = next(r["first_failure"] for r in ok if r["failed"])
        notes.append(f"{label}: first failed tile: {first}")
    verdicts.append(
        (f"{label}: complete frame, no failed tile", all(r["complete"] for r in ok) and not failed)
    )
    if kind in ("cold", "nginx"):
        statuses = ", ".join(f"{s}: {n}" for s, n in sorted(ok[-1]["by_status"].items()))
        notes.append(
            f"{kind}: answers by status {statuses}; at most "
            f"{max(r['in_flight'] for r in ok)} requests in flight at once; loader "
            f"{ok[-1]['loader']}; {med('cpu_s'):.1f} CPU s from the open to the complete frame"
        )
    if kind == "warm":
        verdicts.append(
            (
                f"warm: only the manifest fetched ({med('requests'):.0f} requests, "
                f"{med('manifest'):.0f} of the manifest)",
                all(r["requests"] == r["manifest"] for r in ok),
            )
        )
    if kind == "nginx":
        last = ok[-1]
        notes.append(
            f"nginx: before the first frame {last['early_requests']} requests, "
            f"{len(last['early_files'])} files, {last['early_bytes'] / 1e3:.0f} kB: "
            + ", ".join(last["early_files"])
        )
        verdicts.append(
            (
                f"nginx, {args.latency_ms:g} ms a request: first frame with the store's tiles "
                f"within {FIRST_FRAME_TARGET_S:g} s (median {med('first_s'):.2f} s)",
                med("first_s") <= FIRST_FRAME_TARGET_S,
            )
        )
    return 0


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
    from globeview.bench.views import VIEWS

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
    ap.add_argument(
        "--view",
        default=VIEW,
        choices=sorted(VIEWS),
        metavar="NAME",
        help=f"the view drawn (globeview.bench.views; default {VIEW!r})",
    )
    ap.add_argument(
        "--no-nginx",
        action="store_true",
        help="no run over nginx (by default one more cold run over Debian's nginx answering "
        "--latency-ms late, when nginx and its echo module are installed)",
    )
    ap.add_argument(
        "--runs",
        help="only these runs, comma-separated (local, cold, warm, cold-slow, nginx)",
    )
    ap.add_argument(
        "--load-workers",
        type=int,
        help="loader threads (default: chosen for the layers, 4 with a remote one on 2 cores)",
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
    if args.load_workers is not None and not 1 <= args.load_workers <= 64:
        raise BenchError(f"--load-workers must be 1..64, got {args.load_workers}")
    if args.runs is not None:
        args.runs = [r.strip() for r in args.runs.split(",") if r.strip()]
        unknown = [r for r in args.runs if r not in (*RUN_KINDS, "cold-slow", "nginx")]
        if unknown or not args.runs:
            raise BenchError(f"--runs: unknown run {(unknown or [''])[0]!r}")
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
        from globeview.bench.nginx_server import NginxServer, find_nginx
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
        files = [p for p in store.rglob("*") if p.is_file()]
        mb = sum(p.stat().st_size for p in files) / 1e6
        RUN_CACHE.mkdir(parents=True, exist_ok=True)
        try:
            _run_child({"kind": "prepare"})  # the embedded stores, outside any timing
        except RuntimeError as exc:
            raise BenchError(str(exc)) from None
        print(
            f"\nStore {store.name}: {len(files)} files, {mb:.0f} MB, served from 127.0.0.1; "
            f"view {args.view!r}, {args.size[0]}x{args.size[1]}, chunked-sse tau 2, the store "
            "opened and added over the embedded layers of a running view, frames drawn as the "
            "window draws them (background loader) until none is loading; first frame: the "
            "first with a resident tile of the store's data\n"
        )
        print(
            "| run | open s | first frame s | complete frame s | CPU s | frames | tiles "
            "| failed | requests | MB sent |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        verdicts: list[tuple[str, bool]] = []
        notes: list[str] = []
        broken = 0  # runs that failed outright (exit status 1: publish.py keeps the old block)
        kinds = [*RUN_KINDS, *(("cold-slow",) if args.latency_ms > 0 else ())]
        if args.latency_ms > 0 and not args.no_nginx:
            if find_nginx(latency=True) is None:
                notes.append("nginx with its echo module is not installed: no nginx run")
            else:
                kinds.append("nginx")
        if args.runs is not None:
            kinds = [k for k in kinds if k in args.runs]
        runs: dict[str, list[dict]] = {k: [] for k in kinds}
        with contextlib.ExitStack() as servers:
            server = servers.enter_context(StaticServer(store.parent).start())
            nginx = None
            if "nginx" in kinds:
                nginx = servers.enter_context(NginxServer(store.parent, args.latency_ms).start())
            for _ in range(args.rounds):  # interleaved: the load changes between rounds
                for kind in kinds:
                    runs[kind].append(_one_run(kind, args, store, server, nginx))
            server.clear_faults()
        for kind in kinds:
            broken += _report(kind, runs[kind], args, notes, verdicts)
        print()
        load = " ".join(f"{v:.2f}" for v in os.getloadavg())
        print(f"Medians of {args.rounds} interleaved round(s); load {load} at the end.")
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
