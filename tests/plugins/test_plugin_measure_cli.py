"""The measure tool from the command line, as a user runs it (real subprocesses of
``globeview``): ``render --tool measure --points A;B --tool-csv`` writes the picture, prints
the measurement and writes the profile, whose heights are `globeview height`'s at the same
points; refused points are one line, exit 2, and nothing is written."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pyproj import Geod

REPO = Path(__file__).resolve().parents[2]
SRTM = REPO / "data" / "N44W072.hgt"
POINTS = "-71.45,44.23;-71.22,44.31"
CAMERA = "--camera=-71.335,44.27,40000"


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory, seed_cache) -> dict[str, str]:
    """The children's environment: a config folder and a cache of the module's own, the cache
    seeded with the embedded DEMs' stores (copied, not ingested again by the first child)."""
    return {
        **os.environ,
        "GLOBEVIEW_CACHE_DIR": str(seed_cache(tmp_path_factory.mktemp("cache"))),
        "GLOBEVIEW_CONFIG_DIR": str(tmp_path_factory.mktemp("config")),
    }


def gv(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "globeview", *args],
        capture_output=True, text=True, timeout=300, env=env, cwd=REPO,
    )  # fmt: skip


@pytest.mark.slow
def test_render_measure_writes_png_status_and_profile(env, tmp_path: Path) -> None:
    png, prof = tmp_path / "m.png", tmp_path / "m.csv"
    r = gv(env, "render", str(SRTM), "--tool", "measure", "--points", POINTS,
           "--set", "measure.samples=7", CAMERA, "--size", "320x240",
           "--out", str(png), "--tool-csv", str(prof))  # fmt: skip
    assert r.returncode == 0, r.stderr
    dist = Geod(ellps="WGS84").inv(-71.45, 44.23, -71.22, 44.31)[2]
    assert f"measure: {dist / 1000:,.3f} km geodesic" in r.stdout
    assert png.stat().st_size > 0
    with prof.open(newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["distance_m", "lon", "lat", "height_m"] and len(rows) == 8
    table = np.array(rows[1:], np.float64)
    assert abs(table[-1, 0] - dist) < 1e-3
    # The heights are `globeview height`'s orthometric H at the same points (same store).
    pts = [f"{lon!r},{lat!r}" for lon, lat in table[:, 1:3].tolist()]
    h = gv(env, "height", *pts, str(SRTM), "--json")
    assert h.returncode == 0, h.stderr
    want = [row["orthometric_m"] for row in json.loads(h.stdout)]
    np.testing.assert_allclose(table[:, 3], want, atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("points", "words"),
    [
        ("1,2;3,4;5,6", "1 or 2 points"),
        ("-71.45,44.23;-71.22,95", "latitude"),
    ],
)
def test_refused_points_exit_2_and_write_nothing(env, tmp_path: Path, points, words) -> None:
    png, prof = tmp_path / "m.png", tmp_path / "m.csv"
    prof.write_text("the user's profile\n")
    r = gv(env, "render", str(SRTM), "--tool", "measure", "--points", points, CAMERA,
           "--size", "64x48", "--out", str(png), "--tool-csv", str(prof))  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.startswith("globeview: error: ") and words in r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert not png.exists() and prof.read_text() == "the user's profile\n"
