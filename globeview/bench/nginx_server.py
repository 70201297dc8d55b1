"""A real static web server for tests and benchmarks of remote stores: Debian's nginx.

`NginxServer(root).start()` runs ``nginx`` (``daemon off``, one worker) as a child process
with a configuration of its own in a temporary prefix (its pid file, error log, access log
and temp folders there, nothing under /etc or /var), listening on an unprivileged port of
127.0.0.1, serving the files under ``root`` as any static site would: GET and HEAD, single
and multiple ``Range`` requests answered 206 (nginx's default), keep-alive, ``Content-Length``
always. The store backend's client sees what it would see on the web.

``latency_ms`` > 0 answers every request that many milliseconds late (whole ms: a far
server's round trip; the loopback has none), with nginx's own means: the echo module of Debian's
``libnginx-mod-http-echo`` (``echo_sleep`` then ``echo_exec`` to the static handler), a
timer in nginx's event loop, so concurrent requests wait concurrently as on a real network.

The access log (one line a request: the end time and duration in seconds with millisecond
resolution, method, path, Range header, status, body bytes) is read back by `requests`;
`max_in_flight` is the most requests nginx was answering at once, from those intervals.
`stop()` ends nginx (also the context manager's exit) and removes the prefix.

`find_nginx` says whether nginx (and, for latency, its echo module) is installed: the tests
skip without it, or fail where ``GLOBEVIEW_REQUIRE_NGINX=1`` (./test) says it must be there;
scripts/bootstrap.sh installs both as root.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

__all__ = ["ECHO_MODULE", "NginxError", "NginxServer", "Served", "find_nginx"]

#: Where Debian's libnginx-mod-http-echo puts the echo module (``echo_sleep``).
ECHO_MODULE = Path("/usr/share/nginx/modules/ngx_http_echo_module.so")
_SEARCH = ("/usr/sbin/nginx", "/usr/local/sbin/nginx", "/usr/local/nginx/sbin/nginx")
#: Fields of an access log line (tab-separated, `_parse` reads them).
_LOG_FIELDS = "msec request_time request_method uri http_range status body_bytes_sent"
_LOG_FORMAT = "\\t".join(f"${name}" for name in _LOG_FIELDS.split())


class NginxError(Exception):
    """nginx is missing or would not start (one line)."""


@dataclass(frozen=True)
class Served:
    """One request from nginx's access log: ``start`` and ``end`` (seconds since the epoch,
    1 ms resolution), method, URL path (decoded), Range header (None if absent), status,
    body bytes sent."""

    start: float
    end: float
    method: str
    path: str
    range: str | None
    status: int
    sent: int


def find_nginx(latency: bool = False) -> str | None:
    """The nginx binary (PATH, then Debian's /usr/sbin), or None; with ``latency`` also None
    when the echo module is missing."""
    found = shutil.which("nginx") or next((p for p in _SEARCH if os.access(p, os.X_OK)), None)
    if found is None or (latency and not ECHO_MODULE.is_file()):
        return None
    return found


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _config(prefix: Path, root: Path, port: int, latency_ms: float) -> str:
    """nginx.conf for one server on 127.0.0.1:``port`` serving ``root``."""
    echo = f"load_module {ECHO_MODULE};\n" if latency_ms > 0 else ""
    # As root the workers would switch to nobody/www-data, who cannot read a 0700 temp folder.
    user = "user root root;\n" if os.geteuid() == 0 else ""
    if latency_ms > 0:
        where = (
            f"location / {{ echo_sleep {latency_ms / 1e3:.3f}; echo_exec @file; }}\n"
            "    location @file { }\n"
        )
    else:
        where = "location / { }\n"
    tmp = prefix / "tmp"
    temps = "".join(
        f"  {kind}_temp_path {tmp / kind};\n"
        for kind in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi")
    )
    return (
        f"{echo}{user}daemon off;\nworker_processes 1;\npid {prefix / 'nginx.pid'};\n"
        f"error_log {prefix / 'error.log'} warn;\n"
        "events { worker_connections 512; }\n"
        "http {\n"
        f"  log_format gv '{_LOG_FORMAT}';\n"
        f"  access_log {prefix / 'access.log'} gv;\n"
        f"{temps}"
        "  types { application/json json; text/xml vrt; image/tiff tif; }\n"
        "  default_type application/octet-stream;\n"
        "  keepalive_requests 100000;\n"
        "  server {\n"
        f"    listen 127.0.0.1:{port};\n"
        f"    root {root};\n"
        f"    {where}"
        "  }\n"
        "}\n"
    )


class NginxServer:
    """nginx serving ``root`` on 127.0.0.1 (see the module docstring).

    Attributes:
        root: the folder served.
        latency_ms: milliseconds each request is answered late (0: none).
        url: ``http://127.0.0.1:PORT`` once started (no trailing slash).
    """

    def __init__(self, root: str | Path, latency_ms: float = 0.0) -> None:
        if not 0.0 <= float(latency_ms) <= 60_000.0:
            raise NginxError(f"latency must be 0..60000 ms, got {latency_ms}")
        self.root = Path(root).resolve()
        self.latency_ms = float(round(latency_ms))  # echo_sleep takes whole milliseconds
        self.url = ""
        self._proc: subprocess.Popen[bytes] | None = None
        self._prefix: Path | None = None
        self._log_from = 0

    # -- lifetime ------------------------------------------------------------------------------

    def start(self, tries: int = 5) -> NginxServer:
        """Start nginx on a free port (another tries on a port taken meanwhile); returns self.
        Raises `NginxError` (one line) when nginx is missing or will not start."""
        binary = find_nginx(latency=self.latency_ms > 0)
        if binary is None:
            what = "nginx with its echo module" if self.latency_ms > 0 else "nginx"
            raise NginxError(
                f"{what} is not installed (Debian: apt-get install nginx libnginx-mod-http-echo)"
            )
        if not self.root.is_dir():
            raise NginxError(f"no such folder to serve: {self.root}")
        last = "no attempt"
        for _ in range(max(1, tries)):
            prefix = Path(tempfile.mkdtemp(prefix="gv-nginx-"))
            (prefix / "tmp").mkdir()
            port = _free_port()
            conf = prefix / "nginx.conf"
            conf.write_text(_config(prefix, self.root, port, self.latency_ms))
            proc = subprocess.Popen(
                [binary, "-p", str(prefix), "-c", str(conf), "-e", str(prefix / "error.log")],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
            )
            if _wait_listening(proc, port):
                self._proc, self._prefix = proc, prefix
                self.url = f"http://127.0.0.1:{port}"
                self._log_from = 0
                return self
            last = _why_not(proc, prefix)
            shutil.rmtree(prefix, ignore_errors=True)
        raise NginxError(f"nginx did not start: {last}")

    def stop(self) -> None:
        """Stop nginx (SIGTERM: fast shutdown, connections closed) and remove its prefix."""
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
        if proc is not None and proc.stderr is not None:
            proc.stderr.close()
        if self._prefix is not None:
            shutil.rmtree(self._prefix, ignore_errors=True)
            self._prefix = None

    def __enter__(self) -> NginxServer:
        return self.start() if self._proc is None else self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # -- the access log -------------------------------------------------------------------------

    def reset_log(self) -> None:
        """Forget the requests logged so far (`requests` reads what comes after)."""
        self._log_from = self._log_path().stat().st_size

    def requests(self, pattern: str = "*") -> list[Served]:
        """The requests answered since the last `reset_log` whose path matches ``pattern``
        (fnmatch), in the order nginx finished them."""
        with self._log_path().open("rb") as f:
            f.seek(self._log_from)
            text = f.read().decode("utf-8", "replace")
        out = []
        for line in text.splitlines():
            req = _parse(line)
            if req is not None and fnmatch.fnmatchcase(req.path, pattern):
                out.append(req)
        return out

    def wait_logged(self, n: int, timeout_s: float = 5.0) -> list[Served]:
        """`requests` once at least ``n`` are logged (or ``timeout_s`` passed): nginx writes a
        request's log line after sending its answer, so a client that has just read the answer
        may look before the line is there."""
        deadline = time.monotonic() + timeout_s
        reqs = self.requests()
        while len(reqs) < n and time.monotonic() < deadline:
            time.sleep(0.01)
            reqs = self.requests()
        return reqs

    def max_in_flight(self, pattern: str = "*") -> int:
        """The most requests matching ``pattern`` nginx was answering at once since the last
        `reset_log`, from the logged intervals (each shortened by 1 ms at both ends: the
        log's resolution, so back-to-back requests of one client do not count as two)."""
        events: list[tuple[float, int]] = []
        reqs = self.requests(pattern)
        for r in reqs:
            a, b = r.start + 0.001, r.end - 0.001
            if b > a:
                events += [(a, 1), (b, -1)]
        most, now = min(1, len(reqs)), 0  # a request shorter than 2 ms was one in flight
        for _, step in sorted(events):  # an end sorts before a start at the same time
            now += step
            most = max(most, now)
        return most

    def _log_path(self) -> Path:
        if self._prefix is None:
            raise NginxError("nginx is not running")
        return self._prefix / "access.log"


def _parse(line: str) -> Served | None:
    parts = line.split("\t")
    if len(parts) != 7:
        return None
    try:
        end, took = float(parts[0]), float(parts[1])
        status, sent = int(parts[5]), int(parts[6])
    except ValueError:
        return None
    rng = None if parts[4] in ("", "-") else parts[4]
    path = urllib.parse.unquote(parts[3])
    return Served(end - took, end, parts[2], path, rng, status, sent)


def _wait_listening(proc: subprocess.Popen[bytes], port: int, timeout_s: float = 10.0) -> bool:
    """Whether nginx accepts connections on ``port`` before it exits or ``timeout_s`` pass."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return False
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.2):
            return True
        time.sleep(0.02)
    proc.kill()
    proc.wait(timeout=10)
    return False


def _why_not(proc: subprocess.Popen[bytes], prefix: Path) -> str:
    """nginx's last error line (its stderr, else its error log)."""
    err = b""
    if proc.stderr is not None:
        with contextlib.suppress(OSError, ValueError):
            err = proc.stderr.read()
        proc.stderr.close()
    lines = err.decode("utf-8", "replace").strip().splitlines()
    if not lines:
        with contextlib.suppress(OSError):
            lines = (prefix / "error.log").read_text("utf-8", "replace").strip().splitlines()
    return lines[-1] if lines else f"exit status {proc.returncode}"
