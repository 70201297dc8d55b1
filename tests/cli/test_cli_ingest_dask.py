"""`globeview ingest --workers N --scheduler tcp://HOST:PORT` on the Dask ingest (issue #18):
an unreachable scheduler is one line (exit 2) within a bounded time, and the local scheduler's
stores do not depend on the number of workers (bit for bit)."""

from __future__ import annotations

import inspect
import socket
import time
from pathlib import Path

import pytest

from .run_cli import globeview, one_error_line

DATA = Path(__file__).resolve().parents[2] / "data"

SMALL_DEM = DATA / "topobathy_vancouver.tif"


def closed_port() -> int:
    """A local TCP port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_unreachable_scheduler_is_one_line(tmp_path: Path) -> None:
    from globeview.terrain.ingest.driver import ingest

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


@pytest.mark.slow
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


@pytest.mark.slow
def test_an_incremental_update_says_how_many_chunks_it_rebuilt(tmp_path: Path) -> None:
    import numpy as np
    import rasterio
    from affine import Affine

    def tile(path: Path, west: float, bump: float = 0.0) -> Path:
        n = 2048  # 1/2048 degree pixels: two chunk columns of the finest level per source
        rows = 512  # 45.75..46 N: one chunk row (a quarter of the CPU of a 1-degree-tall tile)
        y, x = np.mgrid[0:rows, 0:n].astype(np.float32) / n
        z = 800.0 + 300.0 * np.sin(6.0 * x + west) * np.cos(5.0 * y)
        z += bump * np.exp(-(((x - 0.8) ** 2 + (y - 0.2) ** 2) / 0.01))
        transform = Affine(1 / n, 0, west, 0, -1 / n, 46.0)
        profile = {"driver": "GTiff", "width": n, "height": rows, "count": 1, "dtype": "float32"}
        with rasterio.open(path, "w", crs="EPSG:4326", transform=transform, **profile) as ds:
            ds.write(z.astype(np.float32), 1)
        return path

    a, b = tile(tmp_path / "a.tif", 10.0), tile(tmp_path / "b.tif", 11.0)
    out = tmp_path / "store"
    args = ("ingest", str(a), str(b), "--out", str(out), "--workers", "2")
    first = globeview(*args, cache=tmp_path / "c")
    assert first.returncode == 0 and "rebuilt" not in first.stdout, first.stdout + first.stderr
    tile(b, 11.0, bump=250.0)  # one source changes
    res = globeview(*args, cache=tmp_path / "c")
    assert res.returncode == 0, res.stderr
    import re

    m = re.search(r"rebuilt (\d+) of (\d+) chunks", res.stdout)
    assert m is not None, res.stdout
    assert 0 < int(m.group(1)) < int(m.group(2))
