"""benchmarks/bench_plan.py (issue #25): bad arguments are one line, and a small run prints a
plan whose counts are the planner's for the same names (structure only, never timings)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "bench_plan.py"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, cwd=ROOT, timeout=300
    )


@pytest.mark.parametrize(
    ("args", "needle"), [(["--tiles", "0"], "--tiles"), (["--rounds", "0"], "--rounds")]
)
def test_bad_arguments_are_one_line(args: list[str], needle: str) -> None:
    proc = _run(*args)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and needle in lines[-1] and "Traceback" not in proc.stderr


def test_a_small_planet_plan_prints_the_planners_counts() -> None:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import bench_plan
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    from globeview.terrain.ingest.footprints import footprints_from_names
    from globeview.terrain.ingest.plan import plan_chunks

    proc = _run("--tiles", "300")
    assert proc.returncode == 0, proc.stderr
    m = re.search(r"planet plan: 300 SRTM 1\" names, (\d+) chunks, (\d+) shards: ", proc.stdout)
    assert m is not None, proc.stdout
    names = bench_plan.srtm_names(bench_plan.planet_cells(300))
    assert len(set(names)) == 300
    p = plan_chunks(footprints_from_names(names), 6)
    assert (int(m.group(1)), int(m.group(2))) == (p.chunks, p.shards())
    assert "sources: 300 (300 by name, 0 by header)" in proc.stdout
