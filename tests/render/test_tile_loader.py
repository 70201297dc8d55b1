"""The background tile queue (render/tile_loader.py): nearest tiles first, a frame's request
replaces the previous one (tiles a moving camera left behind are never built), a prefetch
(a flight's destination) goes before every frame's request, failed tiles are counted and not
retried until `retry_failed_s` has passed, and a cancel discards builds under way; a view
with nothing resident near it gets a few coarse stand-ins first, and after a layer change
the old (retired) tiles stand in where nothing new is resident. No GL:
the builds here are plain callables (the renderer's real `build_mesh` runs in
test_render_async_loading.py)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from globeview.geodesy import lonlat_to_ecef
from globeview.lod.render_set import RenderSet
from globeview.lod.tile_indices import IndexVariant
from globeview.render.tile_loader import (
    STANDIN_TILES,
    BytesWarmer,
    TileLoader,
    coarse_standins,
    covered_by,
    substitute_missing,
    tile_priority,
)


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


def test_tiles_asked_ahead_go_first_in_their_order(busy_loader) -> None:
    """A frame's ``ahead`` tiles (coarse stand-ins) are built before its own, nearest
    first or not, and a tile in both lists is built once."""
    loader, rec, _ = busy_loader
    near, far = (9, 10, 10), (9, 30, 30)
    ahead = np.array([(4, 0, 0), (6, 3, 3), near])
    loader.request(np.array([far, near]), priority=np.array([5.0, 0.0]), ahead=ahead)
    rec.gate.set()
    wait_for(lambda: loader.building == 0)
    assert rec.order == [(0, 0, 0), (4, 0, 0), (6, 3, 3), near, far]


def _view_keys(level: int, x0: int, y0: int, n: int) -> np.ndarray:
    """An n x n block of tiles of ``level`` from (x0, y0): a close view's tiles."""
    xs, ys = np.meshgrid(np.arange(x0, x0 + n), np.arange(y0, y0 + n))
    return np.stack([np.full(n * n, level), xs.ravel(), ys.ravel()], axis=1)


def _is_in(tiles: set):
    return lambda k: np.array([tuple(map(int, r)) in tiles for r in k], dtype=bool)


def test_a_view_with_nothing_resident_gets_a_few_coarse_standins_coarse_tier_first() -> None:
    """A 24 x 24 view of level 12 tiles (576, as a layer just added): the first tier is
    the deepest level with at most 8 ancestors of them, the second at most 32; both
    before the view's own tiles, none of them resident."""
    keys = _view_keys(12, 1200, 1000, 24)
    out = coarse_standins(keys, lambda k: np.zeros(len(k), dtype=bool))
    tiers = [out[out[:, 0] == lv] for lv in np.unique(out[:, 0])]
    assert [len(t) for t in tiers] and len(tiers) == 2
    assert 1 <= len(tiers[0]) <= STANDIN_TILES[0] and len(tiers[1]) <= STANDIN_TILES[1]
    assert tiers[0][0, 0] < tiers[1][0, 0] < 12
    assert list(out[:, 0]) == sorted(out[:, 0])  # the coarse tier first
    # Each stand-in is an ancestor of some view tile, and together they cover the view.
    for tier in tiers:
        assert covered_by(keys, tier).all()


def test_no_standins_where_near_ancestors_are_resident() -> None:
    """The edge a moving camera uncovers (its tiles' parents resident), and a small view:
    nothing is asked ahead; a view whose resident ancestors are coarser than a tier gets
    that tier."""
    keys = _view_keys(12, 1200, 1000, 24)
    parents = {(11, x >> 1, y >> 1) for _, x, y in keys.tolist()}
    assert len(coarse_standins(keys, _is_in(parents))) == 0
    assert len(coarse_standins(keys[:4], _is_in(set()))) == 0

    # Resident ancestors 7 levels up (level 5): both tiers (levels 8 and 9) are asked for;
    # the first tier resident: the second; both: none.
    def below(tiles: set) -> np.ndarray:
        return coarse_standins(keys, _is_in(tiles))

    got = below({(5, x >> 7, y >> 7) for _, x, y in keys.tolist()})
    assert sorted(set(got[:, 0].tolist())) == [8, 9]
    tier1 = {tuple(r) for r in got.tolist() if r[0] == 8}
    tier2 = {tuple(r) for r in got.tolist() if r[0] == 9}
    assert {tuple(r) for r in below(tier1).tolist()} == tier2
    assert len(below(tier1 | tier2)) == 0


