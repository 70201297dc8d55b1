"""`globeview render URL` and `globeview info URL` (issue #18): stores served over HTTP by a
real server on 127.0.0.1 (`globeview.bench.http_server.StaticServer`, honouring Range, with
fault modes); URLs of the wrong form, closed ports, folders that are not stores and hostile
manifests are one line (exit 2) and write nothing."""

from __future__ import annotations

import os
import socket
import subprocess
from pathlib import Path

import pytest
import zygote

from globeview.terrain.store.schema import FORMAT_VERSION

from .run_cli import GLOBEVIEW, globeview, globeview_here, one_error_line


def closed_port() -> int:
    """A local TCP port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
@pytest.mark.parametrize("command", ["render", "info"])
@pytest.mark.parametrize(
    ("url", "needle"),
    [
        ("file:///tmp/store", "file:// URLs are not supported"),
        ("ftp://127.0.0.1/store", "ftp:// URLs are not supported"),
        ("https://my host/store", "no valid host"),
        ("https://127.0.0.1:99999/store", "bad port"),
        ("https://127.0.0.1/store?x=1", "no ?query"),
    ],
)
def test_urls_of_the_wrong_form_are_one_line(tmp_path: Path, command: str, url: str, needle):
    # In this process (`inprocess_cli`): the URL is refused before any request or GL context.
    out = tmp_path / "x.png"
    extra = ["--out", str(out)] if command == "render" else []
    res = globeview_here(command, url, *extra, cache=tmp_path / "c")
    assert needle in one_error_line(res)
    assert not out.exists()


DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A folder served on 127.0.0.1 holding the Vancouver store twice ("store" and
    "a store", a name with a space), a folder that is not a store and one whose
    manifest.json (sparse) is one byte over the most a client reads by default
    (`RemoteOptions.max_manifest_mb`, 64 MB): the test server reads and sends whatever it
    serves, ~2.5 CPU-s a request for the 1 GB file this was before."""
    import shutil

    from globeview.bench.http_server import StaticServer
    from globeview.terrain.ingest.driver import ingest
    from globeview.terrain.store.http_fetch import RemoteOptions

    root = tmp_path_factory.mktemp("www")
    ingest([DATA / "topobathy_vancouver.tif"], root / "store")
    shutil.copytree(root / "store", root / "a store")
    (root / "notstore").mkdir()
    (root / "notstore" / "readme.txt").write_text("hello")
    (root / "huge").mkdir()
    with open(root / "huge" / "manifest.json", "wb") as f:
        f.truncate(int(RemoteOptions.max_manifest_mb * (1 << 20)) + 1)
    with StaticServer(root) as server:
        yield server, root


@pytest.mark.slow
def test_render_url_writes_the_local_stores_png(served, tmp_path: Path) -> None:
    server, root = served
    server.clear_faults()
    view = ["--size", "320x240", "--camera", "-123.2,49.2,60000,20,-50"]
    local = globeview("render", str(root / "store"), "-o", str(tmp_path / "l.png"), *view,
                      cache=tmp_path / "c1")  # fmt: skip
    remote = globeview("render", f"{server.url}/store", "-o", str(tmp_path / "r.png"), *view,
                       "--stats", str(tmp_path / "r.json"), cache=tmp_path / "c2")  # fmt: skip
    assert local.returncode == 0 and remote.returncode == 0, local.stderr + remote.stderr
    assert (tmp_path / "l.png").read_bytes() == (tmp_path / "r.png").read_bytes()
    assert server.requests("*/store/chunks/*"), "the tiles came over HTTP"
    # A name with a space, typed as is: sent percent-encoded, the same picture.
    spaced = globeview("render", f"{server.url}/a store", "-o", str(tmp_path / "s.png"), *view,
                       cache=tmp_path / "c3")  # fmt: skip
    assert spaced.returncode == 0, spaced.stderr
    assert (tmp_path / "s.png").read_bytes() == (tmp_path / "l.png").read_bytes()


@pytest.mark.slow
def test_info_url_describes_the_store(served, tmp_path: Path) -> None:
    import json

    server, root = served
    server.clear_faults()
    res = globeview("info", f"{server.url}/store", cache=tmp_path / "c")
    assert res.returncode == 0, res.stderr
    assert f"tile store, format {FORMAT_VERSION}" in res.stdout and "levels 0..7" in res.stdout
    res = globeview("info", "--json", f"{server.url}/store", str(root / "store"), cache=tmp_path)
    remote, local = json.loads(res.stdout)
    assert remote["store"] == f"{server.url}/store"
    # A folder's chunk files are checked (a stat each); a URL's only with --verify.
    assert remote["chunk_files_checked"] is None and local["chunk_files_checked"] > 0
    same = ("store", "chunk_files_checked")
    assert {k: v for k, v in remote.items() if k not in same} == {
        k: v for k, v in local.items() if k not in same
    }


