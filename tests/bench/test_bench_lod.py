"""benchmarks/bench_lod.py runs (one frame per case, one provider, one view) and prints a
row per case with its figures; bad arguments are one-line GlobeviewErrors. No timing is
asserted: the figures and the targets live in the script."""

from __future__ import annotations

import importlib.util
import itertools
import sys
from pathlib import Path

import pytest

from globeview.errors import GlobeviewError

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_lod.py"


def _bench_lod():
    spec = importlib.util.spec_from_file_location("bench_lod", SCRIPT)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run(mod, monkeypatch, *args: str) -> int:
    monkeypatch.setattr(sys, "argv", ["bench_lod.py", *args])
    return mod.main()


def test_moving_camera_rows_per_provider(monkeypatch, capsys) -> None:
    mod = _bench_lod()
    args = ("--frames", "2", "--size", "320x180", "--view", "White", "--motion", "turn", "move")
    assert _run(mod, monkeypatch, *args, "--lod", "quadtree-clod", "wavelet") == 0
    rows = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| ")][1:]
    assert len(rows) == 4  # 2 providers x 2 motions
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        # provider | view | size | motion | tiles | lod_ms | max | thread_ms | calls a frame
        # | lod_ms cold | clod reused | target
        assert cells[0] in ("quadtree-clod", "wavelet") and cells[3] in ("turn", "move")
        assert cells[2] == "320x180"
        assert int(cells[4]) > 0  # tiles selected
        assert float(cells[5]) > 0.0 and float(cells[9]) > 0.0  # lod_ms warm, cold
        assert int(cells[8]) > 0  # Python-level calls of a select
    clod = {
        c[3]: c
        for c in ([x.strip() for x in r.strip("|").split("|")] for r in rows)
        if c[0] == "quadtree-clod"
    }
    # The 0.01 degree turn stays under clod's reuse limit (each frame after the first
    # reuses the meshes); the move goes past it (every frame rebuilds).
    assert int(clod["turn"][10].split("/")[0]) >= 2 and clod["move"][10] == "0/3"
    assert "<= 10 ms" in clod["move"][11]  # the clod rebuild target is named


def test_move_poses_turn_past_clods_reuse_limit() -> None:
    mod = _bench_lod()
    poses = mod.move_poses((-71.3, 44.15, 9000.0, 0.0, -30.0), 3)
    assert len(poses) == 4
    for a, b in itertools.pairwise(poses):
        assert b[3] - a[3] == pytest.approx(0.2)  # heading: beyond 0.05 degree
        assert (b[0], b[1]) != (a[0], a[1])  # the eye moves


@pytest.mark.parametrize(
    "args",
    [
        ("--frames", "0"),
        ("--tau", "0"),
        ("--view", "Atlantis"),
        ("--lod", "no-such-provider", "--motion", "turn", "--view", "global"),
        ("--size", "12x12"),
    ],
)
def test_bad_arguments_are_one_line_errors(monkeypatch, args) -> None:
    mod = _bench_lod()
    with pytest.raises(GlobeviewError) as e:
        _run(mod, monkeypatch, *args)
    assert "\n" not in str(e.value)
