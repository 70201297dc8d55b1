"""`globeview render --tool` draws through the same frame pipeline as everything else
(issue #14): the tool's overlay is part of `GlobeSession.render`, not a separate call, so the
CLI's picture is pixel for pixel the plugin-author fixture's (`render_frame`) and --stats
counts the overlay the frame drew. In-process CLI, real EGL, the built-in measure tool
through the registry."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.gl

SIZE = (160, 120)
CAMERA = (-122.3, 46.2, 4.0e5, 0.0, -70.0)
POINTS = [(-122.9, 45.6), (-121.7, 46.8)]


@pytest.mark.slow
def test_cli_tool_overlay_is_the_frames_own(
    tmp_path, monkeypatch, globeview_gl, globeview_terrain, globeview_registry
) -> None:
    from inprocess_cli import run_globeview

    from globeview.app.testing import render_frame

    monkeypatch.setenv("GLOBEVIEW_CONFIG_DIR", str(tmp_path / "config"))
    # The CLI opens the embedded DEMs from the cache the session's `globeview_terrain` ingested
    # them into (CACHE/stores/NAME): the same stores as `render_frame`, not a second ingest.
    cache = globeview_terrain.layers[0].store.path.parents[1]
    assert (cache / "stores").is_dir()
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(cache))
    out, stats = tmp_path / "m.png", tmp_path / "m.json"
    plain = tmp_path / "plain.png"
    common = ["render", "--no-borders", "--size", f"{SIZE[0]}x{SIZE[1]}"]
    common += ["--camera", ",".join(str(v) for v in CAMERA)]
    points = ";".join(f"{lon},{lat}" for lon, lat in POINTS)
    res = run_globeview([*common, "--out", str(plain)])
    assert res.returncode == 0, res.stderr
    res = run_globeview([*common, "--tool", "measure", "--points", points, "--out", str(out),
                         "--stats", str(stats)])  # fmt: skip
    assert res.returncode == 0, res.stderr
    cli = np.asarray(Image.open(out).convert("RGB"))
    drawn = json.loads(stats.read_text())["tool"]["overlay_drawn"]
    assert drawn > 0
    assert (cli != np.asarray(Image.open(plain).convert("RGB"))).any(axis=-1).sum() > 50

    frame = render_frame(
        globeview_gl,
        globeview_terrain,
        globeview_registry,
        tool="measure",
        points=POINTS,
        camera=CAMERA,
        size=SIZE,
    )
    try:
        assert frame.failures == {}
        assert np.array_equal(cli, frame.image)  # the same frame, the same path
    finally:
        frame.session.release_gl()
