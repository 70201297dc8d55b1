"""Regenerate the figures in docs/benchmarks.md and README.md from the benchmark scripts.

Each job runs one script in a child process and writes its output, verbatim, between that
job's markers (``<!-- bench:NAME@cpu -->`` ... ``<!-- /bench:NAME@cpu -->``), under a line that
names the machine, the date (UTC), the load average before and after and the command, so no
table in the docs is typed by hand. On a machine with a GPU the ``@gpu`` blocks are rewritten
instead (`globeview.bench.report.machine_tag`). Run it on a quiet machine: llvmpipe frame
times vary 2x with load, and the load is printed so a reader can tell.

    .venv/bin/python benchmarks/publish.py              # every job
    .venv/bin/python benchmarks/publish.py render lod   # some jobs
    .venv/bin/python benchmarks/publish.py --list
    .venv/bin/python benchmarks/publish.py --dry-run render   # print, write nothing

A job that fails leaves its block as it was and makes the exit status 1 (one line per job).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from globeview.bench.harness import machine  # noqa: E402  (the checkout first)
from globeview.bench.report import (  # noqa: E402
    BlockError,
    blocks_in,
    load_average,
    machine_tag,
    replace_block,
)

DOCS = ROOT / "docs" / "benchmarks.md"
README = ROOT / "README.md"


@dataclass(frozen=True)
class Job:
    """One benchmark run: ``argv`` after the Python interpreter, run from the repository root,
    its stdout written to block ``name@<tag>`` of each of ``documents``."""

    name: str
    argv: tuple[str, ...]
    documents: tuple[Path, ...] = (DOCS,)
    needs_display: bool = False  # a real Qt window: run under Xvfb when there is no display
    #: a Markdown file the command writes (relative to the root), published instead of stdout:
    #: its title dropped, its headings one level deeper, its image links through ``figures``.
    report: str | None = None
    #: images the command writes -> where the docs show them (both relative to the root).
    figures: tuple[tuple[str, str], ...] = ()


def _render(lod: str, *extra: str) -> tuple[str, ...]:
    return ("benchmarks/bench_render.py", "--lod", lod, "--frames", "15", *extra)


JOBS: dict[str, Job] = {
    j.name: j
    for j in (
        Job("render-chunked-sse", _render("chunked-sse")),
        Job("render-compare", _render("chunked-sse", "--compare", "--ladder"), (DOCS, README)),
        Job("render-quadtree-clod", _render("quadtree-clod")),
        Job("render-distance-regions", _render("distance-regions")),
        Job("render-wavelet", _render("wavelet")),
        Job("render-4k", ("benchmarks/bench_render.py", "--size", "3840x2160", "--frames", "5")),
        Job("fragment", ("benchmarks/bench_fragment.py", "--rounds", "9")),
        Job("lod", ("benchmarks/bench_lod.py",)),
        Job("tiles", ("benchmarks/bench_tiles.py",)),
        Job("check", ("-m", "globeview", "bench", "check", "--frames", "12")),
        Job("goto", ("benchmarks/bench_goto.py", "--rounds", "5"), needs_display=True),
        # Issue #27: flights in wall time with the window's background loader.
        Job("flight-async", ("benchmarks/bench_flight_async.py",)),
        Job("overlays", ("benchmarks/bench_overlays.py",)),
        Job("collapse", ("benchmarks/bench_collapse.py", "--frames", "9")),
        Job(
            "experiments",
            ("-m", "globeview", "bench", "experiments", "--out", "benchmarks/out/experiments"),
            report="benchmarks/out/experiments/report.md",
            figures=(
                ("benchmarks/out/experiments/fig_tau.png", "docs/img/bench_fig_tau.png"),
                ("benchmarks/out/experiments/fig_rms.png", "docs/img/bench_fig_rms.png"),
            ),
        ),
        Job("soak", ("-m", "globeview", "bench", "soak", "--frames", "200")),
        # Issue #18: ingest (today's, Dask 1/all cores, LocalCluster, GDAL) and remote stores.
        Job(
            "ingest",
            ("benchmarks/bench_ingest.py", "--sizes", "4096,8192", "--rounds", "3"),
            (DOCS, README),
        ),
        Job("remote", ("benchmarks/bench_remote.py", "--rounds", "3")),
    )
}


def gl_renderer() -> str:
    """The GL renderer the scripts will draw with (a throwaway EGL context)."""
    from globeview.render.offscreen import create_headless_context, release_headless_context

    ctx = create_headless_context()
    try:
        return str(ctx.info.get("GL_RENDERER", "?"))
    finally:
        release_headless_context(ctx)


def command_of(job: Job) -> list[str]:
    cmd = [sys.executable, *job.argv]
    if job.needs_display and not os.environ.get("DISPLAY") and shutil.which("xvfb-run"):
        cmd = ["xvfb-run", "-a", "-s", "-screen 0 1920x1080x24", *cmd]
    return cmd


def run_job(job: Job, renderer: str) -> str:
    """Run ``job`` and return its block body (header line + output).

    Raises:
        RuntimeError: the script failed (one line: its last line of stderr).
    """
    where = machine(renderer)  # with the time the job starts
    load0 = load_average()[0]
    t0 = time.perf_counter()
    proc = subprocess.run(command_of(job), cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise RuntimeError(f"{job.name}: exit {proc.returncode}: {last}")
    load1 = load_average()[0]
    output = proc.stdout if job.report is None else _report_body(job)
    shown = " ".join(("python", *job.argv))
    header = (
        f"*Generated by `benchmarks/publish.py {job.name}` running `{shown}` on {where}, "
        f"load {load0:.2f} before / {load1:.2f} after, {wall:.0f} s.*"
    )
    return header + "\n\n" + output.strip("\n")


def _report_body(job: Job) -> str:
    """The job's report file as a block body; its figures copied to where the docs show them."""
    assert job.report is not None
    lines = (ROOT / job.report).read_text().splitlines()
    if lines and lines[0].startswith("# "):
        lines = lines[1:]
    text = "\n".join("#" + ln if ln.startswith("#") else ln for ln in lines)
    for src, dst in job.figures:
        shutil.copyfile(ROOT / src, ROOT / dst)
        # Links in the report are relative to it; in docs/ they are relative to docs/.
        rel = os.path.relpath(ROOT / dst, DOCS.parent)
        text = text.replace(f"({Path(src).name})", f"({rel})")
    return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("jobs", nargs="*", help="job names (default: all); --list shows them")
    ap.add_argument("--list", action="store_true", help="list the jobs and exit")
    ap.add_argument("--dry-run", action="store_true", help="print the blocks, write nothing")
    args = ap.parse_args(argv)
    if args.list:
        for job in JOBS.values():
            print(f"{job.name}: python {' '.join(job.argv)}")
        return 0
    unknown = [n for n in args.jobs if n not in JOBS]
    if unknown:
        print(f"publish: unknown job {unknown[0]!r} (see --list)", file=sys.stderr)
        return 2
    renderer = gl_renderer()
    tag = machine_tag(renderer)
    texts = {doc: doc.read_text() for job in JOBS.values() for doc in job.documents}
    chosen = args.jobs or list(JOBS)
    for name in chosen:  # every block in place before minutes of benchmarks
        for doc in JOBS[name].documents:
            if f"{name}@{tag}" not in blocks_in(texts[doc]):
                print(f"publish: {doc.name} has no block {name}@{tag}", file=sys.stderr)
                return 2
    failed = 0
    for name in chosen:
        job = JOBS[name]
        print(f"publish: {name} ...", file=sys.stderr, flush=True)
        try:
            body = run_job(job, renderer)
            for doc in job.documents:
                texts[doc] = replace_block(texts[doc], f"{name}@{tag}", body)
        except (RuntimeError, BlockError) as exc:
            print(f"publish: {exc}", file=sys.stderr)
            failed += 1
            continue
        if args.dry_run:
            print(body + "\n")
    if not args.dry_run:
        from globeview.fileio import atomic_write_text

        for doc, text in texts.items():
            blocks_in(text)  # still well-formed
            if text != doc.read_text():
                atomic_write_text(doc, text)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
