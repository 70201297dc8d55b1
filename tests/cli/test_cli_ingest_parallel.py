"""`globeview ingest --workers N --scheduler tcp://HOST:PORT` (issue #18): the options are
checked before any source is read (one line, exit 2, nothing written)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[2] / "data"
GLOBEVIEW = Path(sys.executable).with_name("globeview")
SMALL_DEM = DATA / "topobathy_vancouver.tif"


def globeview(*args: str, cache: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(cache)}
    env.pop("GLOBEVIEW_DEBUG", None)
    return subprocess.run(
        [str(GLOBEVIEW), *args], capture_output=True, text=True, timeout=timeout, env=env
    )


def one_error_line(res: subprocess.CompletedProcess) -> str:
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("globeview: error: "), lines[0]
    assert "Traceback" not in res.stderr
    return lines[0]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("--workers", "0"), "--workers must be in 1.."),
        (("--workers", "-3"), "--workers must be in 1.."),
        (("--workers", "two"), "--workers must be a whole number"),
        (("--workers", "1.5"), "--workers must be a whole number"),
        (("--workers", "100000000"), "--workers must be in 1.."),
        (("--scheduler", "http://127.0.0.1:8786"), "tcp://HOST:PORT"),
        (("--scheduler", "tcp://127.0.0.1"), "tcp://HOST:PORT"),
        (("--scheduler", "tcp://127.0.0.1:0"), "tcp://HOST:PORT"),
        (("--scheduler", "tcp://127.0.0.1:70000"), "tcp://HOST:PORT"),
        (("--scheduler", "tcp://my host:8786"), "tcp://HOST:PORT"),
        (("--scheduler", ""), "tcp://HOST:PORT"),
        (("--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"), "has its own workers"),
    ],
)
def test_bad_parallel_options_are_one_line_and_write_nothing(
    tmp_path: Path, args: tuple[str, ...], needle: str
) -> None:
    out = tmp_path / "store"
    res = globeview("ingest", str(SMALL_DEM), "--out", str(out), *args, cache=tmp_path / "c")
    assert needle in one_error_line(res)
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("store")]
