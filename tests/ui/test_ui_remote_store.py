"""The window with a tile store served over HTTP (issue #18), against a real server on
127.0.0.1 (`globeview.bench.http_server.StaticServer`, Range honoured, fault modes): File >
Open URL opens and draws it; chunks the server answers with 500 are counted as failed in the
status bar while the window keeps drawing; a slow server never freezes the UI thread (the
longest gap between timer ticks while tiles load is measured); unreachable servers, folders
that are not stores and a 1 GB manifest are one line in a dialog."""

from __future__ import annotations

import itertools
import socket
import time
from pathlib import Path

import pytest
from PyQt6.QtCore import QPoint, QTimer
from pytestqt.exceptions import TimeoutError

pytestmark = pytest.mark.gui

DATA = Path(__file__).resolve().parents[2] / "data"
#: Longest the UI thread may go without running a 10 ms timer while a slow server's tiles
#: load (ms). A read of a tile on the UI thread would wait for the server's SLOW_S (3 s) at
#: least; frames drawn meanwhile take 60-150 ms on llvmpipe (2 cores), up to ~550 ms
#: measured with the machine 3x oversubscribed (load 6.6), 1 710 ms once at load ~10 (a full
#: suite beside two benchmarks and a planet build); quiet, the longest gap was 77 ms. The
#: bound stays below SLOW_S, so one read on the UI thread still fails the test.
MAX_GAP_MS = 2000
SLOW_S = 3.0
#: Seconds the slow server's loading is watched (at most).
MEASURE_S = 25.0


@pytest.fixture(scope="module")
def served(tmp_path_factory, embedded):
    """Served on 127.0.0.1: the Vancouver store (levels 0..7, "store"), a copy of the
    embedded White Mountains store (N44W072, levels 0..12, "wm": its finest tiles are not
    read when it opens) and hostile folders."""
    import shutil

    from globeview.bench.http_server import StaticServer
    from globeview.terrain.ingest.driver import ingest

    root = tmp_path_factory.mktemp("www")
    ingest([DATA / "topobathy_vancouver.tif"], root / "store")
    wm = next(st for st in embedded if st.path.name.startswith("N44W072"))
    shutil.copytree(wm.path, root / "wm")
    (root / "notstore").mkdir()
    (root / "notstore" / "index.html").write_text("<html></html>")
    (root / "huge").mkdir()
    with open(root / "huge" / "manifest.json", "wb") as f:
        f.truncate(1 << 30)  # 1 GB, sparse
    with StaticServer(root) as server:
        yield server


def _open(win, qtbot, url: str, name: str = "store") -> None:
    """Open ``url`` as File > Open URL does and wait until its layer is listed."""
    win.files.ask_url = lambda parent, initial: url
    win.files.open_url_action.trigger()
    qtbot.waitUntil(lambda: name in [ly.name for ly in win.terrain.layers], timeout=60000)


def _settled(win) -> bool:
    st = win.globe.last_stats
    return not win.globe.flight.active and st is not None and st.tiles_loading == 0


def test_open_url_draws_the_remote_store(make_window, served, qtbot, errors_shown):
    served.clear_faults()
    served.reset_log()
    win = make_window()
    _open(win, qtbot, f"{served.url}/store")
    qtbot.waitUntil(lambda: _settled(win), timeout=60000)
    assert errors_shown == []
    assert win.files.recent_files()[0] == f"{served.url}/store"
    lon, lat, *_ = win.globe.camera.lonlat_hpr()
    assert abs(lon + 124.0) < 0.5 and abs(lat - 49.0) < 0.5  # flew to the store
    st = win.globe.last_stats
    assert st.tiles_drawn > 0 and st.triangles > 0
    assert int(st.extra.get("tiles_failed", 0)) == 0
    assert win.status.loading.text() == ""
    assert served.requests("*/store/chunks/*"), "tiles were read over HTTP"
    win.layer_panel.select("store")
    item = win.layer_panel.list.currentItem()
    assert item.toolTip().startswith(f"{served.url}/store")  # the URL, not a local path


