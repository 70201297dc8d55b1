"""Every subcommand once through the installed console script as a plain subprocess, the way a
user starts it (interpreter start, entry point, the subcommand's imports and its run), and
``python -m globeview`` once: the other CLI tests fork their commands from `zygote`'s pre-warmed
server or call `globeview.cli.main` in-process, which never take this path."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fault.corpus import ALPS, ALPS_CENTRE, plateau, write_raster

from globeview.cli import SUBCOMMANDS

from .run_cli import GLOBEVIEW, one_error_line

pytestmark = pytest.mark.slow  # a plain interpreter start each (0.5-1 CPU-s)

LON, LAT = ALPS_CENTRE


def _runs(dem: Path, tmp: Path) -> dict[str, tuple[list[str], int]]:
    """Subcommand -> (its arguments, the exit status they must give): each does its work on a
    96 x 64 DEM, or (bench, gui) stops at a check that comes after its module's imports."""
    cameras = f"{LON},{LAT},60000,0,-90;{LON + 0.2},{LAT},60000,0,-90"
    return {
        "info": (["info", str(dem)], 0),
        "ingest": (["ingest", str(dem), "--out", str(tmp / "store"), "--quiet"], 0),
        "render": (["render", str(dem), "-o", str(tmp / "x.png"), "--size", "32x24"], 0),
        "movie": (["movie", "-o", str(tmp / "m.gif"), "--size", "32x24", "--fps", "1",
                   "--", cameras, str(dem)], 0),
        "height": (["height", f"{LON},{LAT}", str(dem)], 0),
        "plugins": (["plugins", "list"], 0),
        "bench": (["bench", "flight", "canyon_run", "--frames", "0"], 2),
        "gui": (["gui", str(dem)], 1),  # no display here: one line, exit 1
    }  # fmt: skip


@pytest.fixture(scope="module")
def dem(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("entry")
    return write_raster(folder / "alps.tif", plateau(64, 96), ALPS, "EPSG:4326", dtype="float32")


def _env(tmp: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    for name in ("QT_QPA_PLATFORM", "GLOBEVIEW_DEBUG", "GV_TEST_ZYGOTE"):
        env.pop(name, None)
    env["GLOBEVIEW_CACHE_DIR"] = str(tmp / "cache")
    env["GLOBEVIEW_CONFIG_DIR"] = str(tmp / "config")
    return env


def test_every_subcommand_has_a_run_here(dem: Path, tmp_path: Path) -> None:
    assert sorted(_runs(dem, tmp_path)) == sorted(SUBCOMMANDS)


@pytest.mark.gl
@pytest.mark.parametrize("command", sorted(SUBCOMMANDS))
def test_the_console_script_runs_it(command: str, dem: Path, tmp_path: Path) -> None:
    args, status = _runs(dem, tmp_path)[command]
    res = subprocess.run(
        [str(GLOBEVIEW), *args],
        capture_output=True,
        text=True,
        env=_env(tmp_path),
        cwd=tmp_path,
        timeout=300,
    )
    if status == 0:
        assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr
    else:
        assert res.returncode == status, res.stderr
        if status == 2:
            one_error_line(res)
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_python_m_globeview_runs_it(dem: Path, tmp_path: Path) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "globeview", "info", "--json", str(dem)],
        capture_output=True,
        text=True,
        env=_env(tmp_path),
        timeout=300,
    )
    assert res.returncode == 0 and res.stderr == "", res.stderr
    assert '"width": 96' in res.stdout
