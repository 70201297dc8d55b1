"""`globeview ingest --scheduler tcp://...` on a real dask.distributed cluster started from the
command line (issue #25's proof): a ``dask scheduler`` and two ``dask worker`` processes of
the venv's `dask` CLI on 127.0.0.1, not a LocalCluster.

- One worker is killed with SIGKILL mid-build (once the scheduler holds some results and the
  worker is running a task): the build still finishes on the other, and its store is byte for
  byte (every file's sha256) the store of a local 1-worker build.
- A worker dying every time on one chunk: the workers start with the ingest's own test hook
  ``GLOBEVIEW_INGEST_FAULT=KILL@2`` (`tasks.fault_point`: the process that writes window 2 of
  the build sends itself SIGKILL, as `kill -9` would; windows are numbered in the serial
  build's order whatever runs them), so whichever worker takes that chunk dies, and so does
  the one it is retried on; the scheduler (``allowed-failures`` 1) gives up with KilledWorker
  and the ingest says so in one line (exit 2), leaving nothing in the output's folder.

The workers run without a nanny (the process started is the worker: what is killed stays
dead), one thread and 1 GiB each. Every process is started in its own session and its group
is killed by the fixture's finalizer, whatever the test did. Cost (CPU s, user + sys, the
processes started included; 2026-11-29, load 16): 6.7 and 4.3 (three interpreters with dask
a cluster, the ingest's, the Vancouver DEM built twice or once), hence `slow`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from .run_cli import GLOBEVIEW, globeview, globeview_here, one_error_line

DATA = Path(__file__).resolve().parents[2] / "data"
#: The smallest real DEM of data/ (20 tasks: 8 chunks, their errors, shards, the pole).
SOURCE = DATA / "topobathy_vancouver.tif"
DASK = Path(sys.executable).with_name("dask")
START_TIMEOUT_S = 120.0

pytestmark = pytest.mark.slow


@dataclass
class Cluster:
    """A scheduler's address and the worker processes by name."""

    address: str
    workers: dict[str, subprocess.Popen] = field(default_factory=dict)


def _start(cmd: list[str], env: Mapping[str, str], log: Path) -> subprocess.Popen:
    """A process in its own session (its group is what the finalizer kills), output to
    ``log``."""
    with log.open("wb") as f:
        return subprocess.Popen(
            cmd, env=dict(env), stdout=f, stderr=subprocess.STDOUT, start_new_session=True
        )


def _stop(proc: subprocess.Popen) -> None:
    """SIGTERM to the process's group, SIGKILL after 10 s; reaped."""
    for sig, wait in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 10.0)):
        if proc.poll() is not None:
            break
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        try:
            proc.wait(wait)
        except subprocess.TimeoutExpired:
            continue
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)  # whatever the process left in its group


