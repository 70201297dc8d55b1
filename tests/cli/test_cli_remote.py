"""`globeview render URL` and `globeview info URL` (issue #18): stores served over HTTP by a
real server on 127.0.0.1 (`globeview.bench.http_server.StaticServer`, honouring Range, with
fault modes); URLs of the wrong form, closed ports, folders that are not stores and hostile
manifests are one line (exit 2) and write nothing."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

GLOBEVIEW = Path(sys.executable).with_name("globeview")


def globeview(*args: str, cache: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(cache)}
    env.pop("GLOBEVIEW_DEBUG", None)
    return subprocess.run(
        [str(GLOBEVIEW), *args], capture_output=True, text=True, timeout=timeout, env=env
    )


def one_error_line(res: subprocess.CompletedProcess) -> str:
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("globeview: error: "), lines[0]
    assert "Traceback" not in res.stderr
    return lines[0]


def closed_port() -> int:
    """A local TCP port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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
    out = tmp_path / "x.png"
    extra = ["--out", str(out)] if command == "render" else []
    res = globeview(command, url, *extra, cache=tmp_path / "c")
    assert needle in one_error_line(res)
    assert not out.exists()