def test_chunks_answered_500_are_counted_and_the_window_keeps_drawing(
    make_window, served, qtbot, errors_shown, monkeypatch
):
    """The server answers 500 for the finest level's chunks of the White Mountains store;
    the retry policy is shortened to none (the window's default retries each page three
    times with backoff, which only makes this test slower, not different)."""
    from globeview.terrain.store.http import RemoteOptions
    from globeview.terrain.store.tile_store import TileStore

    real_open = TileStore.open.__func__

    def open_without_retries(cls, path, cache_tiles=None, remote_options=None):
        kwargs = {} if cache_tiles is None else {"cache_tiles": cache_tiles}
        return real_open(cls, path, remote_options=RemoteOptions(retries=0), **kwargs)

    monkeypatch.setattr(TileStore, "open", classmethod(open_without_retries))
    served.clear_faults()
    served.fault("*/wm/chunks/12/*", status=500)
    try:
        win = make_window()
        _open(win, qtbot, f"{served.url}/wm", "wm")
        qtbot.waitUntil(lambda: not win.globe.flight.active, timeout=20000)
        assert win.view_bar.go_to("-71.3, 44.27, 5000, 0, -35")  # Mount Washington: level 12 tiles
        try:
            qtbot.waitUntil(
                lambda: _settled(win) and win.globe.last_stats.extra.get("tiles_failed", 0) > 0,
                timeout=90000,
            )
        except TimeoutError:
            st = win.globe.last_stats
            raise AssertionError(
                f"levels {st.levels} loading {st.tiles_loading} extra {st.extra} "
                f"status {win.status.loading.text()!r} flight {win.globe.flight.active} "
                f"failed {len(win.globe.scene.renderer.loader.failed)}"
            ) from None
        st = win.globe.last_stats
        failed = int(st.extra["tiles_failed"])
        assert win.status.loading.text() == f"{failed} tiles failed"
        assert served.requests("*/wm/chunks/12/*")
        assert st.tiles_drawn > 0 and st.triangles > 0  # coarser tiles stand in
        assert int(st.extra["tiles_standin"]) > 0
        assert errors_shown == []  # failed tiles are counted, not dialogs
        # The window keeps drawing, with the user's LOD provider (not failed by the errors).
        n = win.globe.frames
        win.globe.request_frame()
        qtbot.waitUntil(lambda: win.globe.frames > n, timeout=10000)
        assert "chunked-sse" in win.status.lod.text()
        assert win.plugins.registry.failure_of("chunked-sse") is None
    finally:
        served.clear_faults()


