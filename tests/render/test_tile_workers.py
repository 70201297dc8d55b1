"""The loader on every core (render/tile_workers.py, issue #27 item 2): tiles built in worker
processes (real ones, forkserver, the embedded terrain opened from its recipe) are the bits of
the same tiles built in this process one at a time; a tile whose build raises fails alone and
the loader goes on; a killed worker is replaced; shutting down while tiles load returns at
once. No GL."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

from globeview.render.tile_build import ReadyTile, TileBuilder
from globeview.render.tile_loader import TileLoader
from globeview.render.tile_workers import (
    ProcessBuilder,
    TerrainRecipe,
    WorkerLost,
    default_loader,
)
from globeview.terrain.quadtree import key_for_lonlat


@pytest.fixture(scope="module")
def stack(globeview_terrain):
    """The embedded terrain: the run's one stack (`globeview_terrain`, tests/conftest.py), not
    one of the module's own (each stack measures its layers' blend masks again: up to ~7 CPU-s)."""
    return globeview_terrain


def _key(level: int, lon: float, lat: float) -> tuple[int, int, int]:
    kx, ky = key_for_lonlat(level, np.array([lon]), np.array([lat]))
    return level, int(np.ravel(kx)[0]), int(np.ravel(ky)[0])


def _keys() -> list[tuple[int, int, int]]:
    """Neighbouring tiles over White Mountains' detail layer and Crater Lake (data-level
    normals below its data), a pole tile and the antimeridian: every path of the build."""
    lv, x, y = _key(11, -71.3, 44.2)
    keys = [(lv, x + i, y + j) for j in range(3) for i in range(4)]
    return [*keys, _key(14, -122.1, 42.94), (3, 0, 0), (2, 15, 3), (5, 0, 20)]


def _same(a: ReadyTile, b: ReadyTile) -> bool:
    return (
        all(
            np.ascontiguousarray(getattr(a, f)).tobytes()
            == np.ascontiguousarray(getattr(b, f)).tobytes()
            for f in ("center", "vertices", "albedo", "normal")
        )
        and a.coast_scale == b.coast_scale
        and (a.blocks is None) == (b.blocks is None)
        and (a.blocks is None or np.array_equal(a.blocks, b.blocks))
    )


def _wait_for(cond, timeout: float = 120.0) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


def test_default_loader_keeps_two_cores_for_the_frames() -> None:
    assert default_loader(1) == ("thread", 1)
    assert default_loader(2) == ("thread", 1)
    assert default_loader(3) == ("process", 1)
    assert default_loader(16) == ("process", 14)


def test_tiles_built_in_processes_equal_serial_builds(stack) -> None:
    keys = _keys()
    serial = TileBuilder(stack)
    alone = {k: serial.ready(np.array([k]))[k] for k in keys}
    procs = ProcessBuilder(TerrainRecipe.of(stack), workers=2)
    try:
        assert procs.start(wait_s=120.0)
        procs.warm(np.array(keys[:4]), facts_only=True)  # (a benchmark's warm-up)
        procs.warm(np.array(keys[-2:]))
        # Two threads hand over batches of 4 at once, as the loader's threads do.
        batches = [keys[i : i + 4] for i in range(0, len(keys), 4)]
        got: dict = {}
        errors: list[BaseException] = []

        def run(part):
            try:
                for b in part:
                    got.update(procs.build_many(np.array(b)))
            except BaseException as exc:  # noqa: BLE001  reported below
                errors.append(exc)

        threads = [threading.Thread(target=run, args=(batches[i::2],)) for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(300.0)
        assert not errors, errors
        assert sorted(got) == sorted(keys)
        for k in keys:
            assert _same(got[k], alone[k]), k
        assert procs.cpu_seconds() > 0.0
        assert procs.describe() == "process x2"
    finally:
        procs.shutdown()


def test_a_tile_that_raises_in_a_worker_fails_alone_and_loading_goes_on(stack) -> None:
    procs = ProcessBuilder(TerrainRecipe.of(stack), workers=1)
    loader = TileLoader(
        procs.build, workers=1, build_many=procs.build_many, batch=8, processes=procs
    )
    try:
        good = _keys()[:6]
        bad = (31, 0, 0)  # past the quadtree's deepest level: the build raises ValueError
        loader.request(np.array([*good[:3], bad, *good[3:]]))
        _wait_for(lambda: loader.ready + len(loader.failed) == 7 and loader.building == 0)
        assert set(loader.failed) == {bad}
        assert isinstance(loader.failed[bad], ValueError)
        # The loader keeps building: the next request's tiles arrive.
        more = _keys()[6:9]
        loader.request(np.array(more))
        _wait_for(lambda: loader.ready == 9)
        built = dict(loader.take_ready(100))
        assert set(built) == set(good) | set(more)
        assert all(isinstance(t, ReadyTile) for t in built.values())
    finally:
        loader.shutdown()


def test_a_killed_worker_is_replaced_and_its_tiles_built_again(stack) -> None:
    procs = ProcessBuilder(TerrainRecipe.of(stack), workers=1)
    loader = TileLoader(
        procs.build, workers=1, build_many=procs.build_many, batch=4, processes=procs
    )
    try:
        first = _keys()[:4]
        loader.request(np.array(first))
        _wait_for(lambda: loader.ready == 4)
        (pid,) = procs.pids()
        os.kill(pid, signal.SIGKILL)
        _wait_for(lambda: not _alive(pid), 30.0)
        later = _keys()[4:8]
        loader.request(np.array(later))
        _wait_for(lambda: loader.ready == 8 and loader.building == 0)
        assert not loader.failed
        assert procs.started == 2 and procs.pids() and pid not in procs.pids()
    finally:
        loader.shutdown()


def _alive(pid: int) -> bool:
    try:
        return os.waitpid(pid, os.WNOHANG) == (0, 0)
    except ChildProcessError:
        return False


def test_shutdown_while_tiles_load_returns_promptly_and_ends_the_workers(stack) -> None:
    procs = ProcessBuilder(TerrainRecipe.of(stack), workers=2)
    loader = TileLoader(
        procs.build, workers=2, build_many=procs.build_many, batch=8, processes=procs
    )
    lv, x, y = _key(12, -71.3, 44.2)
    many = np.array([(lv, x + i, y + j) for j in range(12) for i in range(12)])
    loader.request(many)
    _wait_for(lambda: bool(procs.pids()) and loader.building < len(many))
    pids = procs.pids()
    done = threading.Event()

    def stop():
        loader.shutdown()
        done.set()

    t0 = time.monotonic()
    threading.Thread(target=stop, daemon=True).start()
    assert done.wait(30.0), "shutdown hung"
    assert time.monotonic() - t0 < 30.0
    assert not any(_alive(p) for p in pids)
    assert all(not t.is_alive() for t in loader._threads)
    with pytest.raises(WorkerLost):
        procs.build_many(many[:1])


def test_workers_that_cannot_open_the_terrain_fall_back_to_this_process(
    stack, tmp_path, caplog
) -> None:
    """A recipe whose store the workers cannot open (moved, deleted, unreachable): one
    warning line, then the tiles are built here, the same bits; without a fallback each build
    says why in one line."""
    import dataclasses

    from globeview.render.tile_workers import WorkerStartError

    recipe = TerrainRecipe.of(stack)
    gone = dataclasses.replace(recipe.layers[0], location=str(tmp_path / "no-store"))
    bad = dataclasses.replace(recipe, layers=(gone, *recipe.layers[1:]))
    keys = np.array(_keys()[:3])
    here = TileBuilder(stack)
    procs = ProcessBuilder(bad, workers=1, fallback=here.ready)
    try:
        with caplog.at_level("WARNING", logger="globeview.render"):
            got = procs.build_many(keys)
            again = procs.build_many(keys)
        assert set(got) == set(again) == {tuple(k) for k in keys.tolist()}
        for k, tile in got.items():
            assert _same(tile, here.ready(np.array([k]))[k])
        warnings = [r.getMessage() for r in caplog.records]
        assert len(warnings) == 1 and "no-store" in warnings[0] and "\n" not in warnings[0]
        assert procs.describe() == "process x1 (not started: in-process)"
        assert not procs.pids()
    finally:
        procs.shutdown()
    strict = ProcessBuilder(bad, workers=1)
    try:
        with pytest.raises(WorkerStartError, match=r"could not open the terrain: .*no-store"):
            strict.build_many(keys)
    finally:
        strict.shutdown()


EXIT_SCRIPT = """
import time
import numpy as np
from globeview.render.tile_loader import TileLoader
from globeview.render.tile_workers import ProcessBuilder, TerrainRecipe
from globeview.terrain.embedded import embedded_stores
from globeview.terrain.compose.stack import TerrainStack

