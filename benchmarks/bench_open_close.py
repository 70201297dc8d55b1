"""Open-render-close soak: RSS per cycle and its drift over N cycles, what survives a
released cycle, and gc object growth by type between the warm-up and the last cycle.

A cycle opens the embedded tile stores (TileStore.open), stacks them, makes a headless EGL
context, a plugin session, renders one frame, and releases everything. Target: <= 1 MB of RSS
growth from cycle 20 to the last (flat), no object of a released cycle left reachable.

    .venv/bin/python benchmarks/bench_open_close.py [--cycles 200] [--size 160x90]
    [--tracemalloc]

--tracemalloc shows where Python allocations grew, but its own bookkeeping grows RSS by
~0.1 MB per cycle: take the drift figure from a run without it.
"""

from __future__ import annotations

import argparse
import tracemalloc

from globeview.bench.harness import machine, parse_size
from globeview.bench.soak import run_open_close


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--cycles", type=int, default=200)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--size", default="160x90")
    ap.add_argument("--lod", default="chunked-sse")
    ap.add_argument(
        "--tracemalloc", action="store_true", help="also print the top Python allocation growth"
    )
    args = ap.parse_args()
    if args.tracemalloc:
        tracemalloc.start(8)
    snaps = {}

    def log(line: str) -> None:
        print(line, flush=True)
        if args.tracemalloc and line.startswith(f"cycle {args.warmup:4d}"):
            snaps["warm"] = tracemalloc.take_snapshot()

    res = run_open_close(args.cycles, parse_size(args.size), args.lod, args.warmup, log=log)
    try:
        from globeview.render.offscreen import create_headless_context

        ctx = create_headless_context()
        print(f"machine: {machine(str(ctx.info.get('GL_RENDERER', '?')))}")
        ctx.release()
    except Exception as exc:  # noqa: BLE001  the figures above stand without the machine line
        print(f"machine: ? ({exc})")
    print(
        f"RSS after {res['warmup']} cycles {res['rss_after_warmup']:.1f} MB, after "
        f"{res['cycles']}: {res['rss_last']:.1f} MB; drift {res['rss_drift_mb']:+.2f} MB "
        f"({res['per_cycle_mb'] * 1e3:+.1f} kB per cycle; RSS sampled after malloc_trim, "
        f"untrimmed drift {res['rss_raw_drift_mb']:+.2f} MB)"
    )
    print(
        f"GL objects of a session: {res['gl_objects_per_session']}, left unreleased after "
        f"release_gl: {res['gl_objects_left_after_release'] or 'none'}; GL contexts alive at "
        f"the end: {res['samples'][-1]['contexts']} (the one kept for reuse)"
    )
    print(f"objects of the last cycle alive after release: {res['alive_after_release'] or 'none'}")
    print("gc object growth by type (warm-up -> last):")
    for name, n in res["object_growth"].items():
        print(f"  {n:+7d}  {name}")
    if args.tracemalloc and "warm" in snaps:
        top = tracemalloc.take_snapshot().compare_to(snaps["warm"], "traceback")[:8]
        print("tracemalloc growth (top 8):")
        for st in top:
            print(f"  {st.size_diff / 1e3:+9.1f} kB {st.count_diff:+6d} blocks")
            for line in st.traceback.format()[-6:]:
                print(f"      {line}")
    verdict = "met" if res["target_met"] else "NOT met"
    if args.tracemalloc:
        verdict += " (tracemalloc on: RSS holds its own traces too; judge a run without it)"
    print(f"target: drift <= {res['target_mb']:g} MB over {res['cycles']} cycles: {verdict}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
