"""The ingest as a Dask graph: the same store bit for bit on every scheduler (threads with 1
and 2 workers, processes, a dask.distributed LocalCluster of 2 worker processes), progress
through Dask's callbacks, sources that pickle without their value scan, and bad scheduler
settings, an unreachable scheduler and a failing cluster task as one line with nothing left
behind."""

from __future__ import annotations

import json
import os
import pickle
import socket
import time
from pathlib import Path

import numpy as np
import pytest

from globeview.errors import StoreError
from globeview.terrain.dem import reader as dem_mod
from globeview.terrain.dem.reader import open_dem
from globeview.terrain.ingest.driver import FAULT_ENV, ingest
from globeview.terrain.ingest.schedule import parse_scheduler
from globeview.terrain.store.identify import MANIFEST_NAME
from globeview.terrain.store.tile_store import TileStore

DATA = Path(__file__).resolve().parents[2] / "data"
# Global (the east edge of a level's last chunk is its first chunk's west edge: lon 180 is
# -180), with poles; level 4 has two chunks a row. ~2 s.
ETOPO = DATA / "etopo20.tif"
ETOPO_KW = {"max_level": 4}


def _files(store: Path) -> dict[str, bytes]:
    """Every file of a store (chunks, shards and facts in their folders) with its bytes."""
    return {
        p.relative_to(store).as_posix(): p.read_bytes()
        for p in sorted(store.rglob("*"))
        if p.is_file()
    }


def _write(out: Path, files: dict[str, bytes]) -> Path:
    """The store ``files`` (`_files`) written to ``out`` (the reference's bytes instead of
    an ingest of the same source again)."""
    for name, data in files.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(data)
    return out


def _leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """The store built by one thread (the serial order)."""
    out = tmp_path_factory.mktemp("ref") / "s"
    ingest([ETOPO], out, workers=1, **ETOPO_KW)
    return _files(out)


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    saved = dict(os.environ)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as c:
        # Its nannies set OMP_NUM_THREADS, MALLOC_TRIM_THRESHOLD_, ... in this process's
        # environment to spawn their workers (and set them again for a restart); other
        # modules' tests run on this pytest worker while the cluster lives (xdist), and a
        # child they start must inherit the session's environment (tests/test_zygote.py).
        os.environ.clear()
        os.environ.update(saved)
        yield c


@pytest.mark.slow
def test_the_reference_store_has_several_chunks_a_row(reference: dict[str, bytes]) -> None:
    man = json.loads(reference[MANIFEST_NAME])
    fine = man["levels"][-1]
    lv = fine["level"]
    cols = sorted(
        int(n.split("/")[3].split("-")[0]) for n in reference if n.startswith(f"chunks/{lv:02d}/")
    )
    assert cols == [0, 1]  # the east-edge copy crosses chunks
    assert fine["chunks"] == 2 and man["pole_heights"]["south"] is not None


@pytest.mark.slow
@pytest.mark.parametrize(("workers", "scheduler"), [(2, None), (2, "processes")])
def test_local_schedulers_give_the_same_store_bit_for_bit(
    reference: dict[str, bytes], tmp_path: Path, workers: int, scheduler: str | None
) -> None:
    """2 threads (the default; "threads" is the same run, `parse_scheduler` makes it the
    same choice) and a pool of 2 processes."""
    assert parse_scheduler(2, "threads") == parse_scheduler(2, None)
    out = tmp_path / "s"
    ingest([ETOPO], out, workers=workers, scheduler=scheduler, **ETOPO_KW)
    assert _files(out) == reference  # every chunk file, VRT and the manifest, byte for byte


