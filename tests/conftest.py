"""Suite-wide guard: where the project's test command runs (./test sets
GLOBEVIEW_REQUIRE_GL=1), a missing headless OpenGL must fail the run, not quietly skip every
rendering test. Run plain `pytest` on a machine without EGL and those tests skip instead."""

from __future__ import annotations

import fcntl
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import cpu_durations
import pytest
import zygote  # first: its fork server's environment is the session's, taken now

PROBE = "from globeview.render.offscreen import create_headless_context as c; c().release()"


def pytest_addoption(parser: pytest.Parser) -> None:
    cpu_durations.addoption(parser)


def pytest_configure(config: pytest.Config) -> None:
    cpu_durations.configure(config)
    # A suite started as a shell's background job (`./test &`) inherits SIGINT ignored, and so
    # would every child it starts: the Ctrl-C tests would then test the shell, not globeview.
    # Python's own handler is what a terminal's pytest has; children get the default on exec.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_unconfigure(config: pytest.Config) -> None:
    zygote.close()  # the CLI tests' fork server, where one was started


def pytest_sessionstart(session: pytest.Session) -> None:
    if os.environ.get("GLOBEVIEW_REQUIRE_GL") != "1":
        return
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return  # the controlling process probed once for all its workers
    # Probe in a child process: once a thread of this process has had an EGL context current,
    # libglvnd will not make Qt's GLX context current here (the window tests need that).
    probe = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True)
    if probe.returncode != 0:
        reason = (probe.stderr.strip().splitlines() or ["unknown error"])[-1]
        pytest.exit(f"headless OpenGL is required by ./test: {reason}", returncode=1)


# Marks by folder: every test under tests/ui needs a real window, every test under tests/bench
# runs a benchmark (./test --fast leaves both out).
_FOLDER_MARKS = {"ui": "gui", "bench": "bench"}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    tests_dir = Path(__file__).resolve().parent
    for item in items:
        try:
            folder = item.path.resolve().relative_to(tests_dir).parts[0]
        except ValueError:
            continue
        mark = _FOLDER_MARKS.get(folder)
        if mark is not None:
            item.add_marker(mark)


@pytest.fixture(autouse=True)
def _environment_restored() -> Iterator[None]:
    """Each test leaves `os.environ` as it found it: an import can change it for the whole
    process (importing `distributed` sets MALLOC_TRIM_THRESHOLD_, OMP_NUM_THREADS, ... and
    __DASK_PARENT_PID), and a later test in the same worker that checks what a child process
    inherits (tests/test_zygote.py) then failed depending on the order of the tests."""
    saved = dict(os.environ)
    yield
    if os.environ != saved:
        os.environ.clear()
        os.environ.update(saved)


@pytest.fixture(scope="session")
def embedded_cache() -> Path:
    """A cache folder (for ``GLOBEVIEW_CACHE_DIR``) holding the embedded DEMs' stores, kept in
    the system's temporary folder between runs and named by a digest of globeview's terrain
    code (`band_tables.code_digest`: any change to ingest or composition makes a new one).
    Each session re-ingests into it, which is a no-op for a current store and rebuilds a stale
    one; pytest-xdist workers and concurrent runs take turns under a lock, so the stores are
    built once (~8 CPU-s), not once a worker or a run. Never the user's cache. A child
    `globeview render` of the embedded terrain pointed at it reads these stores; children may
    add what a cache holds besides stores (band tables, written atomically). A test about the
    cache itself uses `seed_cache` on a folder of its own."""
    import tempfile

    from globeview.terrain.compose.band_tables import code_digest
    from globeview.terrain.embedded import embedded_stores

    root = Path(tempfile.gettempdir()) / f"globeview-test-cache-{os.getuid()}"
    root.mkdir(mode=0o700, exist_ok=True)
    cache = root / f"embedded-{code_digest()[:16]}"
    with open(root / f"{cache.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        cache.mkdir(exist_ok=True)
        with pytest.MonkeyPatch.context() as mp:  # session scope: no `monkeypatch` fixture
            mp.setenv("GLOBEVIEW_CACHE_DIR", str(cache))
            for store in embedded_stores():
                store.close()
    return cache


@pytest.fixture(scope="session")
def globeview_terrain(embedded_cache: Path):
    """`globeview.app.testing`'s fixture (the embedded terrain as a `TerrainStack`, ingested
    into a temporary cache), on the shared `embedded_cache` instead of a cache ingested again
    by each worker."""
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GLOBEVIEW_CACHE_DIR", str(embedded_cache))
        stores = embedded_stores()
    return TerrainStack.from_stores(stores)


@pytest.fixture(scope="session")
def seed_cache(embedded_cache: Path) -> Callable[[Path], Path]:
    """``seed_cache(folder) -> folder``: copies the embedded DEMs' stores of `embedded_cache`
    into the cache folder ``folder`` (a file copy, ~13 MB, instead of an ~8 CPU-s ingest), so
    a child process given ``GLOBEVIEW_CACHE_DIR=folder`` finds them current."""

    def seed(folder: Path) -> Path:
        shutil.copytree(embedded_cache / "stores", folder / "stores", dirs_exist_ok=True)
        return folder

    return seed


@pytest.fixture(scope="session")
def seed_dem_store() -> Callable[[Path, Path], Path]:
    """``seed_dem_store(folder, dem) -> folder``: copies the store that a command given the
    DEM file ``dem`` (no --crs, no --vdatum) ingests into its cache (`store_path_for`) into
    the cache folder ``folder``, so a child given ``GLOBEVIEW_CACHE_DIR=folder`` finds it
    current instead of ingesting it again (~4.3 CPU-s for data/N44W072.hgt). The store is
    built once per DEM and version of globeview's terrain code (`band_tables.code_digest`)
    in the system's temporary folder, beside `embedded_cache`'s folders; pytest-xdist workers
    and concurrent runs take turns under a lock. For tests that draw or query a DEM, not for
    tests about its ingest into the cache."""
    import hashlib
    import tempfile

    from globeview.terrain.compose.band_tables import code_digest
    from globeview.terrain.sources import open_source, store_path_for

    root = Path(tempfile.gettempdir()) / f"globeview-test-cache-{os.getuid()}"
    root.mkdir(mode=0o700, exist_ok=True)

    def seed(folder: Path, dem: Path) -> Path:
        key = f"{Path(dem).resolve()}|{code_digest()}".encode()
        built = root / f"dem-{hashlib.sha256(key).hexdigest()[:16]}"
        with open(root / f"{built.name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            with pytest.MonkeyPatch.context() as mp:
                mp.setenv("GLOBEVIEW_CACHE_DIR", str(built))
                open_source(dem).close()  # an ingest where the store is missing or stale
                name = store_path_for(Path(dem)).name
            shutil.copytree(built / "stores" / name, folder / "stores" / name, dirs_exist_ok=True)
        return folder

    return seed