@pytest.mark.parametrize("command", ["render", "info"])
@pytest.mark.parametrize(
    ("where", "needle"),
    [
        ("closed port", "connection refused"),
        ("notstore", "not a globeview tile store"),
        ("missing", "not a globeview tile store"),
        ("huge", "too large"),
    ],
)
@pytest.mark.slow
def test_unreadable_stores_are_one_line(served, tmp_path: Path, command, where, needle) -> None:
    server, _ = served
    server.clear_faults()
    url = (
        f"http://127.0.0.1:{closed_port()}/store"
        if where == "closed port"
        else (f"{server.url}/{where}")
    )
    out = tmp_path / "x.png"
    extra = ["--out", str(out), "--size", "64x48"] if command == "render" else []
    res = globeview(command, url, *extra, cache=tmp_path / "c", timeout=120)
    assert needle in one_error_line(res)
    assert not out.exists()


@pytest.mark.slow
def test_tiles_a_server_fails_are_stood_in_and_counted(served, tmp_path: Path) -> None:
    """500s for the finest level's chunks: the picture is drawn from coarser tiles, the
    'wrote' line and the stats count the failed tiles; with --strict nothing is written."""
    import json

    server, _ = served
    server.clear_faults()
    server.fault("*/store/chunks/07/*", status=500)
    view = ["--size", "320x240", "--camera", "-123.2,49.2,60000,20,-50"]
    try:
        out, stats = tmp_path / "x.png", tmp_path / "x.json"
        res = globeview("render", f"{server.url}/store", "-o", str(out), "--stats", str(stats),
                        *view, cache=tmp_path / "c", timeout=180)  # fmt: skip
        assert res.returncode == 0, res.stderr
        assert "tiles could not be read (drawn from coarser ones)" in res.stdout
        figures = json.loads(stats.read_text())
        assert figures["tiles_failed"] > 0 and figures["tiles_standin"] > 0
        assert figures["tiles_drawn"] > 0 and figures["triangles"] > 0
        assert out.exists()
        strict = tmp_path / "strict.png"
        res = globeview("render", f"{server.url}/store", "-o", str(strict), "--strict",
                        *view, cache=tmp_path / "c", timeout=180)  # fmt: skip
        assert res.returncode == 3, res.stderr
        assert "tiles could not be read" in res.stderr and "nothing written" in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1
        assert not strict.exists()
    finally:
        server.clear_faults()


@pytest.mark.slow
def test_a_server_failing_every_chunk_is_one_line_and_writes_nothing(served, tmp_path):
    """Every chunk answers 503 (the manifest still arrives): not one tile can be drawn, so
    the render is an error naming the first failure, not an empty globe with exit 0."""
    server, _ = served
    server.clear_faults()
    server.fault("*/store/chunks/*", status=503)
    try:
        out = tmp_path / "x.png"
        res = globeview("render", f"{server.url}/store", "-o", str(out), "--size", "64x48",
                        cache=tmp_path / "c", timeout=180)  # fmt: skip
        line = one_error_line(res)
        assert "no tile of http" in line and "could be read" in line
        assert "503" in line and "nothing written" in line
        assert not out.exists()
    finally:
        server.clear_faults()


@pytest.mark.slow
def test_ctrl_c_during_a_remote_render_is_one_line_and_quick(served, tmp_path: Path) -> None:
    import signal
    import time

    server, _ = served
    server.clear_faults()
    server.reset_log()  # the requests of this render only
    server.fault("*/store/chunks/*", delay_s=3.0)  # every chunk read waits
    try:
        out = tmp_path / "x.png"
        env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(tmp_path / "c")}
        env.pop("GLOBEVIEW_DEBUG", None)
        proc = zygote.popen(
            [str(GLOBEVIEW), "render", f"{server.url}/store", "-o", str(out)],
            stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
        )  # fmt: skip
        deadline = time.monotonic() + 60
        while not server.requests("*/store/chunks/*") and time.monotonic() < deadline:
            time.sleep(0.05)  # the render is waiting on a chunk now
        assert server.requests("*/store/chunks/*")
        proc.send_signal(signal.SIGINT)
        t0 = time.monotonic()
        _, err = proc.communicate(timeout=60)
        waited = time.monotonic() - t0
        assert proc.returncode == 130, err
        assert err.strip().splitlines() == ["globeview: interrupted"], err
        assert waited < 15, f"took {waited:.1f} s to stop after Ctrl-C"
        assert not out.exists()
    finally:
        server.clear_faults()