def test_missing_tiles_with_no_resident_ancestor_are_drawn_by_stale_tiles() -> None:
    """After a layer change the old tiles are retired: a missing tile with no resident
    ancestor draws its own stale tile or its nearest stale ancestor; a resident ancestor
    wins over a stale tile; nothing drawn overlaps."""
    keys = np.array([[5, 8, 8], [5, 9, 8], [5, 20, 20], [5, 21, 20], [5, 0, 30]])
    rs = RenderSet(keys, np.zeros(5, np.int64), [IndexVariant()], error_px=np.ones(5))
    resident = {(4, 10, 10)}  # the new layers' stand-in for (5, 20, 20) and (5, 21, 20)
    stale = {(5, 8, 8), (3, 2, 2), (5, 20, 20)}  # (3, 2, 2): an ancestor of (5, 9, 8)
    out, missing = substitute_missing(rs, _is_in(resident), _is_in(stale))
    got = {tuple(map(int, r)) for r in out.keys}
    # (5, 8, 8) lies under the stale (3, 2, 2) that (5, 9, 8) needs: the coarser one covers
    # both; the resident (4, 10, 10) wins over the stale (5, 20, 20); (5, 0, 30) has nothing.
    assert got == {(3, 2, 2), (4, 10, 10)}
    assert len(missing) == 5
    assert not covered_by(out.keys, out.keys, strict=True).any()
    assert len(out.variant_ids) == len(out.keys) == len(out.error_px)
    # Without stale tiles: only the resident ancestor.
    out, _ = substitute_missing(rs, _is_in(resident))
    assert {tuple(map(int, r)) for r in out.keys} == {(4, 10, 10)}


def test_standins_never_overlap_when_one_lies_under_another() -> None:
    """Two missing tiles whose nearest resident ancestors nest (a parent and one of its
    children): only the coarser is drawn, covering both (it used to draw both, one
    over the other)."""
    keys = np.array([[4, 0, 0], [4, 3, 3]])
    rs = RenderSet(keys, np.zeros(2, np.int64), [IndexVariant()])
    out, _ = substitute_missing(rs, _is_in({(3, 0, 0), (2, 0, 0)}))
    assert {tuple(map(int, r)) for r in out.keys} == {(2, 0, 0)}


def test_the_bytes_warmer_hands_over_the_latest_keys_on_its_thread() -> None:
    """The byte prefetch runs on the warmer's thread, not the caller's; lists handed over
    while it is busy are replaced by the latest; a failing prefetch does not stop it."""
    calls: list[tuple[str, list]] = []
    busy = threading.Event()

    def warm(keys: np.ndarray) -> None:
        calls.append((threading.current_thread().name, keys.tolist()))
        if len(calls) == 1:
            assert busy.wait(10.0)
        if len(calls) == 2:
            raise OSError("server gone")

    warmer = BytesWarmer(warm)
    try:
        warmer.submit(np.array([[1, 0, 0]]))
        wait_for(lambda: len(calls) == 1)
        warmer.submit(np.array([[2, 0, 0]]))  # replaced before the thread is free
        warmer.submit(np.array([[3, 0, 0]]))
        busy.set()
        wait_for(lambda: len(calls) == 2)
        warmer.submit(np.array([[4, 0, 0]]))  # after a failure: still warming
        wait_for(lambda: len(calls) == 3)
    finally:
        warmer.shutdown()
    assert [c[1] for c in calls] == [[[1, 0, 0]], [[3, 0, 0]], [[4, 0, 0]]]
    assert {c[0] for c in calls} == {"gv-warm"}
