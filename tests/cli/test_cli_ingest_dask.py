"""`globeview ingest --workers N --scheduler tcp://HOST:PORT` on the Dask ingest (issue #18):
an unreachable scheduler is one line (exit 2) within a bounded time, and the local scheduler's
stores do not depend on the number of workers (bit for bit)."""

from __future__ import annotations

import inspect
import os
import socket
import subprocess
import sys
import time
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
    return lines[0]


def closed_port() -> int:
    """A local TCP port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_is_one_line(tmp_path: Path) -> None:
    from globeview.terrain.ingest import ingest

    if "scheduler" not in inspect.signature(ingest).parameters:
        pytest.fail("ingest() has no scheduler keyword (issue #18's Dask ingest)")
    out = tmp_path / "store"
    t0 = time.monotonic()
    res = globeview(
        "ingest",
        str(SMALL_DEM),
        "--out",
        str(out),
        "--scheduler",
        f"tcp://127.0.0.1:{closed_port()}",
        cache=tmp_path / "c",
        timeout=180,
    )
    line = one_error_line(res)
    assert "scheduler" in line.lower(), line
    assert time.monotonic() - t0 < 120  # a bounded connect timeout, not a hang
    assert not (out / "manifest.json").exists()


def _levels(store: Path) -> dict[str, bytes]:
    """The store's level files (chunks and VRTs) by name, and its manifest's levels."""
    return {p.name: p.read_bytes() for p in sorted(store.iterdir()) if p.name.startswith("level_")}


def test_workers_1_and_2_write_the_same_store(tmp_path: Path) -> None:
    stores = []
    for n, extra in (("1", ()), ("2", ()), ("2p", ("--scheduler", "processes"))):
        out = tmp_path / f"store{n}"
        res = globeview(
            "ingest", str(SMALL_DEM), "--out", str(out), "--workers", n[0], *extra,
            cache=tmp_path / "c",
        )  # fmt: skip
        assert res.returncode == 0, res.stderr
        assert "written" in res.stdout
        stores.append(out)
    a, b, c = (_levels(s) for s in stores)
    assert a.keys() == b.keys() and len(a) > 1
    assert a == b == c  # bit for bit: the graph's result does not depend on the scheduling
    # A re-run with another worker count is still a no-op (the store is up to date).
    res = globeview(
        "ingest", str(SMALL_DEM), "--out", str(stores[0]), "--workers", "2", cache=tmp_path / "c"
    )
    assert res.returncode == 0 and "up to date" in res.stdout, res.stdout + res.stderr
