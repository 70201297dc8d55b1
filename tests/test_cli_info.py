"""`globeview info` end to end, in a subprocess like a user runs it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import rasterio
from affine import Affine

from globeview.terrain.dem import EMBEDDED_DATA_DIR


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "globeview", *args], capture_output=True, text=True, timeout=60
    )


def test_info_etopo20() -> None:
    r = _run("info", str(EMBEDDED_DATA_DIR / "etopo20.tif"))
    assert r.returncode == 0, r.stderr
    assert "EPSG:4326" in r.stdout and "1080 x 540" in r.stdout
    assert "reaches a pole" in r.stdout


def test_info_json_embedded() -> None:
    r = _run("info", "--embedded", "--json")
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)
    assert Path(rows[0]["path"]).name == "etopo20.tif"
    assert len(rows) == 4
    crater = next(x for x in rows if "craterlake" in x["path"])
    assert crater["fill_value"] == -32767


def test_info_embedded_describes_the_embedded_dems() -> None:
    # (The bare `globeview` command opens the window; tests/ui covers it.)
    r = _run("info", "--embedded")
    assert r.returncode == 0, r.stderr
    assert "etopo20.tif" in r.stdout and "N44W072.hgt" in r.stdout


def _assert_one_line_error(r: subprocess.CompletedProcess[str], needle: str) -> None:
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("globeview: error:") and needle in lines[0]
    assert "Traceback" not in r.stderr


def test_cli_missing_file(tmp_path: Path) -> None:
    _assert_one_line_error(_run("info", str(tmp_path / "missing.tif")), "not found")


def test_cli_text_file(tmp_path: Path) -> None:
    p = tmp_path / "x.tif"
    p.write_text("hello")
    _assert_one_line_error(_run("info", str(p)), "cannot read")


def test_cli_no_crs_then_crs_flag(tmp_path: Path) -> None:
    p = tmp_path / "nocrs.tif"
    with rasterio.open(
        p,
        "w",
        driver="GTiff",
        width=5,
        height=5,
        count=1,
        dtype="float32",
        transform=Affine(100, 0, 500_000, 0, -100, 5_000_000),
    ) as ds:
        ds.write(np.ones((1, 5, 5), np.float32))
    _assert_one_line_error(_run("info", str(p)), "--crs")
    r = _run("info", "--crs", "EPSG:32610", str(p))
    assert r.returncode == 0, r.stderr
    assert "EPSG:32610" in r.stdout
