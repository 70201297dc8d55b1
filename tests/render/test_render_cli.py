"""`globeview render`: a PNG of the globe and the frame's figures as JSON; bad arguments give
exit code 2 and one line on stderr."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from inprocess_cli import run_globeview
from PIL import Image

pytestmark = pytest.mark.gl

STATS_KEYS = (
    "triangles",
    "tiles_drawn",
    "tiles_culled_frustum",
    "tiles_culled_horizon",
    "frame_ms",
    "lod_ms",
    "max_sse_px",
)


def globeview(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "globeview", "render", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONWARNINGS": "error::DeprecationWarning:globeview"},
    )


@pytest.mark.slow
def test_render_writes_png_and_stats(tmp_path: Path) -> None:
    out, stats = tmp_path / "globe.png", tmp_path / "stats.json"
    res = globeview(
        "--out",
        str(out),
        "--size",
        "200x150",
        "--camera=0,20,2e7,0,-90",
        "--background",
        "1,0,1",
        "--stats",
        str(stats),
    )
    assert res.returncode == 0, res.stderr
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape == (150, 200, 3)
    magenta = np.all(img == (255, 0, 255), axis=-1)
    # Space in the corners, the globe in the middle, and more than a flat disc of colour.
    assert magenta[0, 0] and magenta[-1, -1] and not magenta[75, 100]
    assert 0.2 < (~magenta).mean() < 0.8
    assert len(np.unique(img[~magenta].reshape(-1, 3), axis=0)) > 50
    data = json.loads(stats.read_text())
    for key in STATS_KEYS:
        assert isinstance(data[key], int | float) and data[key] >= 0, key
    assert data["triangles"] > 0 and data["tiles_drawn"] > 0
    assert data["max_sse_px"] <= 2.0 + 1e-6  # the default tau
    assert data["frame_ms"] > 0
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.slow
def test_render_camera_and_tau_change_the_frame(tmp_path: Path) -> None:
    def stats_for(*extra: str) -> dict:
        s = tmp_path / "s.json"
        res = globeview(
            "--out", str(tmp_path / "x.png"), "--size", "160x120", "--stats", str(s), *extra
        )
        assert res.returncode == 0, res.stderr
        return json.loads(s.read_text())

    oblique = stats_for("--camera=-71.3,44.2,6000,0,-10", "--tau", "4")
    assert oblique["max_sse_px"] <= 4.0 + 1e-6
    assert oblique["tiles_culled_frustum"] > 0  # most of the globe is behind or beside
    finer = stats_for("--camera=-71.3,44.2,6000,0,-10", "--tau", "1")
    assert finer["triangles"] > oblique["triangles"]


@pytest.mark.parametrize(
    "args",
    [
        ("--camera=1,2",),
        ("--camera=a,b,c",),
        ("--size", "abc"),
        ("--size", "10x10"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    tmp_path: Path, args: tuple[str, ...], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Refused before any GL: run in this process (`inprocess_cli`), with no headless context
    to be had (one made would fail the test)."""
    from globeview.render import offscreen

    def no_gl(*_a: object, **_k: object) -> None:
        raise AssertionError("a refused render made a GL context")

    monkeypatch.setattr(offscreen, "create_headless_context", no_gl)
    out = tmp_path / "never.png"
    res = run_globeview(["render", "--out", str(out), *args])
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("globeview"), res.stderr
    assert not out.exists()
