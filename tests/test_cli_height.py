"""`globeview height` end to end (issue #16): the first check in a process of its own (forked
by `zygote`; tests/cli/test_entry_points.py starts the console script), the rest in this
process (`inprocess_cli`: the same output and exit status without a new interpreter's start-up
each call).

The done-when check of the issue: at a White Mountains point the ellipsoidal height of the
SRTM tile differs from the SRTM sample (orthometric, EGM96) by the geoid undulation there."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
import zygote
from inprocess_cli import run_globeview

from globeview.terrain.dem.vdatum import find_geoid_grid

REPO = Path(__file__).resolve().parents[1]
SRTM = REPO / "data" / "N44W072.hgt"


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory, seed_dem_store) -> dict[str, str]:
    """The environment with the module's cache folder, holding SRTM's store (copied, not
    ingested again)."""
    cache = seed_dem_store(tmp_path_factory.mktemp("cache"), SRTM)
    return {**os.environ, "GLOBEVIEW_CACHE_DIR": str(cache)}


def _run(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    cache = {"GLOBEVIEW_CACHE_DIR": env["GLOBEVIEW_CACHE_DIR"], "GLOBEVIEW_DEBUG": None}
    return run_globeview(list(args), env=cache, cwd=REPO)


def _subprocess(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return zygote.run(
        [sys.executable, "-m", "globeview", *args],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=REPO,
    )


def _srtm_bilinear(lon: float, lat: float) -> float:
    """The SRTM samples (orthometric metres) around a point, bilinear, read with rasterio
    (.hgt samples sit at pixel centres of its transform)."""
    with rasterio.open(SRTM) as ds:
        col, row = ~ds.transform @ (lon, lat)
        r, c = row - 0.5, col - 0.5
        r0, c0 = int(np.floor(r)), int(np.floor(c))
        a = ds.read(1, window=((r0, r0 + 2), (c0, c0 + 2))).astype(np.float64)
    fr, fc = r - r0, c - c0
    top = a[0, 0] * (1 - fc) + a[0, 1] * fc
    bot = a[1, 0] * (1 - fc) + a[1, 1] * fc
    return float(top * (1 - fr) + bot * fr)


@pytest.mark.slow
def test_done_when_ellipsoidal_is_srtm_plus_undulation(env: dict[str, str]) -> None:
    from globeview.terrain.dem.vdatum import egm96

    # The command as written (a negative longitude, no `--`). Only there: at an SRTM
    # sample that is a local peak (row 875, column 836) the store's nodes, resampled onto the
    # quadtree grid (2.5" apart, the samples 3"), stand 1.5 m lower than the sample itself --
    # resampling, not the datum.
    r = _subprocess(env, "height", "-71.3033,44.2705", "data/N44W072.hgt", "--json")
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)
    assert len(rows) == 1
    geoid = egm96()
    for row, (lon, lat) in zip(rows, [(-71.3033, 44.2705)], strict=True):
        n = float(np.asarray(geoid.undulation(np.array([lon]), np.array([lat]))).reshape(-1)[0])
        assert -40.0 < n < -15.0  # EGM96 in New Hampshire: about -27.5 m
        srtm = _srtm_bilinear(lon, lat)
        assert abs((row["ellipsoidal_m"] - srtm) - n) <= 0.1, (row, srtm, n)
        assert row["geoid_undulation_m"] == pytest.approx(n, abs=1e-3)
        assert row["orthometric_m"] == pytest.approx(row["ellipsoidal_m"] - n, abs=1e-6)
        assert row["layer"] == "N44W072.hgt"


def _undulation(lon: float, lat: float) -> float:
    from globeview.terrain.dem.vdatum import egm96

    return float(np.asarray(egm96().undulation(np.array([lon]), np.array([lat]))).reshape(-1)[0])


@pytest.mark.slow
def test_off_every_layer_there_is_no_elevation(env: dict[str, str]) -> None:
    r = _run(env, "height", "-71.3033,44.2705", "10,0", "data/N44W072.hgt")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    assert "m a.s.l." in lines[0] and "m ell." in lines[0]
    assert lines[1].endswith("N44W072.hgt")
    # Off every layer there is no terrain: the row says so, and shows no height (it showed
    # H = -N, 17.16 "m a.s.l." here, as if the ellipsoid were ground), only the geoid's N.
    cells = lines[2].split()
    assert "no terrain" in lines[2]
    assert cells[2] == cells[4] == "-", lines[2]
    assert float(cells[3]) == pytest.approx(_undulation(10.0, 0.0), abs=0.006)
    r = _run(env, "height", "-71.3033,44.2705", "10,0", "data/N44W072.hgt", "--json")
    on, off = json.loads(r.stdout)
    assert isinstance(on["ellipsoidal_m"], float) and isinstance(on["orthometric_m"], float)
    assert off["ellipsoidal_m"] is None and off["orthometric_m"] is None
    assert off["geoid_undulation_m"] == pytest.approx(_undulation(10.0, 0.0), abs=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["nan,44", "data/N44W072.hgt"], "finite"),
        (["-nan,44", "data/N44W072.hgt"], "finite"),
        (["-71.3,91", "data/N44W072.hgt"], "latitude"),
        # Not "latitude 90 is outside -90..90": the value as given, every digit.
        (["0,90.0000001", "data/N44W072.hgt"], "latitude 90.0000001 is outside"),
        (["0,-90.00000000001", "data/N44W072.hgt"], "latitude -90.00000000001 is outside"),
        # Python's float() reads "1_0" as 10; a coordinate is not Python.
        (["1_0,2", "data/N44W072.hgt"], "LON,LAT"),
        (["-71.3,4_4", "data/N44W072.hgt"], "LON,LAT"),
        (["-71.3,abc", "data/N44W072.hgt"], "LON,LAT"),
        (["1,2,3", "data/N44W072.hgt"], "LON,LAT"),
        (["data/N44W072.hgt"], "no point"),
        (["-71.3,44.2", "no_such_dem.tif"], "no_such_dem.tif"),
    ],
)
def test_bad_input_is_one_line(env: dict[str, str], args: list[str], words: str) -> None:
    r = _run(env, "height", *args)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("globeview: error:"), r.stderr
    assert words in lines[0]
    assert r.stdout == ""


@pytest.mark.slow
def test_json_flag_may_stand_between_points_and_sources(env: dict[str, str]) -> None:
    # argparse alone refused this: "unrecognized arguments: data/N44W072.hgt"
    r = _run(env, "height", "-71.3033,44.2705", "--json", "10,0", "data/N44W072.hgt")
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)
    assert [row["layer"] for row in rows] == ["N44W072.hgt", "none (ellipsoid)"]


def _no_crs_tif(path: Path, height_m: float) -> Path:
    """A 20 x 20 float32 GeoTIFF of one height, 0.01 degree pixels from (5, 45) down-right,
    with no CRS: only a --crs places it."""
    from affine import Affine

    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=20,
        height=20,
        count=1,
        dtype="float32",
        transform=Affine(0.01, 0, 5.0, 0, -0.01, 45.0),
    ) as ds:
        ds.write(np.full((1, 20, 20), height_m, np.float32))
    return path


@pytest.mark.slow
def test_crs_and_vdatum_as_render_has_them(env: dict[str, str], tmp_path: Path) -> None:
    dem = str(_no_crs_tif(tmp_path / "nocrs.tif", 500.0))
    r = _run(env, "height", "5.1,44.9", dem)
    assert r.returncode == 2 and "--crs" in r.stderr, r.stderr
    n = _undulation(5.1, 44.9)
    # The option may stand between the points and the sources, as --json may.
    r = _run(env, "height", "5.1,44.9", "--crs", "EPSG:4326", dem, "--json")
    assert r.returncode == 0, r.stderr
    row = json.loads(r.stdout)[0]
    # The default datum of a plain GeoTIFF is EGM96: 500 m above the geoid.
    assert row["ellipsoidal_m"] == pytest.approx(500.0 + n, abs=0.01)
    assert row["orthometric_m"] == pytest.approx(500.0, abs=0.01)
    r = _run(env, "height", "--vdatum", "ellipsoid", "5.1,44.9", dem, "--crs=EPSG:4326", "--json")
    assert r.returncode == 0, r.stderr
    row = json.loads(r.stdout)[0]
    assert row["ellipsoidal_m"] == pytest.approx(500.0, abs=0.01)
    assert row["orthometric_m"] == pytest.approx(500.0 - n, abs=0.01)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--vdatum", "egm2008"], "heights are on EGM2008 (--vdatum) and no EGM2008 grid"),
        (["--vdatum", "navd88x"], "unknown vertical datum"),
        (["--crs", "EPSG:999999"], "unknown CRS 'EPSG:999999'"),
    ],
)
def test_bad_crs_or_vdatum_is_one_line(
    env: dict[str, str], tmp_path: Path, args: list[str], words: str
) -> None:
    if "egm2008" in args and find_geoid_grid("egm2008") is not None:
        pytest.skip("this machine has an EGM2008 grid (in PROJ's folders or the environment)")
    dem = str(_no_crs_tif(tmp_path / "nocrs.tif", 500.0))
    r = _run(env, "height", "5.1,44.9", dem, *args)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("globeview: error:"), r.stderr
    assert words in lines[0] and "ERROR 1" not in r.stderr
    assert r.stdout == ""


def test_crs_and_vdatum_read_the_same_in_every_command() -> None:
    # One meaning, one help text, in every command that reads DEM files.
    from globeview.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    helps: dict[str, set[str | None]] = {"--crs": set(), "--vdatum": set()}
    for name in ("info", "ingest", "render", "height"):
        opts = {o: a for a in sub.choices[name]._actions for o in a.option_strings}
        for option, seen in helps.items():
            assert option in opts, (name, option)
            seen.add(opts[option].help)
    assert len(helps["--crs"]) == 1 and len(helps["--vdatum"]) == 1, helps