@pytest.mark.slow
def test_progress_counts_every_chunk_and_error_task(tmp_path: Path) -> None:
    calls: list[tuple[int, int]] = []
    ingest([ETOPO], tmp_path / "s", workers=2, on_progress=lambda d, t: calls.append((d, t)))
    man = json.loads((tmp_path / "s" / MANIFEST_NAME).read_text())
    # One task per planned chunk of every level (global: all of them), one error task per
    # chunk of levels 1..L.
    windows = [
        -(-lv["bbox"]["ny"] * 64 // 1024) * -(-lv["bbox"]["nx"] * 64 // 1024)
        for lv in man["levels"]
    ]
    total = sum(windows) + sum(windows[1:])
    assert [d for d, _ in calls] == list(range(1, total + 1))
    assert {t for _, t in calls} == {total}


@pytest.mark.slow
def test_a_cancel_from_progress_stops_the_graph_and_leaves_nothing(tmp_path: Path) -> None:
    class Cancel(Exception):
        pass

    def cancel(done: int, total: int) -> None:
        if done == 2:
            raise Cancel

    with pytest.raises(Cancel):
        ingest([ETOPO], tmp_path / "s", workers=2, on_progress=cancel, **ETOPO_KW)
    assert not (tmp_path / "s").exists() and _leftovers(tmp_path) == []


def test_a_dem_pickles_without_its_value_scan(monkeypatch: pytest.MonkeyPatch) -> None:
    with open_dem(ETOPO) as dem:
        blob = pickle.dumps(dem)
        want = dem.read_grid(-30.0, 60.0, 0.25, 0.25, 40, 30)

        def no_scan(self: object) -> None:
            raise AssertionError("the value scan ran again")

        monkeypatch.setattr(dem_mod.Dem, "_scan_values", no_scan)
        assert len(blob) < 16_000  # metadata, not data
        copy = pickle.loads(blob)
        try:
            assert copy.info == dem.info and copy.fill_values == dem.fill_values
            np.testing.assert_array_equal(copy.read_grid(-30.0, 60.0, 0.25, 0.25, 40, 30), want)
        finally:
            copy.close()


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"workers": 0}, "--workers must be >= 1"),
        ({"workers": -1}, "--workers must be >= 1"),
        ({"workers": "x"}, "--workers must be a whole number"),
        ({"workers": 1.5}, "--workers must be a whole number"),
        ({"workers": True}, "--workers must be a whole number"),
        ({"workers": 10**9}, "--workers must be in 1..4096"),
        ({"scheduler": "x"}, "--scheduler must be tcp://HOST:PORT"),
        ({"scheduler": "http://127.0.0.1:8786"}, "--scheduler must be tcp://HOST:PORT"),
        ({"scheduler": "tcp://"}, "--scheduler must be tcp://HOST:PORT"),
        ({"scheduler": "tcp://127.0.0.1:99999"}, "port 99999 is out of range"),
        ({"scheduler": 8786}, "--scheduler must be tcp://HOST:PORT"),
    ],
)
def test_bad_workers_or_scheduler_is_one_line(tmp_path: Path, kw: dict, needle: str) -> None:
    with pytest.raises(StoreError) as exc:
        ingest([ETOPO], tmp_path / "s", **kw)
    assert needle in str(exc.value) and "\n" not in str(exc.value)
    assert list(tmp_path.iterdir()) == []


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_a_scheduler_that_does_not_answer_is_one_line_within_seconds(
    tmp_path: Path, reference: dict[str, bytes]
) -> None:
    out = _write(tmp_path / "s", reference)
    before = _files(out)
    t0 = time.monotonic()
    with pytest.raises(StoreError) as exc:
        ingest([ETOPO], out, force=True, scheduler=f"tcp://127.0.0.1:{_free_port()}")
    assert time.monotonic() - t0 < 30
    msg = str(exc.value)
    assert "cannot reach the dask scheduler at tcp://127.0.0.1:" in msg and "\n" not in msg
    assert _files(out) == before and _leftovers(tmp_path) == []


@pytest.mark.slow
def test_a_port_that_accepts_but_never_answers_is_one_line_within_seconds(
    tmp_path: Path,
) -> None:
    """distributed.Client alone would wait forever here (the kernel accepts the connection
    into the listen backlog; nobody ever speaks)."""
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(8)
        port = srv.getsockname()[1]
        t0 = time.monotonic()
        with pytest.raises(StoreError) as exc:
            ingest([ETOPO], tmp_path / "s", scheduler=f"tcp://127.0.0.1:{port}")
        assert time.monotonic() - t0 < 30
    assert "cannot reach the dask scheduler" in str(exc.value) and "\n" not in str(exc.value)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_a_worker_that_dies_is_one_line_and_leaves_nothing(tmp_path: Path) -> None:
    """kill -9 of the worker running a chunk (every time it is retried): one StoreError line,
    no store, no building folder (the tasks still running elsewhere finish first)."""
    import dask
    from distributed import LocalCluster

    with (
        dask.config.set({"distributed.scheduler.allowed-failures": 1}),
        LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",
            env={FAULT_ENV: "KILL@3"},  # every worker, restarted ones too
        ) as c,
        pytest.raises(StoreError) as exc,
    ):
        ingest([ETOPO], tmp_path / "s", scheduler=c.scheduler_address, **ETOPO_KW)
    msg = str(exc.value)
    assert msg.startswith("a dask worker died running chunk-") and "\n" not in msg
    assert list(tmp_path.iterdir()) == []


# The tests on the module's `cluster` last and together: its two idle worker processes
# spend CPU for as long as it lives (until the module's last test), ~4 CPU-s when it lived
# through the waits of the tests above.


@pytest.mark.slow
def test_a_distributed_cluster_gives_the_same_store_bit_for_bit(
    reference: dict[str, bytes], tmp_path: Path, cluster
) -> None:
    out = tmp_path / "s"
    ingest([ETOPO], out, scheduler=cluster.scheduler_address, **ETOPO_KW)
    assert _files(out) == reference
    with TileStore.open(out) as st:
        st.verify()


@pytest.mark.slow
def test_a_worker_address_is_not_a_scheduler(tmp_path: Path, cluster) -> None:
    worker = next(iter(cluster.workers.values())).worker_address
    with pytest.raises(StoreError, match="is not a dask scheduler"):
        ingest([ETOPO], tmp_path / "s", scheduler=worker)


@pytest.mark.slow
def test_a_failing_task_on_the_cluster_is_one_line_and_leaves_the_old_store(
    tmp_path: Path, cluster, reference: dict[str, bytes]
) -> None:
    from distributed import Client

    out = _write(tmp_path / "s", reference)
    before = _files(out)
    with Client(cluster.scheduler_address) as client:
        # A full disk at the 3rd chunk write, on whichever worker runs it.
        client.run(lambda: os.environ.__setitem__(FAULT_ENV, "ENOSPC@3"))
        try:
            with pytest.raises(StoreError) as exc:
                ingest([ETOPO], out, force=True, scheduler=cluster.scheduler_address, **ETOPO_KW)
        finally:
            client.run(lambda: os.environ.pop(FAULT_ENV, None))
    assert str(exc.value).startswith(f"disk full writing {out}") and "\n" not in str(exc.value)
    assert _files(out) == before and _leftovers(tmp_path) == []
