"""The background tile queue (render/tile_loader.py): nearest tiles first, a frame's request
replaces the previous one (tiles a moving camera left behind are never built), a prefetch
(a flight's destination) goes before every frame's request, failed tiles are counted and not
retried until `retry_failed_s` has passed, and a cancel discards builds under way. No GL:
the builds here are plain callables (the renderer's real `build_mesh` runs in
test_render_async_loading.py)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from globeview.geodesy import lonlat_to_ecef
from globeview.render.tile_loader import TileLoader, tile_priority


class Recorder:
    """A build that records the keys in the order it was called; the first call waits for
    ``gate`` so the test can fill the queue while the (single) worker is busy."""

    def __init__(self, fail: set | None = None) -> None:
        self.gate = threading.Event()
        self.started = threading.Event()
        self.order: list[tuple[int, int, int]] = []
        self.fail = fail or set()

    def __call__(self, key):
        self.order.append(key)
        if len(self.order) == 1:
            self.started.set()
            assert self.gate.wait(10.0)
        if key in self.fail:
            raise OSError(f"unreadable tile {key}")
        return ("mesh", key)


def wait_for(cond, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.005)


@pytest.fixture
def busy_loader():
    """A one-worker loader whose worker is blocked in its first build (key (0, 0, 0))."""
    rec = Recorder(fail={(5, 1, 1)})
    ready_calls = []
    loader = TileLoader(rec, workers=1, on_ready=lambda: ready_calls.append(1))
    loader.request(np.array([[0, 0, 0]]))
    assert rec.started.wait(10.0)
    yield loader, rec, ready_calls
    rec.gate.set()
    loader.shutdown()


def test_priority_is_zero_under_the_eye_and_grows_with_distance() -> None:
    eye = lonlat_to_ecef(-71.3, 44.15, 9000.0)
    # Level 10 tiles: the one under the eye, one ~2 tiles east, one on the other side of Earth.
    size = 180.0 / 2**10
    x0, y0 = int((-71.3 + 180) / size), int((90 - 44.15) / size)
    keys = np.array([[10, x0 + 2, y0], [10, x0, y0], [10, x0 + 1024, y0], [3, 4, 2]])
    p = tile_priority(keys, eye)
    assert p[1] == 0.0  # the eye is over this tile (its nearest point is under the eye)
    assert 0.0 < p[0] < p[2]
    assert p[3] == 0.0  # the coarse tile (22.5 deg) holding the point under the eye


def test_frame_requests_load_nearest_first_and_replace_the_previous_one(busy_loader) -> None:
    loader, rec, _ = busy_loader
    far, mid, near = (5, 9, 9), (5, 3, 3), (5, 2, 2)
    stale = (5, 20, 20)
    loader.request(np.array([stale]))  # an earlier frame's tile, no longer wanted below
    loader.request(np.array([far, near, mid]), priority=np.array([30.0, 1.0, 2.0]))
    assert loader.pending == 4  # three queued + the one being built
    rec.gate.set()
    wait_for(lambda: loader.building == 0)
    assert rec.order == [(0, 0, 0), near, mid, far]  # the stale tile was never built
    got = loader.take_ready(2)
    assert [k for k, _ in got] == [(0, 0, 0), near]  # in the order they finished, up to 2
    assert loader.ready == 2 and loader.pending == 2


def test_a_prefetch_goes_before_frame_requests_and_survives_them(busy_loader) -> None:
    loader, rec, _ = busy_loader
    dest = [(7, 1, 1), (7, 2, 1)]
    loader.prefetch(np.array(dest), priority=np.array([1.0, 0.0]))
    loader.request(np.array([(4, 0, 0)]))
    loader.request(np.array([(4, 1, 0)]))  # a later frame: the prefetch stays queued
    rec.gate.set()
    wait_for(lambda: loader.building == 0)
    assert rec.order == [(0, 0, 0), (7, 2, 1), (7, 1, 1), (4, 1, 0)]


def test_a_failed_tile_is_counted_told_and_not_retried(busy_loader) -> None:
    loader, rec, ready_calls = busy_loader
    bad = (5, 1, 1)
    loader.request(np.array([bad, (5, 1, 2)]))
    rec.gate.set()
    wait_for(lambda: len(ready_calls) == 3)  # each finished tile, the failed one too
    assert isinstance(loader.failed[bad], OSError)
    loader.request(np.array([bad]))  # asked again: not rebuilt
    time.sleep(0.05)
    assert rec.order.count(bad) == 1 and loader.building == 0
    assert {k for k, _ in loader.take_ready(10)} == {(0, 0, 0), (5, 1, 2)}


def test_a_failed_tile_is_tried_again_once_its_retry_delay_has_passed() -> None:
    """A store over HTTP fails while its server is down: after ``retry_failed_s`` the next
    request builds the tile again, and a success then replaces the failure."""
    down = threading.Event()
    down.set()
    calls: list[tuple[int, int, int]] = []

    def build(key):
        calls.append(key)
        if down.is_set():
            raise OSError("HTTP 503 for a chunk")
        return ("mesh", key)

    loader = TileLoader(build, workers=1, retry_failed_s=0.3)
    try:
        key = (6, 3, 3)
        loader.request(np.array([key]))
        wait_for(lambda: key in loader.failed)
        loader.request(np.array([key]))  # at once: still failed, not rebuilt
        time.sleep(0.05)
        assert calls == [key] and key in loader.failed
        down.clear()  # the server is back
        time.sleep(0.35)
        loader.request(np.array([key]))
        wait_for(lambda: loader.ready == 1)
        assert calls == [key, key] and key not in loader.failed
        assert [k for k, _ in loader.take_ready(5)] == [key]
    finally:
        loader.shutdown()


@pytest.mark.parametrize("bad", [-1.0, float("nan")])
def test_a_negative_or_nan_retry_delay_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match="retry_failed_s"):
        TileLoader(lambda key: ("mesh", key), retry_failed_s=bad)


def test_cancel_discards_the_build_under_way_and_the_queue(busy_loader) -> None:
    loader, rec, ready_calls = busy_loader
    loader.request(np.array([(6, 0, 0)]))
    loader.cancel_all()  # new layers: what was being built is stale
    assert loader.pending == 0
    # A tile asked for after the cancel: the single worker builds it only once it has dealt
    # with the stale build, so its arrival (the first `on_ready`: a discarded build calls
    # none) is the moment to look, whatever the machine's load.
    loader.request(np.array([(7, 0, 0)]))
    rec.gate.set()
    wait_for(lambda: len(ready_calls) >= 1)
    assert [k for k, _ in loader.take_ready(10)] == [(7, 0, 0)]
    assert rec.order == [(0, 0, 0), (7, 0, 0)]


def test_a_broken_listener_does_not_stop_loading() -> None:
    def boom() -> None:
        raise RuntimeError("listener gone")

    loader = TileLoader(lambda key: ("mesh", key), workers=2, on_ready=boom)
    try:
        loader.request(np.array([(3, 0, 0), (3, 1, 0), (3, 2, 0)]))
        wait_for(lambda: loader.ready == 3)
    finally:
        loader.shutdown()


def test_workers_must_be_at_least_one() -> None:
    with pytest.raises(ValueError, match="at least 1"):
        TileLoader(lambda key: None, workers=0)


def test_batches_go_through_build_many_in_load_order_and_a_bad_tile_fails_alone() -> None:
    batches: list[list[tuple[int, int, int]]] = []
    bad = (6, 3, 0)

    def build_many(keys):
        ks = [tuple(map(int, k)) for k in keys]
        batches.append(ks)
        if bad in ks:
            raise OSError("one unreadable tile in the batch")
        return {k: ("mesh", k) for k in ks}

    def build(key):
        if key == bad:
            raise OSError("unreadable")
        return ("one", key)

    keys = np.array([(6, i, 0) for i in range(7)])
    loader = TileLoader(build, workers=1, build_many=build_many, batch=3)
    try:
        loader.request(keys, priority=np.arange(7.0))
        wait_for(lambda: loader.building == 0 and loader.ready == 6)
    finally:
        loader.shutdown()
    assert batches[0] == [(6, 0, 0), (6, 1, 0), (6, 2, 0)]
    assert all(len(b) <= 3 for b in batches)
    assert set(loader.failed) == {bad}
    got = dict(loader.take_ready(10))
    assert got[(6, 0, 0)] == ("mesh", (6, 0, 0))
    assert got[(6, 4, 0)] == ("one", (6, 4, 0))  # its batch was rebuilt tile by tile


@pytest.mark.slow
def test_shutdown_waits_for_the_build_under_way_and_frees_the_build() -> None:
    """A closed window's renderer must be garbage at once: after shutdown no worker is
    alive (a worker's frame holds the loader and so the build callables)."""
    import gc
    import weakref

    rec = Recorder()
    loader = TileLoader(rec, workers=2)
    loader.request(np.array([[0, 0, 0]]))
    assert rec.started.wait(10.0)
    threading.Timer(0.2, rec.gate.set).start()  # the build under way ends after shutdown began
    loader.shutdown()
    assert not any(t.is_alive() for t in loader._threads)
    ref = weakref.ref(rec)
    del rec, loader
    gc.collect()
    assert ref() is None


def test_a_failure_is_remembered_without_its_traceback(busy_loader) -> None:
    """The traceback's frames would keep the batch's other meshes alive as long as the
    failure is remembered."""
    loader, rec, _ = busy_loader
    loader.request(np.array([[5, 1, 1]]))
    rec.gate.set()
    wait_for(lambda: (5, 1, 1) in loader.failed)
    exc = loader.failed[(5, 1, 1)]
    assert isinstance(exc, OSError) and "unreadable tile" in str(exc)
    assert exc.__traceback__ is None
