"""Stores served by a real static web server, Debian's nginx (issue #25 item 4's proof): the
same pixels as the local store, GDAL reading a level's VRT over /vsicurl/, what opening by URL
fetches before the first frame (nginx's access log), and the window's loader threads for
remote layers overlapping their round trips behind a 20 ms server (`NginxServer`'s echo_sleep).

nginx runs as a child process with its own configuration on a free port of 127.0.0.1
(`globeview.bench.nginx_server`); one per module. Without nginx the tests skip, unless
``GLOBEVIEW_REQUIRE_NGINX=1`` (./test) says it must be there: then they fail.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.windows import Window

from globeview.bench.nginx_server import NginxError, NginxServer, find_nginx
from globeview.terrain.quadtree import TileKey, key_for_lonlat
from globeview.terrain.store import http as remote
from globeview.terrain.store.backend import TileNotReady
from globeview.terrain.store.http import RemoteOptions
from globeview.terrain.store.tile_store import TileStore

N44 = Path(__file__).resolve().parents[2] / "data" / "N44W072.hgt"
STORE = "mtwash"
#: Mount Washington from 20 km, oblique (lon, lat, height m, heading, pitch degrees).
POSE = (-71.3, 44.27, 2.0e4, 0.0, -35.0)


def _nginx(root: Path, latency_ms: float = 0.0) -> NginxServer:
    """nginx serving ``root``, started; skips without nginx (fails where it is required)."""
    if find_nginx(latency=latency_ms > 0) is None:
        why = "nginx (and its echo module) not installed: scripts/bootstrap.sh installs them"
        if os.environ.get("GLOBEVIEW_REQUIRE_NGINX") == "1":
            pytest.fail(f"{why} (GLOBEVIEW_REQUIRE_NGINX=1)", pytrace=False)
        pytest.skip(why)
    try:
        return NginxServer(root, latency_ms=latency_ms).start()
    except NginxError as exc:
        pytest.fail(str(exc), pytrace=False)


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding ``mtwash/``: the store of the SRTM3 tile's south-east quarter (0.5 x
    0.5 degrees around Mount Washington, 601 x 601 samples; 2.5 CPU-s to ingest)."""
    from globeview.terrain.ingest.driver import ingest

    src = N44 if N44.exists() else Path("/work/shared/data/N44W072.hgt")
    root = tmp_path_factory.mktemp("nginx-site")
    crop = root.parent / "mtwash.tif"
    with rasterio.open(src) as ds:
        win = Window(600, 600, 601, 601)  # lon -71.5..-71, lat 44.5..44
        shift = Affine.translation(win.col_off, win.row_off)
        profile = ds.profile | dict(
            driver="GTiff", width=601, height=601, transform=ds.transform @ shift
        )
        with rasterio.open(crop, "w", **profile) as out:
            out.write(ds.read(1, window=win), 1)
    ingest([crop], root / STORE, vdatum="egm96")
    return root


@pytest.fixture(scope="module")
def nginx(site: Path) -> Iterator[NginxServer]:
    server = _nginx(site)
    yield server
    server.stop()


def _opts(tmp_path: Path, **kw: object) -> RemoteOptions:
    remote.clear_memory()  # a fresh process's memory: every byte from the server or the disk
    base: dict[str, object] = dict(cache_dir=tmp_path / "http-cache", retries=1, backoff_s=0.01)
    return RemoteOptions(**(base | kw))  # type: ignore[arg-type]


def test_nginx_answers_range_requests_and_logs_them(site: Path, nginx: NginxServer) -> None:
    """The server as the store client sees it: a range request is a 206 of those bytes, and
    the access log has it (what the other tests count)."""
    nginx.reset_log()
    opts = _opts(Path(site.parent))
    ans = remote.fetch(f"{nginx.url}/{STORE}/manifest.json", opts, (0, 10))
    assert ans.status == 206 and ans.body == (site / STORE / "manifest.json").read_bytes()[:10]
    (req,) = nginx.wait_logged(1)  # nginx logs a request after answering it
    assert (req.path, req.range, req.status, req.sent) == (
        f"/{STORE}/manifest.json",
        "bytes=0-9",
        206,
        10,
    )


