"""`globeview info` end to end: once in a process of its own (forked by `zygote`;
tests/cli/test_entry_points.py starts the console script), the rest in this process
(`inprocess_cli`: the same output, exit status and stderr, without a new interpreter's start-up
for each call)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
import zygote
from affine import Affine
from inprocess_cli import run_globeview

from globeview.terrain.dem.data import EMBEDDED_DATA_DIR


def _subprocess(*args: str) -> subprocess.CompletedProcess[str]:
    return zygote.run(
        [sys.executable, "-m", "globeview", *args], capture_output=True, text=True, timeout=60
    )


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return run_globeview(list(args), env={"GLOBEVIEW_DEBUG": None})


@pytest.mark.slow
def test_info_etopo20() -> None:
    r = _subprocess("info", str(EMBEDDED_DATA_DIR / "etopo20.tif"))
    assert r.returncode == 0, r.stderr
    assert "EPSG:4326" in r.stdout and "1080 x 540" in r.stdout
    assert "reaches a pole" in r.stdout


@pytest.mark.slow
def test_info_json_embedded() -> None:
    r = _run("info", "--embedded", "--json")
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)
    assert Path(rows[0]["path"]).name == "etopo20.tif"
    assert len(rows) == 4
    crater = next(x for x in rows if "craterlake" in x["path"])
    assert crater["fill_value"] == -32767


@pytest.mark.slow
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


@pytest.mark.slow
def test_cli_missing_file(tmp_path: Path) -> None:
    _assert_one_line_error(_run("info", str(tmp_path / "missing.tif")), "not found")


@pytest.mark.slow
def test_cli_text_file(tmp_path: Path) -> None:
    p = tmp_path / "x.tif"
    p.write_text("hello")
    _assert_one_line_error(_run("info", str(p)), "cannot read")


@pytest.mark.slow
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


# ---- hostile input (issue #13): one line on stderr, exit 2; or a truthful summary --------------


def _geo_tif(path: Path, arr: np.ndarray, **profile: object) -> Path:
    prof: dict[str, object] = {
        "driver": "GTiff",
        "width": arr.shape[-1],
        "height": arr.shape[-2],
        "count": 1,
        "dtype": arr.dtype.name,
        "crs": "EPSG:4326",
        "transform": Affine(0.01, 0, 5.0, 0, -0.01, 45.0),
    }
    prof.update(profile)
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(arr[None])
    return path


@pytest.mark.slow
def test_cli_reports_masked_samples(tmp_path: Path) -> None:
    a = np.linspace(100, 2000, 400, dtype=np.float32).reshape(20, 20)
    a[5:10, 5:10] = np.inf
    a[0, 0] = 1e30
    p = _geo_tif(tmp_path / "garbage.tif", a)
    r = _run("info", str(p))
    assert r.returncode == 0 and r.stderr == "", r.stderr  # no RuntimeWarning chatter
    assert "masked      26 samples (non-finite or outside -12000..9000 m)" in r.stdout
    assert "heights     104.762 .. 2000" in r.stdout  # a[0, 0] (100) was the 1e30
    rows = json.loads(_run("info", "--json", str(p)).stdout)
    assert rows[0]["masked_samples"] == 26


@pytest.mark.slow
def test_cli_unknown_crs_is_one_line(tmp_path: Path) -> None:
    p = _geo_tif(tmp_path / "a.tif", np.ones((5, 5), np.float32))
    r = _run("info", "--crs", "EPSG:999999", str(p))
    _assert_one_line_error(r, "unknown CRS 'EPSG:999999'")
    assert "ERROR 1" not in r.stderr  # PROJ's own chatter stays out


@pytest.mark.slow
def test_cli_directory_and_complex(tmp_path: Path) -> None:
    _assert_one_line_error(_run("info", str(tmp_path)), "is a directory, not a DEM file")
    c = _geo_tif(tmp_path / "c.tif", np.ones((5, 5), np.complex64))
    r = _run("info", str(c))
    _assert_one_line_error(r, "has complex samples; a DEM needs real heights")
    assert "ComplexWarning" not in r.stderr


@pytest.mark.slow
def test_cli_polar_stereographic_resolution_in_km(tmp_path: Path) -> None:
    # 1 km cells around the south pole: degrees of longitude per cell are meaningless there
    p = _geo_tif(
        tmp_path / "antarctica.tif",
        np.full((100, 100), 2500, np.float32),
        crs="EPSG:3031",
        transform=Affine(1000, 0, -50_000, 0, -1000, 50_000),
    )
    r = _run("info", str(p))
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if x.strip().startswith("resolution"))
    assert line.split()[1:5] == ["1", "km", "x", "1"] and "deg" not in line and "e+" not in line


@pytest.mark.slow
@pytest.mark.parametrize("crs", ["EPSG:3413", "EPSG:3031"])
def test_cli_polar_stereographic_json_resolution_in_degrees(tmp_path: Path, crs: str) -> None:
    # 300 x 300 cells of 1 km centred on the pole: res_deg said ~1e9 (a degree of longitude
    # there is ~1e-6 m). A cell's ground size in degrees of arc (~111 km each) is what a
    # geographic grid of that detail has: ~0.009 deg.
    p = _geo_tif(
        tmp_path / "polar.tif",
        np.full((300, 300), 100, np.float32),
        crs=crs,
        transform=Affine(1000, 0, -150_000, 0, -1000, 150_000),
    )
    r = _run("info", "--json", str(p))
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)[0]
    assert d["res_crs_m"] == [1000.0, 1000.0]
    # The grid's true-scale latitude is 70 degrees: at the pole a 1 km cell is ~1.03 km.
    assert all(1000.0 < m < 1040.0 for m in d["res_m"]), d["res_m"]
    from pyproj import Geod

    pole = 90.0 if crs == "EPSG:3413" else -90.0
    _, _, m_per_deg = Geod(ellps="WGS84").inv(0.0, pole, 0.0, pole - np.sign(pole))
    for deg, m in zip(d["res_deg"], d["res_m"], strict=True):
        assert deg == pytest.approx(m / m_per_deg, rel=2e-3), d["res_deg"]


@pytest.mark.slow
def test_cli_cf_netcdf_assumed_wgs84(tmp_path: Path) -> None:
    import rasterio.shutil
    from rasterio.io import MemoryFile

    a = np.arange(36 * 18, dtype=np.float32).reshape(18, 36)
    p = tmp_path / "etopo_like.nc"
    with MemoryFile() as mf:
        with mf.open(
            driver="GTiff",
            width=36,
            height=18,
            count=1,
            dtype="float32",
            transform=Affine(10, 0, -180, 0, -10, 90),
        ) as ds:
            ds.write(a[None])
        with mf.open() as src:
            rasterio.shutil.copy(src, p, driver="netCDF")
    r = _run("info", str(p))
    assert r.returncode == 0, r.stderr
    assert "CRS         EPSG:4326 (assumed from CF lat/lon axes)" in r.stdout


@pytest.mark.slow
def test_cli_paths_that_are_not_dems_are_one_line_each(tmp_path: Path) -> None:
    import os

    empty = tmp_path / "empty.tif"
    empty.write_bytes(b"")
    loop = tmp_path / "loop.tif"
    os.symlink(tmp_path / "loop2.tif", loop)
    os.symlink(loop, tmp_path / "loop2.tif")
    fifo = tmp_path / "pipe.tif"
    os.mkfifo(fifo)  # GDAL would wait on it forever
    vrt = tmp_path / "mosaic.vrt"
    vrt.write_text(
        '<VRTDataset rasterXSize="10" rasterYSize="10"><SRS>EPSG:4326</SRS>'
        "<GeoTransform>5.0, 0.01, 0, 45.0, 0, -0.01</GeoTransform>"
        '<VRTRasterBand dataType="Float32" band="1"><SimpleSource>'
        '<SourceFilename relativeToVRT="1">tile_gone.tif</SourceFilename>'
        "<SourceBand>1</SourceBand></SimpleSource></VRTRasterBand></VRTDataset>"
    )
    lat95 = _geo_tif(
        tmp_path / "lat95.tif", np.ones((10, 10), np.float32), transform=Affine(1, 0, 0, 0, -1, 95)
    )
    cases = [
        (empty, "is empty (0 bytes)"),
        (loop, "symbolic link loop"),
        (fifo, "not a regular file"),
        (vrt, "tile_gone.tif, which does not exist"),
        (lat95, "beyond +-90 degrees"),
    ]
    for path, needle in cases:
        _assert_one_line_error(_run("info", str(path)), needle)