def _address(scheduler_file: Path, proc: subprocess.Popen, log: Path) -> str:
    """The scheduler's address, once it has written its scheduler file."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"dask scheduler exited {proc.returncode}: {log.read_text()[-800:]}")
        try:
            return str(json.loads(scheduler_file.read_text())["address"])
        except (OSError, ValueError, KeyError):
            time.sleep(0.1)
    pytest.fail("dask scheduler did not write its scheduler file in time")


@pytest.fixture
def dask_cluster(tmp_path: Path) -> Iterator[Callable[..., Cluster]]:
    """``start(worker_env={}, scheduler_env={})``: a dask scheduler and two workers (w1, w2)
    on 127.0.0.1, ready; every process started is killed (its group) at teardown."""
    procs: list[subprocess.Popen] = []
    base = {k: v for k, v in os.environ.items() if not k.startswith(("DASK_", "GLOBEVIEW_"))}

    def start(
        worker_env: Mapping[str, str] | None = None,
        scheduler_env: Mapping[str, str] | None = None,
    ) -> Cluster:
        folder = tmp_path / "dask"
        folder.mkdir()
        sfile = folder / "scheduler.json"
        cmd = [str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0"]
        cmd += ["--no-dashboard", "--scheduler-file", str(sfile)]
        log = folder / "scheduler.log"
        procs.append(_start(cmd, {**base, **(scheduler_env or {})}, log))
        cluster = Cluster(_address(sfile, procs[-1], log))
        for name in ("w1", "w2"):
            cmd = [str(DASK), "worker", cluster.address, "--name", name, "--nthreads", "1"]
            cmd += ["--no-nanny", "--memory-limit", "1GiB", "--death-timeout", "60"]
            cmd += ["--local-directory", str(folder / name)]
            env = {**base, **(worker_env or {})}
            procs.append(_start(cmd, env, folder / f"{name}.log"))
            cluster.workers[name] = procs[-1]
        _wait_for_workers(cluster, folder)
        return cluster

    try:
        yield start
    finally:
        for proc in reversed(procs):
            _stop(proc)


def _client(address: str):  # -> distributed.Client (imported here: ~1 s, only these tests)
    from distributed import Client

    return Client(address, timeout=30, set_as_default=False)


def _wait_for_workers(cluster: Cluster, folder: Path) -> None:
    with _client(cluster.address) as client:
        try:
            client.wait_for_workers(len(cluster.workers), timeout=START_TIMEOUT_S)
        except TimeoutError:
            logs = "".join(p.read_text()[-400:] for p in folder.glob("w*.log"))
            pytest.fail(f"the dask workers did not join in time: {logs}")


def _digest(store: Path) -> dict[str, str]:
    """Every file of a store by its path in it: sha256."""
    return {
        p.relative_to(store).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(store.rglob("*"))
        if p.is_file()
    }


def _kill_a_busy_worker(cluster: Cluster, ingest: subprocess.Popen) -> tuple[str, int, int]:
    """SIGKILL the first worker seen running a task of the ingest once the scheduler holds
    some of its results: (the worker's name, results held, tasks running at that moment)."""
    with _client(cluster.address) as client:
        deadline = time.monotonic() + 300.0
        while time.monotonic() < deadline and ingest.poll() is None:
            held = sum(len(keys) for keys in client.has_what().values())
            running = client.processing()
            names = {a: w["name"] for a, w in client.scheduler_info()["workers"].items()}
            busy = [names[a] for a, keys in running.items() if keys and a in names]
            if held >= 1 and busy:
                cluster.workers[busy[0]].send_signal(signal.SIGKILL)
                return busy[0], held, sum(len(k) for k in running.values())
            time.sleep(0.02)
    pytest.fail(f"the ingest ended (exit {ingest.poll()}) before a worker could be killed")


def test_a_worker_killed_mid_build_changes_nothing_in_the_store(
    tmp_path: Path, dask_cluster: Callable[..., Cluster]
) -> None:
    reference = tmp_path / "local" / "store"
    reference.parent.mkdir()
    res = globeview_here(
        "ingest", str(SOURCE), "--out", str(reference), "--workers", "1", "--quiet",
        cache=tmp_path / "c",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    cluster = dask_cluster()
    out = tmp_path / "cluster" / "store"
    out.parent.mkdir()
    cmd = [str(GLOBEVIEW), "ingest", str(SOURCE), "--out", str(out), "--quiet"]
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(tmp_path / "c")}
    ingest = subprocess.Popen(
        [*cmd, "--scheduler", cluster.address], env=env, start_new_session=True,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        name, held, running = _kill_a_busy_worker(cluster, ingest)
        _, stderr = ingest.communicate(timeout=600)
    finally:
        _stop(ingest)
    assert cluster.workers[name].wait(10) == -signal.SIGKILL  # it was killed, not finished
    assert held >= 1 and running >= 1  # mid-build: results held, tasks still running
    assert ingest.returncode == 0, stderr
    assert "Traceback" not in stderr
    assert (out / "manifest.json").is_file()
    ours, theirs = _digest(out), _digest(reference)
    assert len(ours) > 10  # chunk files, shards, VRTs, sources, manifest
    assert ours == theirs  # byte for byte, every file


def test_a_worker_dying_every_time_on_one_chunk_is_one_line(
    tmp_path: Path, dask_cluster: Callable[..., Cluster]
) -> None:
    from globeview.terrain.ingest.tasks import FAULT_ENV

    cluster = dask_cluster(
        worker_env={FAULT_ENV: "KILL@2"},
        scheduler_env={"DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "1"},
    )
    parent = tmp_path / "out"
    parent.mkdir()
    out = parent / "store"
    res = globeview(
        "ingest", str(SOURCE), "--out", str(out), "--scheduler", cluster.address,
        cache=tmp_path / "c", timeout=600,
    )  # fmt: skip
    line = one_error_line(res)
    assert "a dask worker died running chunk-" in line, line
    assert list(parent.iterdir()) == []  # no store, no building folder, no lock
    for proc in cluster.workers.values():  # both took the chunk, both died of it
        assert proc.wait(30) == -signal.SIGKILL
