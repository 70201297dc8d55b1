"""`globeview ingest` through its CLI module: exit codes, messages, no-op re-run."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest
from inprocess_cli import run_globeview

from globeview.cli import ingest as cli_ingest
from globeview.errors import GlobeviewError

DATA = Path(__file__).resolve().parents[1] / "data"


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    cli_ingest.add_arguments(p)
    return p.parse_args(list(argv))


def test_ingest_then_up_to_date(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = str(DATA / "topobathy_vancouver.tif")
    out = str(tmp_path / "store")
    assert cli_ingest.run(_args(src, "--out", out, "--quiet")) == 0
    assert (tmp_path / "store" / "manifest.json").exists()
    capsys.readouterr()
    assert cli_ingest.run(_args(src, "--out", out, "--quiet")) == 0
    assert "store is up to date" in capsys.readouterr().out


@pytest.mark.slow
def test_bad_input_is_one_line_nonzero(tmp_path: Path) -> None:
    bad = tmp_path / "fake.tif"
    bad.write_text("not a raster")
    with pytest.raises(GlobeviewError):
        cli_ingest.run(_args(str(bad), "--out", str(tmp_path / "s"), "--quiet"))
    # Through the real entry point (a child process): exit code and a single stderr line.
    code = (
        "import sys, argparse\n"
        "from globeview.cli import ingest as m\n"
        "from globeview.errors import GlobeviewError\n"
        "p = argparse.ArgumentParser(); m.add_arguments(p)\n"
        "try:\n    sys.exit(m.run(p.parse_args(sys.argv[1:])))\n"
        "except GlobeviewError as e:\n"
        "    print('globeview: error:', e, file=sys.stderr)\n"
        "    sys.exit(2)\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code, str(bad), "--out", str(tmp_path / "s")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0
    assert len(r.stderr.strip().splitlines()) == 1 and "error" in r.stderr
    assert not (tmp_path / "s").exists()


def _cli(*argv: str) -> subprocess.CompletedProcess:
    """``globeview ingest ARGV`` run in this process (`inprocess_cli`: its output and exit
    status as the child process above would give them)."""
    return run_globeview(["ingest", *argv], env={"GLOBEVIEW_DEBUG": None})


@pytest.mark.slow
def test_directory_and_missing_source_wording(tmp_path: Path) -> None:
    # A folder is a folder of DEM tiles (issue #18); one with none in it is one line.
    out = tmp_path / "s"
    r = _cli(str(tmp_path), "--out", str(out))
    assert r.returncode == 2
    assert len(r.stderr.splitlines()) == 1
    assert r.stderr.startswith(f"globeview: error: {tmp_path} is a folder with no DEM files")
    r = _cli(str(tmp_path / "nope.tif"), "--out", str(out))
    assert r.returncode == 2
    assert r.stderr.splitlines() == [
        f"globeview: error: DEM file not found: {tmp_path / 'nope.tif'}"
    ]
    assert not out.exists()


@pytest.mark.slow
def test_out_that_is_a_file_or_a_link(tmp_path: Path) -> None:
    src = str(DATA / "topobathy_vancouver.tif")
    f = tmp_path / "report.pdf"
    f.write_text("mine")
    r = _cli(src, "--out", str(f))
    assert r.returncode == 2 and "not a directory" in r.stderr and len(r.stderr.splitlines()) == 1
    assert f.read_text() == "mine"
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    r = _cli(src, "--out", str(tmp_path / "link"))
    assert r.returncode == 2 and "symbolic link" in r.stderr
    assert list((tmp_path / "real").iterdir()) == []


@pytest.mark.slow
def test_not_a_tty_means_no_progress_lines(tmp_path: Path) -> None:
    r = _cli(str(DATA / "topobathy_vancouver.tif"), "--out", str(tmp_path / "s"))
    assert r.returncode == 0 and r.stderr == ""
    assert r.stdout.count("\n") == 1 and "levels 0.." in r.stdout


@pytest.mark.slow
def test_odd_sources_and_out_parents_are_one_line(tmp_path: Path) -> None:
    src = str(DATA / "topobathy_vancouver.tif")
    r = _cli("/dev/zero", "--out", str(tmp_path / "s"))
    assert r.stderr.splitlines() == [
        "globeview: error: /dev/zero is not a regular file, not a DEM file"
    ]
    f = tmp_path / "notes.txt"
    f.write_text("mine")
    r = _cli(src, "--out", str(f / "s"))
    assert r.returncode == 2
    assert r.stderr.splitlines() == [f"globeview: error: {f} is not a folder; choose another --out"]


@pytest.mark.slow
def test_max_level_past_the_natural_level(tmp_path: Path) -> None:
    # Was an internal error (argmax of an empty sequence): the levels between had no extent.
    from globeview.terrain.store.tile_store import TileStore

    out = tmp_path / "s"
    r = _cli(str(DATA / "topobathy_vancouver.tif"), "--out", str(out), "--max-level", "9")
    assert r.returncode == 0, r.stderr
    with TileStore.open(out) as st:
        assert st.max_level == 9
        st.verify()
    r = _cli(str(DATA / "topobathy_vancouver.tif"), "--out", str(out), "--max-level", "22")
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1
    # No tile count caps a store (format 7): the planned chunk files need more than this disk
    # holds, refused up front (nothing written), naming the level that fits.
    assert "--max-level 22 would have" in r.stderr and "the limit is" in r.stderr
    assert not out.with_name(".s.building").exists()


@pytest.mark.slow
def test_ingest_says_how_many_samples_were_read_as_nodata(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue #13: +-inf and impossible heights, and undeclared fills, are nodata, and ingest
    says how many (the store holds less than the source)."""
    import numpy as np
    import rasterio
    from affine import Affine

    z = 500.0 + 50.0 * np.sin(np.arange(64 * 64, dtype=np.float64).reshape(64, 64) / 40.0)
    z[0, :5] = np.inf  # 5 non-finite
    z[10, 10:13] = 1e30  # 3 impossible
    z[40:50, 40:50] = -9999.0  # 100 undeclared fill
    src = tmp_path / "hostile.tif"
    with rasterio.open(
        src, "w", driver="GTiff", width=64, height=64, count=1, dtype="float32",
        crs="EPSG:4326", transform=Affine(1 / 64, 0, 10.0, 0, -1 / 64, 46.0),
    ) as ds:  # fmt: skip
        ds.write(z.astype(np.float32), 1)
    assert cli_ingest.run(_args(str(src), "--out", str(tmp_path / "s"), "--quiet")) == 0
    out = capsys.readouterr().out
    assert "read as nodata: 8 samples non-finite or outside -12000..9000 m" in out, out
    assert "100 undeclared fill samples" in out, out
    # A clean source says nothing of the kind.
    clean = str(DATA / "topobathy_vancouver.tif")
    assert cli_ingest.run(_args(clean, "--out", str(tmp_path / "c"), "--quiet")) == 0
    assert "read as nodata" not in capsys.readouterr().out