stack = TerrainStack.from_stores(embedded_stores())
procs = ProcessBuilder(TerrainRecipe.of(stack), workers=2)
loader = TileLoader(procs.build, 2, build_many=procs.build_many, batch=8, processes=procs)
keys = np.array([(12, 1230 + i, 700 + j) for j in range(16) for i in range(16)])
loader.request(keys)
while loader.ready < 24:
    time.sleep(0.005)
loader.shutdown()
print("shut down with", loader.building, "tiles left", flush=True)
"""


def test_a_process_that_shut_its_loader_down_mid_load_exits(tmp_path) -> None:
    """The whole process ends after a shutdown in the middle of loading: no thread of the
    worker pool is left waiting (the interpreter's exit waits for them)."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-c", EXIT_SCRIPT], capture_output=True, text=True, timeout=240
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "shut down with" in done.stdout


def _psm() -> set[str]:
    """Shared-memory segments on this machine (Python's are named psm_*)."""
    return {n for n in os.listdir("/dev/shm") if n.startswith("psm_")}


def test_tiles_come_back_through_shared_memory_and_free_their_slots(stack) -> None:
    """Issue #27: a worker writes its batch into the window's slab; the tiles view their
    slots (the serial builds' bits), a slot is free again once its tile is released (as an
    upload does) or dropped, and with too few slots free a batch travels pickled."""
    import gc

    keys = _keys()[:8]
    serial = TileBuilder(stack)
    procs = ProcessBuilder(TerrainRecipe.of(stack), workers=1, slab_tiles=12)
    try:
        got = procs.build_many(np.array(keys))
        slab = procs.slab
        assert slab is not None and slab.spec.name.lstrip("/") in _psm()
        assert procs.tiles_shared == 8 and slab.free_count == 4
        for k in keys:
            assert _same(got[k], serial.ready(np.array([k]))[k]), k
            assert got[k].vertices.base is not None  # a view of the slab, not a copy
            assert got[k].blocks is not None  # the block stats travel beside the slot
        for k in keys[:3]:
            got[k].release()
            got[k].release()  # idempotent
        assert slab.free_count == 7
        more = procs.build_many(np.array(keys[:8]))  # 8 > 7 free: pickled
        assert procs.tiles_pickled == 8 and slab.free_count == 7
        assert all(t.release is None for t in more.values())
        twice = procs.build_many(np.array([keys[0], keys[0], keys[1]]))  # a key given twice
        assert list(twice) == [keys[0], keys[1]] and slab.free_count == 5
        assert _same(twice[keys[1]], serial.ready(np.array([keys[1]]))[keys[1]])
        del twice
        del got
        gc.collect()
        assert slab.free_count == 12  # dropped tiles free their slots
    finally:
        procs.shutdown()
    assert procs.slab is None and slab.closed
    assert slab.spec.name.lstrip("/") not in _psm()


def test_a_worker_killed_mid_batch_leaks_no_shared_memory(stack) -> None:
    """SIGKILL to a worker while it builds a batch into the slab: the call fails with
    WorkerLost, the batch's slots are free again once the pool's processes are gone, the next
    build (a fresh worker) writes into the same slab the serial builds' bits, a loader over
    it goes on building, and after shutdown no shared memory is left in /dev/shm."""
    before = _psm()
    lv, x, y = _key(12, -71.3, 44.2)
    big = np.array([(lv, x + i, y + j) for j in range(16) for i in range(16)])  # ~0.3 s CPU
    procs = ProcessBuilder(TerrainRecipe.of(stack), workers=1, slab_tiles=300)
    errors: list[BaseException] = []
    try:
        assert procs.start(wait_s=120.0)
        procs.warm(big[:8])
        slab = procs.slab
        assert slab is not None
        (pid,) = procs.pids()
        from globeview.render.tile_workers import _proc_cpu_s

        cpu0 = _proc_cpu_s(pid) or 0.0

        def build() -> None:
            try:
                procs.build_many(big)
            except BaseException as exc:  # noqa: BLE001  checked below
                errors.append(exc)

        t = threading.Thread(target=build)
        t.start()
        # Mid-batch: the worker has spent CPU on this batch and its slots are taken.
        _wait_for(lambda: (_proc_cpu_s(pid) or 0.0) > cpu0 + 0.05, 60.0)
        assert slab.free_count == 300 - len(big)
        os.kill(pid, signal.SIGKILL)
        t.join(60.0)
        assert not t.is_alive()
        assert len(errors) == 1 and isinstance(errors[0], WorkerLost), errors
        assert slab.free_count == 300 and slab.lost == 0
        keys = _keys()[:4]
        got = procs.build_many(np.array(keys))
        assert procs.slab is slab and pid not in procs.pids()
        serial = TileBuilder(stack)
        for k in keys:
            assert _same(got[k], serial.ready(np.array([k]))[k]), k
        loader = TileLoader(procs.build, 1, build_many=procs.build_many, batch=4, processes=procs)
        loader.request(np.array(_keys()[4:12]))
        _wait_for(lambda: loader.ready == 8 and loader.building == 0)
        for _, tile in loader.take_ready(100):
            assert tile.release is not None
            tile.release()  # as the upload does
        del got
        assert slab.free_count == 300
        loader.shutdown()
    finally:
        procs.shutdown()
    assert procs.slab is None
    _wait_for(lambda: not (_psm() - before), 10.0)