def test_a_slow_server_never_freezes_the_window(make_window, served, qtbot, errors_shown):
    served.clear_faults()
    served.reset_log()
    # Every chunk request waits SLOW_S, as a distant or overloaded server would (the manifest
    # and the blend mask's tiles too: they are read on the loader thread).
    served.fault("*/wm/chunks/*", delay_s=SLOW_S)
    win = make_window()
    g = win.globe
    ticks: list[float] = []
    timer = QTimer()
    timer.setInterval(10)
    timer.timeout.connect(lambda: ticks.append(time.perf_counter()))
    frame_ms: list[float] = []  # each frame's LOD + draw time (what a gap may be)
    g.frameRendered.connect(lambda st, _fps: frame_ms.append(st.lod_ms + st.draw_ms))
    try:
        _open(win, qtbot, f"{served.url}/wm", "wm")
        timer.start()  # from the moment the layer is there: frames, selections, picks
        qtbot.waitUntil(lambda: not g.flight.active, timeout=20000)
        assert win.view_bar.go_to(
            "-71.3, 44.27, 6000, 0, -35"
        )  # Mount Washington, close: levels 10..12
        t0 = time.perf_counter()
        k = 0
        while time.perf_counter() - t0 < MEASURE_S:
            # The cursor moves over the loading terrain: each move picks a height under it
            # (the finest tile there is not fetched yet).
            qtbot.mouseMove(g, QPoint(g.width() // 3 + (k % 40) * 8, g.height() // 2))
            k += 1
            qtbot.wait(30)
            if g.last_stats.tiles_loading == 0 and not g.flight.active and k > 50:
                break
        timer.stop()
        loading = g.last_stats.tiles_loading
        assert "°" in win.status.cursor.text()  # the cursor read a place and a height
        # Once the mouse rests over a remote layer the cursor is picked again (the tile
        # under it may have arrived since).
        picks: list[object] = []
        g.cursorPicked.connect(picks.append)
        qtbot.mouseMove(g, QPoint(g.width() // 2, g.height() // 2))
        qtbot.waitUntil(lambda: len(picks) >= 2, timeout=5000)
    finally:
        served.clear_faults()
    slow_reads = [r for r in served.requests("*/wm/chunks/1[0-2]/*")]
    assert slow_reads, "finest tiles were fetched (slowly) while the UI was measured"
    assert len(ticks) > 100
    gaps = [b - a for a, b in itertools.pairwise(ticks)]
    longest_ms = 1000.0 * max(gaps)
    print(  # noqa: T201
        f"slow server ({SLOW_S} s a request): {len(ticks)} ticks over "
        f"{ticks[-1] - ticks[0]:.1f} s, longest gap {longest_ms:.0f} ms, "
        f"{len(slow_reads)} finest-level requests, {loading} tiles still loading, "
        f"longest frame {max(frame_ms, default=0):.0f} ms"
    )
    assert longest_ms < MAX_GAP_MS, (
        f"the UI thread stalled {longest_ms:.0f} ms (longest frame {max(frame_ms):.0f} ms)"
    )
    assert errors_shown == []


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize(
    ("where", "needle"),
    [
        ("closed port", "connection refused"),
        ("notstore", "not a globeview tile store"),
        ("huge", "too large"),
    ],
)
def test_unreachable_or_bad_stores_are_one_line(
    reused_window, served, qtbot, errors_shown, wait_frame, where, needle
):
    served.clear_faults()
    url = (
        f"https://127.0.0.1:{_closed_port()}/store"
        if where == "closed port"
        else f"{served.url}/{where}"
    )
    win = reused_window
    layers = [ly.name for ly in win.terrain.layers]
    n = len(win.errors.history)
    assert win.files.open_url(url)
    qtbot.waitUntil(
        lambda: len(win.errors.history) > n and not win.files.loader.busy, timeout=60000
    )
    new = win.errors.history[n:]
    assert len(new) == 1 and errors_shown == new, [m.text for m in new]
    assert needle in new[0].text and "\n" not in new[0].text, new[0].text
    assert "Unexpected error" not in new[0].text and not new[0].details
    assert [ly.name for ly in win.terrain.layers] == layers
    wait_frame(win)
    assert win.globe.last_stats.triangles > 0  # the globe keeps drawing


def test_a_server_gone_since_opens_offline_from_the_cache(
    make_window, served, qtbot, errors_shown, tmp_path
):
    """A store viewed before opens from the disk cache when its server cannot be reached at
    all; the window says so in the status bar and draws the cached tiles."""
    import shutil

    from globeview.bench.http_server import StaticServer

    served.clear_faults()
    root = tmp_path / "www"
    root.mkdir()
    shutil.copytree(Path(served.root) / "store", root / "store")
    server = StaticServer(root).start()
    url = f"{server.url}/store"
    try:
        win = make_window()
        _open(win, qtbot, url)
        qtbot.waitUntil(lambda: _settled(win), timeout=60000)
        assert errors_shown == []
    finally:
        server.stop()
    win2 = make_window()
    n = len(win2.errors.history)
    _open(win2, qtbot, url)
    qtbot.waitUntil(lambda: _settled(win2), timeout=60000)
    notes = [m.text for m in win2.errors.history[n:]]
    assert any("offline" in t for t in notes), notes
    st = win2.globe.last_stats
    assert st.tiles_drawn > 0 and int(st.extra.get("tiles_failed", 0)) == 0
    assert errors_shown == []  # a notice, not a dialog
