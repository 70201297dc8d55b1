"""Remote stores: the HTTP transport, its disk cache and tile stores opened by URL.

Every test talks to a real HTTP server on 127.0.0.1 (`globeview.bench.http_server`), with
its fault modes standing in for slow, dropping and failing servers. No mocks.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rasterio

from globeview.bench.http_server import StaticServer
from globeview.errors import StoreError
from globeview.terrain.quadtree import TileKey
from globeview.terrain.store import http as remote
from globeview.terrain.store.backend import TileNotReady
from globeview.terrain.store.http import RemoteError, RemoteOptions, fetch, is_url
from globeview.terrain.store.http_cache import DiskCache
from globeview.terrain.store.schema import FORMAT_VERSION
from globeview.terrain.store.tile_store import TileStore

# ---------------------------------------------------------------------------------------------
# Fixtures: a folder of files with known bytes, served


@pytest.fixture
def files(tmp_path: Path) -> Path:
    root = tmp_path / "www"
    root.mkdir()
    rng = np.random.default_rng(18)
    (root / "blob.bin").write_bytes(rng.integers(0, 256, 300_000, dtype=np.uint8).tobytes())
    (root / "small.bin").write_bytes(b"0123456789")
    return root


@pytest.fixture
def server(files: Path):
    with StaticServer(files) as srv:
        yield srv


def _opts(tmp_path: Path, **kw: object) -> RemoteOptions:
    base: dict[str, object] = dict(
        cache_dir=tmp_path / "http-cache",
        connect_timeout_s=2.0,
        read_timeout_s=2.0,
        retries=2,
        backoff_s=0.01,
        page_kb=16,
    )
    base.update(kw)
    return RemoteOptions(**base)  # type: ignore[arg-type]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _bytes(server: StaticServer, files: Path, opts: RemoteOptions, name: str = "blob.bin"):
    return remote._RemoteBytes(f"{server.url}/{name}", _sha(files / name), opts)


# ---------------------------------------------------------------------------------------------
# URLs and options


def test_is_url() -> None:
    assert is_url("http://127.0.0.1:8000/store") and is_url("HTTPS://example.org/a/b/")
    assert is_url(" http://user:pw@host/s ")
    for text in (
        "",
        "/tmp/store",
        "store",
        "file:///tmp/store",
        "ftp://host/store",
        "http://",
        "http:///path",
        "http://[::1",
        "http://host:99999/s",
        "http://host/a\nb",
        "http://host/a b",
        "http://host/\x7f",
        "s3://bucket/store",
        "javascript:alert(1)",
        None,
        3,
    ):
        assert not is_url(text), text


@pytest.mark.parametrize(
    ("url", "match"),
    [
        ("http://127.0.0.1:1/x\nfoo", "not a valid store URL"),
        ("https://", "not a valid store URL"),
        ("http://[::1", "not a valid store URL"),
        ("HTTP://127.0.0.1:99999/x", "not a valid store URL"),
        ("http://user:secret@127.0.0.1:1/s", r"user:\*\*\*@127\.0\.0\.1:1/s.*connection refused"),
        ("http://127.0.0.1:1/" + "a" * 5000, "connection refused"),
    ],
)
def test_odd_urls_are_one_line(tmp_path: Path, url: str, match: str) -> None:
    with pytest.raises(StoreError, match=match) as err:
        TileStore.open(url, remote_options=_opts(tmp_path, retries=0))
    msg = str(err.value)
    assert "\n" not in msg and "secret" not in msg and len(msg) < 600


@pytest.mark.parametrize(
    "kw",
    [
        {"cache_mb": -1},
        {"max_requests": 0},
        {"max_requests": 2.5},
        {"retries": True},
        {"connect_timeout_s": 0},
        {"read_timeout_s": float("nan")},
        {"page_kb": 1},
        {"cache_dir": 5},
    ],
)
def test_bad_options_are_one_line(kw: dict[str, object]) -> None:
    with pytest.raises(StoreError) as err:
        RemoteOptions(**kw)  # type: ignore[arg-type]
    assert "\n" not in str(err.value) and next(iter(kw)) in str(err.value)


# ---------------------------------------------------------------------------------------------
# Range reads and the disk cache


def test_range_reads_equal_the_file_and_a_warm_cache_needs_no_server(
    tmp_path: Path, files: Path
) -> None:
    blob = (files / "blob.bin").read_bytes()
    opts = _opts(tmp_path)
    rng = np.random.default_rng(1)
    spans = [
        (int(a), int(n))
        for a, n in zip(rng.integers(0, len(blob), 40), rng.integers(1, 70_000, 40))
    ]
    with StaticServer(files) as srv:
        data = _bytes(srv, files, opts)
        for a, n in spans:
            assert data.read(a, n) == blob[a : a + n]
        log = srv.requests("/blob.bin")
        assert log and all(
            r.range and r.range.startswith("bytes=") and r.status == 206 for r in log
        )
        assert len(log) <= len(blob) // opts.page_bytes + 1  # each page fetched once
    # The server is gone: a fresh reader of the same chunk (same sha256) is served from disk.
    remote.clear_memory()
    again = remote._RemoteBytes(f"{srv.url}/blob.bin", _sha(files / "blob.bin"), opts)
    for a, n in spans:
        assert again.read(a, n) == blob[a : a + n]
    assert again.read(len(blob) - 5, 100) == blob[-5:] and again.read(len(blob), 10) == b""


def test_a_rebuilt_file_never_reads_stale_pages(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path)
    old = _bytes(server, files, opts)
    assert old.read(0, 1000) == (files / "blob.bin").read_bytes()[:1000]
    (files / "blob.bin").write_bytes(b"new contents " * 5000)  # the store is rebuilt
    new = _bytes(server, files, opts)  # the manifest now names a new sha256
    assert new.read(0, 13) == b"new contents "


@pytest.mark.slow
def test_the_disk_cache_stays_under_its_bound(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path, cache_mb=0.1)  # 104857 bytes: 6 pages of 16 KB with headers
    blob = (files / "blob.bin").read_bytes()
    data = _bytes(server, files, opts)
    for a in range(0, len(blob), 9000):
        assert data.read(a, 9000) == blob[a : a + 9000]
    on_disk = sum(f.stat().st_size for f in opts.folder.rglob("*") if f.is_file())
    assert 0 < on_disk <= 0.1 * (1 << 20)
    assert opts.cache().total_bytes == on_disk
    # Least recently used went first: the last pages read are still there.
    last = len(blob) // opts.page_bytes
    assert opts.cache().get(f"{data.key}_{opts.page_kb}k_{last}") is not None
    assert opts.cache().get(f"{data.key}_{opts.page_kb}k_0") is None


def test_a_damaged_cache_entry_is_fetched_again(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path)
    blob = (files / "blob.bin").read_bytes()
    assert _bytes(server, files, opts).read(0, 100) == blob[:100]
    entries = [f for f in opts.folder.rglob("*_16k_0") if f.is_file()]
    assert len(entries) == 1
    raw = bytearray(entries[0].read_bytes())
    raw[-1] ^= 0xFF  # one flipped bit on disk
    entries[0].write_bytes(bytes(raw))
    remote.clear_memory()
    server.reset_log()
    assert _bytes(server, files, opts).read(0, 100) == blob[:100]
    assert len(server.requests("/blob.bin")) == 1
    entries[0].write_bytes(b"GVPG")  # truncated
    remote.clear_memory()
    server.reset_log()
    assert _bytes(server, files, opts).read(10, 100) == blob[10:110]
    assert len(server.requests("/blob.bin")) == 1


def test_an_unwritable_cache_folder_only_turns_caching_off(
    tmp_path: Path, files: Path, server
) -> None:
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("x")  # (root ignores permissions; a file as the folder fails)
    opts = _opts(tmp_path, cache_dir=not_a_folder / "http")
    blob = (files / "blob.bin").read_bytes()
    data = _bytes(server, files, opts)
    assert data.read(0, 200_000) == blob[:200_000]
    assert not opts.cache().writable
    assert _bytes(server, files, opts).read(5, 10) == blob[5:15]


def test_disk_cache_writes_are_atomic_and_leftovers_are_swept(tmp_path: Path) -> None:
    cache = DiskCache(tmp_path / "c", 1 << 20)
    assert cache.put("abcdef", b"payload")
    sub = tmp_path / "c" / "ab"
    (sub / ".tmp-1-2-abcxyz").write_bytes(b"half")  # a writer killed mid-write
    fresh = DiskCache(tmp_path / "c", 1 << 20)
    assert fresh.get("abcdef") == b"payload"
    assert not (sub / ".tmp-1-2-abcxyz").exists()
    assert [p.name for p in sub.iterdir()] == ["abcdef"]


# ---------------------------------------------------------------------------------------------
# Concurrency, timeouts, retries


def test_requests_in_flight_never_exceed_the_bound(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path, max_requests=3, cache_mb=0)
    server.fault("/blob.bin", delay_s=0.05)
    blob = (files / "blob.bin").read_bytes()
    data = _bytes(server, files, opts)
    errors: list[BaseException] = []

    def work(i: int) -> None:
        try:
            for k in range(4):
                a = ((i * 4 + k) * 16384) % (len(blob) - 16384)
                assert data.read(a, 100) == blob[a : a + 100]
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert server.max_in_flight == 3  # reached, never exceeded
    assert remote.GATE.in_flight == 0


def _together(n: int, fn) -> list[object]:
    """Run ``fn()`` in ``n`` threads at once; their results or exceptions."""
    out: list[object] = [None] * n
    barrier = threading.Barrier(n)

    def run(i: int) -> None:
        barrier.wait()
        try:
            out[i] = fn()
        except Exception as exc:  # noqa: BLE001 - returned to the test
            out[i] = exc

    threads = [threading.Thread(target=run, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return out


@pytest.mark.slow
def test_threads_wanting_the_same_page_share_one_request(
    tmp_path: Path, files: Path, server
) -> None:
    blob = (files / "blob.bin").read_bytes()
    server.fault("/blob.bin", delay_s=0.2)
    data = _bytes(server, files, _opts(tmp_path, cache_mb=0))
    assert _together(6, lambda: data.read(40_000, 100)) == [blob[40_000:40_100]] * 6
    assert len(server.requests("/blob.bin")) == 2  # the size (page 0), then page 2
    server.clear_faults()
    server.fault("/blob.bin", status=500, delay_s=0.2)
    server.reset_log()
    results = _together(4, lambda: data.read(100_000, 100))
    assert all(isinstance(r, RemoteError) and "HTTP 500" in str(r) for r in results)
    assert len(server.requests("/blob.bin")) == 3  # one round of retries, shared


def test_a_slow_server_fails_within_the_timeouts(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path, read_timeout_s=0.3, retries=1)
    server.fault("/blob.bin", delay_s=3.0)
    t = time.monotonic()
    with pytest.raises(RemoteError) as err:
        _bytes(server, files, opts).read(0, 10)
    took = time.monotonic() - t
    assert took <= opts.worst_case_s + 1.0
    msg = str(err.value)
    assert "\n" not in msg and "/blob.bin" in msg and "timed out" in msg and "2 attempts" in msg


def test_a_body_that_stalls_fails_within_the_timeouts(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path, read_timeout_s=0.3, retries=0)
    server.fault("/blob.bin", stall_s=3.0)
    t = time.monotonic()
    with pytest.raises(RemoteError, match="timed out"):
        _bytes(server, files, opts).read(0, 10)
    assert time.monotonic() - t <= opts.worst_case_s + 1.0


def test_dropped_connections_are_retried(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path, retries=3)
    rule = server.fault("/blob.bin", flaky=2)
    blob = (files / "blob.bin").read_bytes()
    assert _bytes(server, files, opts).read(100, 50) == blob[100:150]
    assert rule.failed == 2
    assert [r.status for r in server.requests("/blob.bin")] == [0, 0, 206]


def test_a_connection_dropped_mid_body_is_retried_then_fails(
    tmp_path: Path, files: Path, server
) -> None:
    opts = _opts(tmp_path, retries=2)
    server.fault("/blob.bin", drop=True)
    with pytest.raises(RemoteError) as err:
        _bytes(server, files, opts).read(0, 10)
    assert "connection closed" in str(err.value) and err.value.status is None
    assert len(server.requests("/blob.bin")) == 3


@pytest.mark.parametrize(("status", "tries"), [(500, 3), (503, 3), (429, 3), (404, 1), (403, 1)])
def test_http_errors_retry_only_when_worth_it(
    tmp_path: Path, files: Path, server, status: int, tries: int
) -> None:
    opts = _opts(tmp_path, retries=2)
    server.fault("/blob.bin", status=status)
    with pytest.raises(RemoteError) as err:
        _bytes(server, files, opts).read(0, 10)
    assert err.value.status == status and f"HTTP {status}" in str(err.value)
    assert f"{server.url}/blob.bin" in str(err.value) and "\n" not in str(err.value)
    assert len(server.requests("/blob.bin")) == tries


# ---------------------------------------------------------------------------------------------
# Hostile answers


def test_a_server_ignoring_range_still_works(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path)
    server.fault("/blob.bin", ignore_range=True)
    blob = (files / "blob.bin").read_bytes()
    data = _bytes(server, files, opts)
    assert data.read(123_456, 1000) == blob[123_456:124_456]
    assert data.read(5, 5) == blob[5:10] and data.read(290_000, 20_000) == blob[290_000:]
    assert len(server.requests("/blob.bin")) == 1  # the whole file once, every page cached


def test_a_huge_content_length_is_refused_unread(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path)
    server.fault("/blob.bin", length=1 << 40, ignore_range=True)
    with pytest.raises(RemoteError, match="announced") as err:
        _bytes(server, files, opts).read(0, 10)
    assert "\n" not in str(err.value)


def test_a_short_body_is_retried_then_fails(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path, retries=1)
    server.fault("/blob.bin", short=True)
    with pytest.raises(RemoteError, match="connection closed after"):
        _bytes(server, files, opts).read(0, 10)
    assert len(server.requests("/blob.bin")) == 2


def test_an_encoded_answer_is_refused(tmp_path: Path, files: Path, server) -> None:
    server.fault("/blob.bin", headers={"Content-Encoding": "gzip"})
    with pytest.raises(RemoteError, match="gzip-encoded") as err:
        _bytes(server, files, _opts(tmp_path)).read(0, 10)
    assert "\n" not in str(err.value) and len(server.requests("/blob.bin")) == 1


def test_redirects_are_followed_and_bounded(tmp_path: Path, files: Path, server) -> None:
    opts = _opts(tmp_path)
    blob = (files / "blob.bin").read_bytes()
    with StaticServer(files) as front:
        front.fault("/blob.bin", redirect=server.url)
        assert _bytes(front, files, opts).read(7, 7) == blob[7:14]
        assert server.requests("/blob.bin")
        front.clear_faults()
        front.fault("/loop*", redirect=front.url + "/loop")  # /loop -> /loop/loop -> ...
        with pytest.raises(RemoteError, match="redirects"):
            fetch(front.url + "/loop", opts, (0, 10))


def test_a_redirect_to_another_scheme_is_refused(tmp_path: Path, files: Path, server) -> None:
    server.fault("/blob.bin", redirect="file:///etc")
    with pytest.raises(RemoteError, match="not http"):
        fetch(server.url + "/blob.bin", _opts(tmp_path), (0, 10))


def test_an_unreachable_host_fails_fast(tmp_path: Path, files: Path) -> None:
    with StaticServer(files) as srv:
        url = srv.url
    opts = _opts(tmp_path, retries=1)
    t = time.monotonic()
    with pytest.raises(RemoteError, match="connection refused"):
        fetch(url + "/blob.bin", opts, (0, 10))
    assert time.monotonic() - t < opts.worst_case_s


def test_the_server_log_and_in_flight_are_honest(files: Path) -> None:
    with StaticServer(files) as srv:
        srv.fault("/small.bin", delay_s=0.2)
        ts = [
            threading.Thread(target=fetch, args=(srv.url + "/small.bin", RemoteOptions(cache_mb=0)))
            for _ in range(3)
        ]
        for t in ts:
            t.start()
        for t in ts:
            t.join()
        assert srv.max_in_flight == 3
        assert [r.status for r in srv.requests("/small.bin")] == [200] * 3
        assert all(r.range is None for r in srv.log)
    assert os.path.isdir(files)


# ---------------------------------------------------------------------------------------------
# Tile stores opened by URL

N44 = Path(__file__).resolve().parents[2] / "data" / "N44W072.hgt"


def _n44() -> Path:
    return N44 if N44.exists() else Path("/work/shared/data/N44W072.hgt")


@pytest.fixture(scope="module")
def store_root(tmp_path_factory: pytest.TempPathFactory, seed_dem_store) -> Path:
    """A folder holding ``n44/``, the store of the SRTM3 White Mountains tile (levels 0-12,
    four chunk files at level 12; what ``ingest([N44], out)`` writes, copied from the
    session's `seed_dem_store` instead of ingested again), and ``not-a-store/`` (a folder
    with a foreign manifest.json)."""
    root = tmp_path_factory.mktemp("remote")
    (store,) = (seed_dem_store(tmp_path_factory.mktemp("cache"), _n44()) / "stores").iterdir()
    store.rename(root / "n44")
    (root / "not-a-store").mkdir()
    (root / "not-a-store" / "manifest.json").write_text('{"name": "a web app"}')
    return root


@pytest.fixture
def served(store_root: Path):
    with StaticServer(store_root) as srv:
        yield srv


def _keys(st: TileStore) -> list[TileKey]:
    """Every tile of every level's extent and the ring of tiles just outside it."""
    keys = []
    for lv in range(st.max_level + 1):
        g = st.level_grid(lv)
        keys += [
            TileKey(lv, (g.x0 + ix) % g.ncols, g.y0 + iy)
            for iy in range(-1, g.ny + 1)
            for ix in range(-1, g.nx + 1)
            if 0 <= g.y0 + iy < g.nrows
        ]
    return keys


