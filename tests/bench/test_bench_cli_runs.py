"""`globeview bench` subcommands on tiny headless runs: file outputs and structure only,
never timings (performance targets live in the benchmark output)."""

from __future__ import annotations

import argparse
import csv

import pytest

from globeview.bench.harness import CSV_COLUMNS


@pytest.fixture(scope="module", autouse=True)
def _need_gl():
    from globeview.render.offscreen import RenderError, create_headless_context

    try:
        create_headless_context().release()
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")


def _bench(argv: list[str]) -> int:
    from globeview.cli import bench

    parser = argparse.ArgumentParser(prog="globeview bench")
    bench.add_arguments(parser)
    return bench.run(parser.parse_args(argv))


def test_two_frame_flight_writes_csv(tmp_path, capsys):
    out = tmp_path / "f.csv"
    rc = _bench(["flight", "canyon_run", "--frames", "2", "--size", "160x90", "--csv", str(out)])
    assert rc == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2
    assert list(rows[0]) == CSV_COLUMNS
    for col in (
        "frame_ms",
        "lod_ms",
        "triangles",
        "tiles_drawn",
        "tiles_culled_frustum",
        "tiles_loading",
        "rss_mb",
    ):
        assert col in rows[0]
    assert int(rows[0]["triangles"]) > 0
    assert float(rows[1]["rss_mb"]) > 0
    assert "frame_ms median" in capsys.readouterr().out


def test_check_quick_prints_a_verdict_per_target(capsys):
    assert _bench(["check", "--quick"]) == 0
    out = capsys.readouterr().out
    verdicts = [ln for ln in out.splitlines() if ln.startswith(("PASS", "FAIL"))]
    assert len(verdicts) == 4
    for word in ("frame time", "lod_ms", "full resolution", "screen-space error"):
        assert any(word in ln for ln in verdicts), word
    assert "targets hold" in out


@pytest.mark.slow  # over 5 CPU-s (tests/cpu_durations.py)
def test_experiments_quick_writes_csv_png_md(tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "exp"
    rc = _bench(
        [
            "experiments",
            "--quick",
            "--out",
            str(out),
            "--lod",
            "chunked-sse",
            "--lod",
            "quadtree-clod",
        ]
    )
    assert rc == 0
    for name in ("tau_sweep.csv", "table1.csv", "fig_tau.png", "fig_rms.png", "report.md"):
        assert (out / name).stat().st_size > 0, name
    with (out / "tau_sweep.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["provider"] for r in rows} == {"chunked-sse", "quadtree-clod"}
    assert {"tau_px", "triangles", "fps", "rms_error", "max_sse_px"} <= set(rows[0])
    assert (out / "fig_tau.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out / "report.md").read_text()
    assert "GL renderer" in md and "TREND table 1" in md and "fig_rms.png" in md