@pytest.mark.gl
def test_a_store_served_by_nginx_renders_as_the_local_one(
    site: Path, nginx: NginxServer, tmp_path: Path, globeview_gl
) -> None:
    """The headless pipeline draws the same image from the store over nginx as from its
    folder, and the chunks came from nginx by range requests."""
    from globeview.bench.harness import Bench
    from globeview.terrain.compose.stack import TerrainStack

    nginx.reset_log()
    images = []
    for where in (str(site / STORE), f"{nginx.url}/{STORE}"):
        st = TileStore.open(where, remote_options=_opts(tmp_path))
        bench = Bench(TerrainStack.from_stores([st]), (160, 96), ctx=globeview_gl)
        try:
            bench.set_pose(POSE, cut=True)
            bench.frame()
            images.append(bench.target.read_rgb())
        finally:
            bench.release()
            st.close()
    assert images[0].std() > 5  # a real picture, not a blank frame
    assert np.array_equal(images[0], images[1])
    chunks = nginx.requests(f"/{STORE}/chunks/*.tif")
    assert chunks and all(r.status == 206 and r.range for r in chunks)


def test_gdal_reads_a_level_vrt_over_vsicurl(site: Path, nginx: NginxServer) -> None:
    """`gdalinfo /vsicurl/URL/level_NN.vrt` as a GIS user would run it (rasterio, GDAL's
    own HTTP client): the level's size, CRS and heights, its chunk files found relative to
    the VRT on the server."""
    with TileStore.open(site / STORE) as st:
        level = st.max_level
        grid = st.level_grid(level)
    name = f"level_{level:02d}.vrt"
    with rasterio.open(site / STORE / name) as local:
        win = Window(local.width // 3, local.height // 3, 64, 64)
        want = local.read(1, window=win)
    with (
        rasterio.Env(GDAL_DISABLE_READDIR_ON_OPEN="EMPTY_DIR"),
        rasterio.open(f"/vsicurl/{nginx.url}/{STORE}/{name}") as ds,
    ):
        assert (ds.width, ds.height) == (grid.width, grid.height)
        assert ds.crs is not None and ds.crs.to_epsg() == 4326
        got = ds.read(1, window=win)
    assert np.isfinite(want).any()
    np.testing.assert_array_equal(got, want)


def test_opening_by_url_fetches_three_small_files_before_the_first_frame(
    site: Path, nginx: NginxServer, tmp_path: Path
) -> None:
    """Opening by URL reads the manifest and the top metadata shard, nothing else; as a
    layer over another its blend mask comes from the top shard's coverage (no chunk of the
    mask's level), and the first frame's coarsest tiles (levels 0 and 1: no data of a half
    degree yet) and the first with the store's data add one chunk file: three files from
    nginx before the first frame, each small."""
    from globeview.terrain.compose.stack import TerrainStack

    nginx.reset_log()
    with (
        TileStore.open(site / STORE) as base,
        TileStore.open(f"{nginx.url}/{STORE}", remote_options=_opts(tmp_path)) as st,
    ):
        opened = [r.path for r in nginx.requests()]
        assert len(opened) == 2 and opened[0] == f"/{STORE}/manifest.json", opened
        assert opened[1].startswith(f"/{STORE}/meta/top-")
        stack = TerrainStack.from_stores([base, st])
        mask = stack.blend_mask(st)
        assert mask.level >= 9 and 0 < mask.w.mean() < 1  # a regional layer's real band
        for key in (TileKey(0, 0, 0), TileKey(1, 0, 0)):
            assert np.isfinite(stack.heights(key)).any()
            stack.metadata(key.level, np.array([key.x]), np.array([key.y]))
        # The coarsest tile with the store's data (a node in its half degree: level 3).
        first = next(
            TileKey(lv, int(x[()]), int(y[()]))
            for lv in range(st.max_level + 1)
            for x, y in [key_for_lonlat(lv, POSE[0], POSE[1])]
            if st.has_tile(lv, int(x[()]), int(y[()]))
        )
        assert first.level <= 5 and np.isfinite(st.heights(first)).any()
        files = {r.path for r in nginx.requests()}
        sizes = [(site / p.lstrip("/")).stat().st_size for p in files]
    assert len(files) <= 3, sorted(files)
    assert max(sizes) < 64 << 10, sizes  # small files


def test_the_top_shards_coverage_is_the_mask_levels_data(site: Path) -> None:
    """The ingest stores the coverage of the blend mask's level in the top shard: the same
    bits as that level's tiles give (what a store built without one reads)."""
    from globeview.terrain.store.coverage import coverage_level, read_coverage

    with TileStore.open(site / STORE) as st:
        level = coverage_level(st.bounds, st.tile_n, st.max_level)
        stored = st._meta.coverage
        assert stored is not None and stored.level == level
        np.testing.assert_array_equal(stored.bits, read_coverage(st, level).bits)
        assert 0 < stored.bits.mean() < 1


# ---------------------------------------------------------------------------------------------
# The window's loader threads for remote layers


def _load_async(bench, deadline_s: float = 120.0) -> int:
    """Frames drawn as the window draws them (the background loader) until none is loading."""
    bench.session.renderer.async_loading = True
    bench.set_pose(POSE, cut=True)
    frames, deadline = 0, time.monotonic() + deadline_s
    while time.monotonic() < deadline:
        r, _ = bench.frame()
        frames += 1
        if r.stats.tiles_drawn and r.stats.tiles_loading == 0:
            return frames
        time.sleep(0.01)
    pytest.fail("the view never finished loading")


@pytest.mark.gl
def test_a_remote_layer_gets_remote_load_workers_and_loses_them_when_hidden(
    site: Path, nginx: NginxServer, tmp_path: Path, globeview_gl
) -> None:
    """Loader threads: 1 for local layers (2 cores), `REMOTE_LOAD_WORKERS` (at most the
    store's max_requests) while a remote layer is visible; the loader is made again when
    that changes."""
    from globeview.bench.harness import Bench
    from globeview.render.renderer import REMOTE_LOAD_WORKERS
    from globeview.terrain.compose.stack import TerrainStack

    local = TileStore.open(site / STORE)
    far = TileStore.open(f"{nginx.url}/{STORE}", remote_options=_opts(tmp_path, max_requests=3))
    stack = TerrainStack.from_stores([local])
    bench = Bench(stack, (64, 48), ctx=globeview_gl)
    renderer = bench.session.renderer
    renderer.load_kind = "thread"  # the 2-core kind, on any machine
    base = renderer.load_workers
    try:
        bench.frame()  # synchronous: no loader
        renderer.async_loading = True
        bench.frame()
        assert renderer.loader is not None and renderer.loader.workers == base
        stack.add(far, "far")
        assert renderer.load_workers == max(base, min(REMOTE_LOAD_WORKERS, 3)) == max(base, 3)
        bench.frame()
        assert renderer.loader.workers == max(base, 3)
        stack.set_visible("far", False)
        bench.frame()
        assert renderer.load_workers == base and renderer.loader.workers == base
        renderer.load_workers = 2  # by hand (a benchmark): kept whatever the layers
        stack.set_visible("far", True)
        assert renderer.load_workers == 2
    finally:
        bench.release()
        far.close()
        local.close()


@pytest.fixture(scope="module")
def slow_nginx(site: Path) -> Iterator[NginxServer]:
    """nginx answering every request 20 ms late (a far server)."""
    server = _nginx(site, latency_ms=20)
    yield server
    server.stop()


@pytest.mark.gl
@pytest.mark.slow
def test_remote_loader_threads_overlap_their_requests(
    site: Path, slow_nginx: NginxServer, tmp_path: Path, globeview_gl, monkeypatch
) -> None:
    """Behind a 20 ms server the loader's threads each wait on their own chunk requests:
    with `REMOTE_LOAD_WORKERS` nginx answers several chunk requests at once, with one
    thread never more than one (the byte prefetch, which overlaps requests by itself, is
    turned off here so the loader's threads are all that fetch chunks)."""
    from globeview.bench.harness import Bench
    from globeview.render.renderer import REMOTE_LOAD_WORKERS
    from globeview.terrain.compose.stack import TerrainStack

    in_flight = {}
    for workers in (1, None):
        st = TileStore.open(
            f"{slow_nginx.url}/{STORE}", remote_options=_opts(tmp_path / str(workers))
        )
        stack = TerrainStack.from_stores([st])
        monkeypatch.setattr(stack, "prefetch_bytes", None)
        bench = Bench(stack, (160, 96), ctx=globeview_gl)
        renderer = bench.session.renderer
        renderer.load_kind = "thread"
        renderer.load_workers = workers  # None: chosen for the layers
        try:
            slow_nginx.reset_log()
            _load_async(bench)
            assert renderer.loader is not None
            in_flight[renderer.loader.workers] = slow_nginx.max_in_flight(f"/{STORE}/chunks/*")
            assert not renderer.loader.failed
        finally:
            bench.release()
            st.close()
    assert in_flight.keys() == {1, REMOTE_LOAD_WORKERS}
    assert in_flight[1] == 1
    assert in_flight[REMOTE_LOAD_WORKERS] > 1, in_flight


def _chunk_level(path: str) -> int:
    """The level of a chunk file's URL path (``.../chunks/LL/cy/cx-h16.tif``)."""
    return int(path.split("/chunks/")[1].split("/")[0])


def _store_tiles(renderer, store: TileStore, keys: np.ndarray) -> np.ndarray:
    """The resident tiles among ``keys`` (N, 3) built with ``store``'s data (a key finer
    than the store: its ancestor at the store's finest level has data); retired tiles,
    built before the store was added, are not resident."""
    keys = keys[renderer.pool.slots_of(keys) >= 0]
    up = np.maximum(keys[:, 0] - store.max_level, 0)
    has = np.array(
        [
            store.has_data(int(lv - u), np.array([x >> u]), np.array([y >> u])).any()
            for (lv, x, y), u in zip(keys.tolist(), up.tolist(), strict=True)
        ],
        dtype=bool,
    )
    return keys[has]


@pytest.mark.gl
@pytest.mark.slow
def test_a_remote_layer_added_draws_coarse_ancestors_first_and_never_blanks(
    site: Path, slow_nginx: NginxServer, tmp_path: Path, globeview_gl
) -> None:
    """The window's path (issue #25 item 4): a view drawn complete from a local base layer,
    then the store over nginx 20 ms away added on top, its reads on the drawing thread never
    waiting for the network (`forbid_network_on`, as the window's UI thread: the first
    selections over it wait for its metadata shards, fetched in the background, and draw the
    last selection meanwhile). No frame is blank (the base layer's retired tiles and the
    store's stand-ins are drawn); the first frame drawing the store's data draws it through a
    few coarse ancestors while the view's own tiles are still missing; nginx's access log
    shows the chunk requests of those coarse levels before those of the view's deepest
    level; the view then completes with no failed tile. One request in flight at a time
    (``max_requests=1``: one loader thread, one byte-prefetch thread), so the log's order
    is the order the tiles were asked for, not a race between threads. One finished tile
    uploaded a frame once the store is added (``upload_budget``): on a loaded machine a
    frame can take longer than the loader needs for the whole view, and the frames must
    still see the view complete itself tile by tile, in the order the tiles finished."""
    from globeview.bench.harness import Bench
    from globeview.terrain.compose.stack import TerrainStack

    base = TileStore.open(site / STORE)
    stack = TerrainStack.from_stores([base])
    bench = Bench(stack, (160, 96), ctx=globeview_gl)
    renderer = bench.session.renderer
    renderer.load_kind = "thread"
    far = None
    try:
        _load_async(bench)
        slow_nginx.reset_log()
        renderer.upload_budget = 1
        far = TileStore.open(
            f"{slow_nginx.url}/{STORE}", remote_options=_opts(tmp_path, max_requests=1)
        )
        far.forbid_network_on(threading.get_ident())
        stack.add(far, "far")
        first = None
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            r, _ = bench.frame()
            assert r.stats.tiles_drawn > 0, "a blank frame while the layer loads"
            if first is None:
                try:
                    mine = _store_tiles(renderer, far, renderer.last_drawn.keys)
                except TileNotReady:  # its metadata not fetched yet: not drawn yet either
                    mine = np.empty((0, 3), np.int64)
                if len(mine):
                    first = (r, mine)  # the store's tiles drawn, as resident at that frame
            if r.stats.tiles_loading == 0:
                break
            time.sleep(0.01)
        assert first is not None and r.stats.tiles_loading == 0, "the view never completed"
        assert not renderer.loader.failed
        fr, drawn = first
        wanted = int(r.render_set.keys[:, 0].max())  # the complete view's deepest level
        assert fr.stats.extra["tiles_missing"] > 0  # the view's own tiles still loading
        assert int(drawn[:, 0].max()) <= wanted - 3, (drawn.tolist(), wanted)
        chunks = sorted(slow_nginx.requests(f"/{STORE}/chunks/*"), key=lambda q: q.start)
        levels = [_chunk_level(q.path) for q in chunks]
        assert levels and levels[0] <= wanted - 3 and max(levels) > levels[0], levels
    finally:
        bench.release()
        if far is not None:
            far.close()
        base.close()
