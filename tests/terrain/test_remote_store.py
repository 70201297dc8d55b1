"""Remote stores: the HTTP transport, its disk cache and tile stores opened by URL.

Every test talks to a real HTTP server on 127.0.0.1 (`globeview.bench.http_server`), with
its fault modes standing in for slow, dropping and failing servers. No mocks.
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from globeview.bench.http_server import StaticServer
from globeview.errors import StoreError
from globeview.terrain import remote
from globeview.terrain.http_cache import DiskCache
from globeview.terrain.remote import RemoteError, RemoteOptions, fetch, is_url

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
    for text in (
        "",
        "/tmp/store",
        "store",
        "file:///tmp/store",
        "ftp://host/store",
        "http://",
        "http:///path",
        "s3://bucket/store",
        "javascript:alert(1)",
        None,
        3,
    ):
        assert not is_url(text), text


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
    server.reset_log()
    assert _bytes(server, files, opts).read(0, 100) == blob[:100]
    assert len(server.requests("/blob.bin")) == 1
    entries[0].write_bytes(b"GVPG")  # truncated
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
