"""`globeview ingest --workers N --scheduler tcp://HOST:PORT` (issue #18): the options are
checked before any source is read (one line, exit 2, nothing written)."""

from __future__ import annotations

from pathlib import Path

import pytest

from .run_cli import globeview, one_error_line

DATA = Path(__file__).resolve().parents[2] / "data"

SMALL_DEM = DATA / "topobathy_vancouver.tif"


@pytest.mark.slow
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