def _level12_files(st: TileStore) -> dict[tuple[int, int], str]:
    """Level 12's chunk files (store format 7: chunks/12/cy/cx-<sha>.tif) by their (row,
    column) among the level's chunks with a file, (0, 0) the first; the SRTM3 tile's are
    2 x 3 chunks of the global grid."""
    found = {(cy, cx): f.file for lv, cy, cx, f in st.iter_chunks() if lv == 12 and f.file}
    cy0, cx0 = min(cy for cy, _ in found), min(cx for _, cx in found)
    return {(cy - cy0, cx - cx0): name for (cy, cx), name in found.items()}


def _chunk12(store_root: Path, where: tuple[int, int]) -> str:
    """The file name (relative to the store) of level 12's chunk ``where`` (`_level12_files`)."""
    with TileStore.open(store_root / "n44") as st:
        return _level12_files(st)[where]


def _level12_by_chunk(st: TileStore) -> dict[tuple[int, int], list[TileKey]]:
    """Level 12's tiles with data by the chunk file their nodes come from (keys as
    `_level12_files`), row by row."""
    g = st.level_grid(12)
    k = st.manifest.chunk_tiles
    files = {(cy, cx) for lv, cy, cx, f in st.iter_chunks() if lv == 12 and f.file}
    cy0, cx0 = min(cy for cy, _ in files), min(cx for _, cx in files)
    out: dict[tuple[int, int], list[TileKey]] = {}
    for y in range(g.y0, g.y0 + g.ny):
        for x in range(g.x0, g.x0 + g.nx):
            if (y // k, x // k) in files and st.has_tile(12, x, y):
                out.setdefault((y // k - cy0, x // k - cx0), []).append(TileKey(12, x, y))
    return out


@pytest.mark.slow
def test_remote_heights_equal_local_heights(store_root: Path, served, tmp_path: Path) -> None:
    local = TileStore.open(store_root / "n44")
    with TileStore.open(f"{served.url}/n44", remote_options=_opts(tmp_path)) as st:
        assert st.url == f"{served.url}/n44" and st.location == st.url and st.path.name == "n44"
        assert st.max_level == local.max_level == 12 and st.bounds == local.bounds
        keys = _keys(st)
        assert len(keys) > 1000
        for k in keys:
            assert np.array_equal(st.heights_padded(k), local.heights_padded(k), equal_nan=True)
        # ... and the local store reads what the level's VRT (GDAL's mosaic) holds.
        g = local.level_grid(12)
        with rasterio.open(store_root / "n44" / "level_12.vrt") as vrt:
            whole = vrt.read(1)
        n = g.tile_nodes
        for k in keys[-400:]:
            iy, ix = k.y - g.y0, (k.x - g.x0) % g.ncols
            if k.level == 12 and 0 <= iy < g.ny and ix < g.nx:
                want = whole[iy * n : iy * n + n + 1, ix * n : ix * n + n + 1]
                assert np.array_equal(st.heights(k), want, equal_nan=True)
        xs, ys = np.meshgrid(np.arange(g.x0 - 1, g.x0 + g.nx + 1), np.arange(g.y0, g.y0 + g.ny))
        assert np.array_equal(st.has_data(12, xs, ys), local.has_data(12, xs, ys))
        assert np.array_equal(
            st.tile_stride_error(12, xs, ys), local.tile_stride_error(12, xs, ys), equal_nan=True
        )
        st.verify()
    local.close()


@pytest.mark.slow
def test_a_cold_cache_uses_range_requests_and_a_warm_one_none(
    store_root: Path, tmp_path: Path
) -> None:
    opts = _opts(tmp_path)
    srv = StaticServer(store_root).start()
    try:
        with TileStore.open(f"{srv.url}/n44", remote_options=opts) as st:
            keys = _keys(st)
            cold = [st.heights(k) for k in keys]
        chunks = srv.requests("/n44/chunks/*.tif")
        assert chunks and all(r.range and r.status == 206 for r in chunks)
        assert not srv.requests("*.vrt")  # the chunk files are read directly
        warm = TileStore.open(f"{srv.url}/n44", remote_options=opts)
    finally:
        srv.stop()
    n_before = len(srv.log)
    remote.clear_memory()
    with warm:  # the server is gone: every byte from the disk cache
        assert not warm.offline
        for k, h in zip(keys, cold, strict=True):
            assert np.array_equal(warm.heights(k), h, equal_nan=True)
    # A store viewed before opens with the server gone (its manifest kept in the cache too).
    remote.clear_memory()
    with TileStore.open(f"{srv.url}/n44", remote_options=_opts(tmp_path, retries=0)) as off:
        assert off.offline
        for k, h in zip(keys, cold, strict=True):
            assert np.array_equal(off.heights(k), h, equal_nan=True)
    assert len(srv.log) == n_before
    on_disk = sum(f.stat().st_size for f in opts.folder.rglob("*") if f.is_file())
    assert on_disk <= opts.cache_mb * (1 << 20)


@pytest.mark.slow
@pytest.mark.parametrize("status", [500, 404])
def test_one_failing_chunk_fails_only_its_tiles(
    store_root: Path, served, tmp_path: Path, status: int
) -> None:
    opts = _opts(tmp_path, retries=1, fail_fast_s=0.5)
    name = _chunk12(store_root, (0, 0))
    served.fault(f"/n44/{name}", status=status)
    with TileStore.open(f"{served.url}/n44", remote_options=opts) as st:
        by_chunk = _level12_by_chunk(st)
        assert len(by_chunk) == 6
        failed, loaded = set(), set()
        for keys in by_chunk.values():
            for k in keys:
                try:
                    st.heights(k)
                    loaded.add(k)
                except StoreError as exc:
                    msg = str(exc)
                    assert "\n" not in msg and f"HTTP {status}" in msg
                    assert f"{served.url}/n44/{name}" in msg
                    failed.add(k)
        # The failing chunk's tiles fail; tiles of the other chunks load, except those whose
        # ring or last row/column reaches into the failing chunk.
        assert set(by_chunk[(0, 0)]) <= failed
        assert set(by_chunk[(1, 1)]) - failed and set(by_chunk[(0, 1)]) - failed
        assert len(loaded) > len(failed)
        # The server recovers: the failed tiles load (no handle or cache kept the failure
        # past fail_fast_s).
        served.clear_faults()
        time.sleep(0.5)
        for k in failed:
            st.heights(k)


@pytest.mark.slow
def test_a_failed_chunk_fails_fast_for_a_while(store_root: Path, served, tmp_path: Path) -> None:
    """After a chunk's read failed (retries spent), its other tiles fail at once for
    fail_fast_s (the window shows them failed in seconds), then the server is asked again."""
    opts = _opts(tmp_path, retries=2, backoff_s=0.2, fail_fast_s=2.0)
    name = _chunk12(store_root, (1, 0))
    served.fault(f"/n44/{name}", status=503)
    with TileStore.open(f"{served.url}/n44", remote_options=opts) as st:
        keys = _level12_by_chunk(st)[(1, 0)]
        with pytest.raises(StoreError, match="HTTP 503"):
            st.heights(keys[0])
        asked = len(served.requests(f"*/{name}"))
        assert asked == 3
        t = time.monotonic()
        for k in keys[1:20]:
            with pytest.raises(StoreError, match=r"HTTP 503.* s ago") as err:
                st.heights(k)
            assert "\n" not in str(err.value)
        assert time.monotonic() - t < 1.0  # 19 tiles, not 19 rounds of retries (0.6 s each)
        assert len(served.requests(f"*/{name}")) == asked
        served.clear_faults()
        time.sleep(2.0)
        assert st.heights(keys[1]).shape == (st.tile_size, st.tile_size)


def test_ctrl_c_during_a_remote_read_is_a_keyboard_interrupt(
    store_root: Path, served, tmp_path: Path
) -> None:
    """SIGINT while GDAL waits inside a read of a slow server: KeyboardInterrupt reaches the
    caller (not a crash, not a StoreError), and the store reads on afterwards."""
    served.fault("*.tif", delay_s=1.5)
    with TileStore.open(f"{served.url}/n44", remote_options=_opts(tmp_path)) as st:
        key = _level12_by_chunk(st)[(0, 0)][5]
        threading.Timer(0.4, os.kill, (os.getpid(), signal.SIGINT)).start()
        with pytest.raises(KeyboardInterrupt):
            st.heights(key)
        served.clear_faults()
        assert st.heights(key).shape == (st.tile_size, st.tile_size)


_CTRL_C_IN_A_CALLBACK = """
import signal, sys
from pathlib import Path
from globeview.interrupts import install_sigint_marker
from globeview.terrain.store import http as remote
from globeview.terrain.store.http import RemoteOptions
from globeview.terrain.store.tile_store import TileStore
where, url, cache = sys.argv[1:4]
assert install_sigint_marker()
st = TileStore.open(url, remote_options=RemoteOptions(cache_dir=Path(cache)))
g = st.level_grid(12)
key = (12, g.x0 + g.nx // 2, g.y0 + g.ny // 2)  # in the data (the bbox's chunks reach past it)
if where == "close":
    st.heights(key)  # its chunk file open, to be closed
cls = remote._Opener if where == "open" else remote._RemoteFile
original, calls = getattr(cls, where), []
def ctrl_c_on_entry(self, *args, **kwargs):  # a Ctrl-C lands as GDAL calls back, outside our guard
    calls.append(where)
    if len(calls) == 1:
        signal.raise_signal(signal.SIGINT)
    return original(self, *args, **kwargs)
setattr(cls, where, ctrl_c_on_entry)
try:
    st.close() if where == "close" else st.heights(key)
    print("returned", flush=True)
except KeyboardInterrupt:
    print("KeyboardInterrupt", flush=True)
except Exception as exc:
    print(type(exc).__name__, exc, flush=True)
if where != "close":
    print("then", st.heights(key).shape, flush=True)  # the store reads on
"""


@pytest.mark.slow
@pytest.mark.parametrize("where", ["read", "seek", "tell", "open", "close"])
def test_ctrl_c_inside_a_gdal_callback_is_a_keyboard_interrupt(
    store_root: Path, served, tmp_path: Path, where: str
) -> None:
    """A SIGINT that lands in a callback of GDAL's, where rasterio swallows what Python raises
    (it was a generic read error, a tile stood in for and an interrupted render exiting 0; a
    close that returned normally; or, at a read's start, an aborted process): held back and
    raised as KeyboardInterrupt once GDAL returns. In a child process (the failure aborted)."""
    url = f"{served.url}/n44"
    r = subprocess.run(
        [sys.executable, "-c", _CTRL_C_IN_A_CALLBACK, where, url, str(tmp_path / "c")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stdout.splitlines()
    assert lines[0] == "KeyboardInterrupt", (lines, r.stderr[-2000:])
    if where != "close":
        assert lines[1] == "then (65, 65)"


def test_dropped_connections_are_retried_for_tiles(
    store_root: Path, served, tmp_path: Path
) -> None:
    name = _chunk12(store_root, (1, 1))
    served.fault(f"/n44/{name}", flaky=2)
    local = TileStore.open(store_root / "n44")
    with TileStore.open(f"{served.url}/n44", remote_options=_opts(tmp_path, retries=3)) as st:
        for k in _level12_by_chunk(st)[(1, 1)]:
            assert np.array_equal(st.heights(k), local.heights(k), equal_nan=True)
    assert [r.status for r in served.requests(f"/n44/{name}")][:3] == [0, 0, 206]
    local.close()


def test_a_slow_server_fails_a_tile_within_the_timeouts(
    store_root: Path, served, tmp_path: Path
) -> None:
    opts = _opts(tmp_path, read_timeout_s=0.3, retries=1)
    with TileStore.open(f"{served.url}/n44", remote_options=opts) as st:
        served.fault("*.tif", delay_s=2.0)
        key = _level12_by_chunk(st)[(0, 0)][0]
        t = time.monotonic()
        with pytest.raises(StoreError, match="timed out") as err:
            st.heights(key)
        assert time.monotonic() - t <= opts.worst_case_s + 1.0
        name = _chunk12(store_root, (0, 0))
        assert "\n" not in str(err.value) and name in str(err.value)


@pytest.mark.slow
def test_a_server_ignoring_range_still_serves_the_store(
    store_root: Path, served, tmp_path: Path
) -> None:
    served.fault("*.tif", ignore_range=True)
    local = TileStore.open(store_root / "n44")
    with TileStore.open(f"{served.url}/n44", remote_options=_opts(tmp_path)) as st:
        for k in _keys(st)[::7]:
            assert np.array_equal(st.heights(k), local.heights(k), equal_nan=True)
    assert all(r.status == 200 for r in served.requests("*.tif"))
    local.close()


def test_prefetch_keeps_requests_in_flight_under_the_bound(
    store_root: Path, served, tmp_path: Path
) -> None:
    served.fault("*.tif", delay_s=0.03)
    opts = _opts(tmp_path, max_requests=2, cache_mb=0)
    with TileStore.open(f"{served.url}/n44", remote_options=opts) as st:
        keys = [k for keys in _level12_by_chunk(st).values() for k in keys[:40:5]]
        for f in st.prefetch(keys):
            f.result(timeout=60)
    assert 1 <= served.max_in_flight <= 2


@pytest.mark.slow
def test_a_thread_forbidden_the_network_never_waits(
    store_root: Path, served, tmp_path: Path
) -> None:
    served.fault("*.tif", delay_s=0.5)
    with TileStore.open(f"{served.url}/n44", remote_options=_opts(tmp_path)) as st:
        key = _level12_by_chunk(st)[(1, 1)][3]  # (its shards read: the tile's bytes are not)
        st.forbid_network_on(threading.get_ident())
        t = time.monotonic()
        with pytest.raises(TileNotReady):
            st.heights(key)
        assert time.monotonic() - t < 0.2  # at once, not after the server's 0.5 s
        for _ in range(50):  # asked again and again (a cursor over it): loaded once
            with pytest.raises(TileNotReady):
                st.heights(key)
        assert len(st._prefetch.loading) == 1
        deadline = time.monotonic() + 30
        while not st.cached(key) and time.monotonic() < deadline:
            time.sleep(0.05)  # loaded by the store's background pool meanwhile
        assert st.heights(key).shape == (st.tile_size, st.tile_size)
        time.sleep(0.1)
        assert not st._prefetch.loading
    # One load of the tile's pages, not one per ask.
    assert len(served.requests(f"*/{_chunk12(store_root, (1, 1))}")) <= 4


@pytest.mark.slow
def test_prefetch_bytes_fetches_a_frames_blocks_concurrently(
    store_root: Path, served, tmp_path: Path
) -> None:
    """The renderer hands a frame's missing tiles to `prefetch_bytes`: their blocks' bytes
    arrive several requests at once, and the reads that follow need no request at all."""
    served.fault("*.tif", delay_s=0.05)
    opts = _opts(tmp_path, max_requests=4)
    local = TileStore.open(store_root / "n44")
    assert local.prefetch_bytes([(12, 2460, 1030)]) == []
    with TileStore.open(f"{served.url}/n44", remote_options=opts) as st:
        keys = [k for ks in _level12_by_chunk(st).values() for k in ks[::3]]
        futures = st.prefetch_bytes(keys)
        assert futures and st.prefetch_bytes(keys) == []  # each tile's blocks asked once
        for f in futures:
            f.result(timeout=60)
        assert 2 <= served.max_in_flight <= 4
        served.reset_log()
        remote.clear_memory()
        for k in keys:
            assert np.array_equal(st.heights(k), local.heights(k), equal_nan=True)
        assert served.requests("*.tif") == []  # every byte already here
    local.close()


def test_closing_a_store_cancels_its_reads_at_once(
    store_root: Path, served, tmp_path: Path
) -> None:
    """A slow server does not hold `close` (the window's) for the timeouts: reads under way
    end within milliseconds, as one-line errors."""
    opts = _opts(tmp_path, read_timeout_s=30.0, retries=3)
    st = TileStore.open(f"{served.url}/n44", remote_options=opts)
    served.fault("*.tif", stall_s=20.0)  # half the body, then silence
    futures = st.prefetch(_level12_by_chunk(st)[(0, 0)][:8])
    deadline = time.monotonic() + 10
    while not served.requests("*.tif") and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.2)  # the reads are blocked in the body now
    t = time.monotonic()
    st.close()
    assert time.monotonic() - t < 3.0  # not 4 x 30 s
    for f in futures:
        assert f.cancelled() or isinstance(f.exception(timeout=5), StoreError)


@pytest.mark.parametrize(
    ("where", "fault", "match"),
    [
        ("/nothing-here", None, r"not a globeview tile store \(no manifest\.json: HTTP 404\)"),
        ("/not-a-store", None, r"not a globeview tile store \(manifest\.json is not ours\)"),
        ("/n44", {"status": 500}, r"cannot open .*HTTP 500"),
        ("/n44", {"status": 403}, r"cannot open .*HTTP 403"),
        ("/n44", {"length": 1 << 30, "drop": True}, r"cannot open .*1073741824 bytes announced"),
        ("/n44", {"redirect": "ftp://example.org"}, r"not http"),
    ],
)
def test_bad_store_urls_are_one_line(
    served, tmp_path: Path, where: str, fault: dict | None, match: str
) -> None:
    if fault is not None:
        served.fault("*/manifest.json", **fault)
    with pytest.raises(StoreError, match=match) as err:
        TileStore.open(served.url + where, remote_options=_opts(tmp_path, retries=1))
    assert "\n" not in str(err.value)


def test_damaged_or_oversized_manifests_are_one_line(store_root: Path, tmp_path: Path) -> None:
    www = tmp_path / "www"
    for name, text in [
        ("garbage", b"\x00\xff not json"),
        ("array", b"[1, 2, 3]"),
        ("old", b'{"format": "globeview-tile-store", "format_version": 2}'),
        (
            "broken",
            b'{"format": "globeview-tile-store", "format_version": %d, "levels": 3}'
            % FORMAT_VERSION,
        ),
        ("huge", b" " * (2 << 20) + b"{}"),
    ]:
        (www / name).mkdir(parents=True)
        (www / name / "manifest.json").write_bytes(text)
    opts = _opts(tmp_path, max_manifest_mb=1.0)
    with StaticServer(www) as srv:
        for name, match in [
            ("garbage", "unreadable manifest"),
            ("array", "not a JSON object"),
            ("old", "built before vertical datums"),
            ("broken", "damaged manifest.json"),
            ("huge", "bytes announced"),
        ]:
            with pytest.raises(StoreError, match=match) as err:
                TileStore.open(f"{srv.url}/{name}", remote_options=opts)
            assert "\n" not in str(err.value) and srv.url in str(err.value)


def test_an_unreachable_server_is_one_line(tmp_path: Path, files: Path) -> None:
    with StaticServer(files) as srv:
        url = srv.url
    with pytest.raises(StoreError, match="connection refused") as err:
        TileStore.open(url + "/store", remote_options=_opts(tmp_path, retries=0))
    assert "\n" not in str(err.value)


@pytest.mark.slow
def test_a_remote_store_renders_as_the_local_one(store_root: Path, served, tmp_path: Path) -> None:
    """The real pipeline (the harness's headless session, the window's FramePipeline) draws
    the same image from the store over HTTP as from its folder."""
    from globeview.bench.harness import Bench
    from globeview.terrain.compose.stack import TerrainStack

    pose = (-71.3, 44.27, 2.0e4, 0.0, -35.0)  # Mount Washington, oblique
    images = []
    for where in (str(store_root / "n44"), f"{served.url}/n44"):
        st = TileStore.open(where, remote_options=_opts(tmp_path))
        bench = Bench(TerrainStack.from_stores([st]), (160, 96))
        try:
            bench.set_pose(pose, cut=True)
            for _ in range(3):
                bench.frame()
            images.append(bench.target.read_rgb())
        finally:
            bench.release()
            st.close()
    assert images[0].std() > 5  # a real picture, not a blank frame
    assert np.array_equal(images[0], images[1])
    assert served.requests("/n44/chunks/*.tif")


def _self_signed(tmp_path: Path) -> tuple[Path, Path]:
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
         "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
         "-keyout", str(key), "-out", str(cert)],
        check=True, capture_output=True,
    )  # fmt: skip
    return cert, key


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
def test_https_stores(store_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Over HTTPS: an untrusted certificate is one line at once (no retries); trusted (here
    through SSL_CERT_FILE, as for any OpenSSL client), the store reads as the local one."""
    cert, key = _self_signed(tmp_path)
    local = TileStore.open(store_root / "n44")
    with StaticServer(store_root, certfile=cert, keyfile=key) as srv:
        assert srv.url.startswith("https://")
        t = time.monotonic()
        with pytest.raises(StoreError, match=r"(?i)certificate") as err:
            TileStore.open(f"{srv.url}/n44", remote_options=_opts(tmp_path, retries=3))
        assert "\n" not in str(err.value) and time.monotonic() - t < 2.0
        monkeypatch.setenv("SSL_CERT_FILE", str(cert))
        with TileStore.open(f"{srv.url}/n44", remote_options=_opts(tmp_path)) as st:
            for k in _level12_by_chunk(st)[(1, 0)][::9]:
                assert np.array_equal(st.heights(k), local.heights(k), equal_nan=True)
        assert all(r.status == 206 for r in srv.requests("*.tif"))
    local.close()


def test_a_chunk_replaced_on_the_server_is_one_line_not_mixed_bytes(
    store_root: Path, tmp_path: Path
) -> None:
    """A store rebuilt on the server while it is open: pages of the new file are neither
    decoded with the old one's nor cached under the old digest."""
    www = tmp_path / "www"
    shutil.copytree(store_root / "n44", www / "n44")
    opts = _opts(tmp_path, retries=0)
    with StaticServer(www) as srv, TileStore.open(f"{srv.url}/n44", remote_options=opts) as st:
        keys = _level12_by_chunk(st)[(1, 1)]
        st.heights(keys[0])  # the chunk's header and first blocks are read
        chunk = www / "n44" / _chunk12(store_root, (1, 1))
        chunk.write_bytes(chunk.read_bytes() + b"\0" * 70_000)  # rebuilt: another size
        remote.clear_memory()
        with pytest.raises(StoreError, match="changed on the server") as err:  # noqa: PT012
            for k in keys:
                st.heights(k)
        assert "\n" not in str(err.value)


@pytest.mark.slow
def test_remote_datasets_never_crash_the_garbage_collector(
    store_root: Path, tmp_path: Path
) -> None:
    """Datasets opened by threads that end, a store dropped without close, the collector run
    on the main thread, then the interpreter's exit: no crash (rasterio's opener keeps file
    objects per context; a foreign close used to segfault). In a child process, to see it."""
    script = f"""
import gc, threading
from pathlib import Path
from globeview.bench.http_server import StaticServer
from globeview.terrain.store import http as remote
from globeview.terrain.store.http import RemoteOptions
from globeview.terrain.store.tile_store import TileStore
srv = StaticServer({str(store_root)!r}).start()
opts = RemoteOptions(cache_dir=Path({str(tmp_path / "c")!r}))
st = TileStore.open(srv.url + "/n44", remote_options=opts)
g = st.level_grid(12)
# The rows with data (the bbox's chunks reach past the tile's).
rows = [y for y in range(g.y0, g.y0 + g.ny) if st.has_tile(12, g.x0 + g.nx // 2, y)]
y0, ny = rows[0], len(rows)
def work(i):
    for k in range(6):
        st.heights((12, g.x0 + (i * 7 + k) % g.nx, y0 + (i * 3 + k) % ny))
ts = [threading.Thread(target=work, args=(i,)) for i in range(4)]
[t.start() for t in ts]; [t.join() for t in ts]
for f in st.prefetch([(12, g.x0 + i, y0 + 5) for i in range(8)]):
    f.result()
del st, ts
gc.collect()
st2 = TileStore.open(srv.url + "/n44", remote_options=opts)
st2.heights((12, g.x0, y0))
st2.close()
assert remote.open_datasets() > 0  # the first store's, closed at exit
gc.collect()
srv.stop()
print("OK")
"""
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip().endswith("OK"), r.stderr[-2000:]


def test_opening_by_url_reads_the_manifest_and_the_top_shard_only(
    store_root: Path, served, tmp_path: Path
) -> None:
    """Store format 7: opening a store over HTTP asks for two small files (the manifest and
    the top metadata shard); the first frame's level-0 tiles add one chunk file: at most 3
    files before the first frame, whatever the store's size. Deeper shards come when a tile
    under them is asked about, once (then from the disk cache, keyed by their sha256)."""
    served.reset_log()
    opts = _opts(tmp_path)
    with TileStore.open(f"{served.url}/n44", remote_options=opts) as st:
        opened = sorted({r.path for r in served.log})
        assert opened[0] == "/n44/manifest.json" and len(opened) == 2, opened
        assert opened[1].startswith("/n44/meta/top-") and st.shards_loaded == 1
        for x in (0, 1):
            st.heights(TileKey(0, x, 0))
        assert len({r.path for r in served.log}) <= 3
        g = st.level_grid(12)
        # Level 12's facts: its shard (rooted at level 10) and the one naming it (at 6).
        assert st.has_data(12, g.x0 + 20, g.y0 + 20)
        shards = {r.path for r in served.log if "/meta/" in r.path}
        assert len(shards) == 3 and st.shards_loaded == 3
    served.reset_log()
    remote.clear_memory()
    with TileStore.open(f"{served.url}/n44", remote_options=opts) as again:
        assert again.has_data(12, g.x0 + 20, g.y0 + 20)
    assert not [r for r in served.log if "/meta/" in r.path]  # from the disk cache


def test_a_shard_asked_for_on_a_thread_that_must_not_wait_loads_in_the_background(
    store_root: Path, served, tmp_path: Path
) -> None:
    """A window's thread asking about tiles under a shard not fetched yet: TileNotReady at
    once, the shard fetched in the background, then the answer."""
    with TileStore.open(f"{served.url}/n44", remote_options=_opts(tmp_path, cache_mb=0)) as st:
        g = st.level_grid(12)
        st.forbid_network_on(threading.get_ident())
        with pytest.raises(TileNotReady):
            st.has_data(12, g.x0 + 20, g.y0 + 20)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                assert st.has_data(12, g.x0 + 20, g.y0 + 20)
                break
            except TileNotReady:
                time.sleep(0.05)  # the parent shard first, then level 12's
        else:
            pytest.fail("the shard never arrived")
