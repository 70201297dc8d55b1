"""A static HTTP server for tests and benchmarks of remote stores, with fault modes.

`StaticServer(root).start()` serves the files under ``root`` on ``127.0.0.1`` (an ephemeral
port) from a background thread, as any static server would serve a store: GET and HEAD,
single-range ``Range: bytes=a-b`` / ``a-`` / ``-n`` requests answered 206 with
``Content-Range`` (416 past the end; a multi-range request gets the whole file, 200, as RFC
9110 allows), HTTP/1.1 keep-alive, ``Content-Length`` always. Nothing outside ``root`` is
served (``..`` and symlinks out are 404).

Faults are set per path with `StaticServer.fault` (an `fnmatch` pattern on the URL path, e.g.
``"*/chunks/03/*"``; the last matching rule wins) and cleared with `clear_faults`:

- ``delay_s``: sleep before the status line (a slow server);
- ``stall_s``: send half the body, then sleep (slow *within* the body);
- ``drop``: send the headers and half the body, then close the connection;
- ``status``: answer this status (404, 500, 429, ...) with a short body;
- ``flaky``: the first k matching requests are dropped (connection closed, no response),
  later ones are served;
- ``short``: announce the full Content-Length but send only half the body, then close;
- ``ignore_range``: answer 200 with the whole file even to a Range request;
- ``redirect``: answer 302 to ``redirect + path`` (another server's base URL);
- ``length``: announce this Content-Length (e.g. a huge one) whatever the body is;
- ``headers``: extra response headers (e.g. ``{"Content-Encoding": "gzip"}``).

Every request is logged (`log`: `Request` records with path, Range header, status) and
`max_in_flight` is the most requests the server was answering at once. With ``certfile``
and ``keyfile`` (PEM) it serves HTTPS instead. `stop()` shuts it
down (also the context manager's exit). Used by tests/terrain/test_remote_store.py, the
window's tests and benchmarks/bench_remote.py.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import re
import socket
import ssl
import sys
import threading
import time
import urllib.parse
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import TracebackType

__all__ = ["Fault", "Request", "StaticServer"]

_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


@dataclass
class Fault:
    """What the server does wrong for the paths of one rule (see the module docstring)."""

    delay_s: float = 0.0
    stall_s: float = 0.0
    drop: bool = False
    status: int | None = None
    flaky: int = 0
    short: bool = False
    ignore_range: bool = False
    redirect: str | None = None
    length: int | None = None
    headers: dict[str, str] | None = None
    # Requests this rule has failed so far (for ``flaky``).
    failed: int = field(default=0, compare=False)


@dataclass(frozen=True)
class Request:
    """One logged request: method, URL path, Range header (None if absent), status sent
    (0 = connection closed without a response)."""

    method: str
    path: str
    range: str | None
    status: int


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server: _Server

    def setup(self) -> None:
        super().setup()
        self.server.owner._connection(self.connection, True)

    def finish(self) -> None:
        self.server.owner._connection(self.connection, False)
        super().finish()

    def log_message(self, format: str, *args: object) -> None:
        pass  # quiet: the log is `StaticServer.log`

    def do_HEAD(self) -> None:
        self._serve(body=False)

    def do_GET(self) -> None:
        self._serve(body=True)

    def _serve(self, body: bool) -> None:
        owner = self.server.owner
        owner._enter()
        try:
            self._answer(owner, body)
        except (BrokenPipeError, ConnectionResetError):
            self.close_connection = True
        finally:
            owner._leave()

    def _answer(self, owner: StaticServer, body: bool) -> None:
        path = urllib.parse.unquote(urllib.parse.urlsplit(self.path).path)
        rng = self.headers.get("Range")
        fault = owner._fault_for(path)

        def log(status: int) -> None:
            owner._log(Request(self.command, path, rng, status))

        if fault is not None and fault.delay_s:
            time.sleep(fault.delay_s)
        if fault is not None and fault.flaky and owner._take_flaky(fault):
            log(0)
            self.close_connection = True
            return
        if fault is not None and fault.redirect:
            log(302)
            self.send_response(302)
            self.send_header("Location", fault.redirect.rstrip("/") + path)
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        if fault is not None and fault.status:
            log(fault.status)
            self._plain(fault.status, f"fault {fault.status}\n".encode())
            return
        file = owner._resolve(path)
        if file is None:
            log(404)
            self._plain(404, b"not found\n")
            return
        try:
            size = file.stat().st_size
        except OSError:
            log(404)
            self._plain(404, b"not found\n")
            return
        status, start, end = 200, 0, size
        m = _RANGE.match(rng.strip()) if rng else None
        if m and not (fault is not None and fault.ignore_range) and (m.group(1) or m.group(2)):
            a, b = m.group(1), m.group(2)
            if a:
                start, end = int(a), size if not b else min(int(b) + 1, size)
            else:
                start, end = max(0, size - int(b)), size
            if start >= size or end <= start:
                log(416)
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{size}")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            status = 206
        try:  # only the bytes asked for, as a static server would (not the whole file)
            with file.open("rb") as f:
                f.seek(start)
                part = f.read(end - start)
        except OSError:
            log(500)
            self._plain(500, b"cannot read\n")
            return
        log(status)
        self.send_response(status)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Accept-Ranges", "bytes")
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{end - 1}/{size}")
        length = fault.length if fault is not None and fault.length is not None else len(part)
        self.send_header("Content-Length", str(length))
        for name, value in (fault.headers or {}).items() if fault is not None else ():
            self.send_header(name, value)
        self.end_headers()
        if not body:
            return
        half = len(part) // 2
        if fault is not None and (fault.drop or fault.short):
            self.wfile.write(part[:half])
            self.wfile.flush()
            self.close_connection = True
            return
        if fault is not None and fault.stall_s:
            self.wfile.write(part[:half])
            self.wfile.flush()
            time.sleep(fault.stall_s)
            self.wfile.write(part[half:])
            return
        self.wfile.write(part)
        if fault is not None and fault.length is not None and fault.length != len(part):
            self.close_connection = True

    def _plain(self, status: int, text: bytes) -> None:
        self.send_response(status)
        self.send_header("Content-Type", "text/plain")
        self.send_header("Content-Length", str(len(text)))
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(text)


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    owner: StaticServer

    def handle_error(self, request: object, client_address: object) -> None:
        """A client closing its connection (a timeout, a dropped read) is no server error."""
        exc = sys.exc_info()[1]
        if not isinstance(exc, ConnectionError | TimeoutError):
            super().handle_error(request, client_address)  # type: ignore[arg-type]


class StaticServer:
    """Serve ``root`` over HTTP on 127.0.0.1 in a background thread (see the module docstring).

    Attributes:
        root: the folder served.
        url: ``http://127.0.0.1:PORT`` once started (no trailing slash).
        log: the requests answered so far (`Request`), in arrival order.
        max_in_flight: the most requests answered at once since the last `reset_log`.
    """

    def __init__(
        self,
        root: str | Path,
        certfile: str | Path | None = None,
        keyfile: str | Path | None = None,
    ) -> None:
        self.root = Path(root).resolve()
        self._tls = (certfile, keyfile) if certfile is not None else None
        self.url = ""
        self.log: list[Request] = []
        self.max_in_flight = 0
        self._in_flight = 0
        self._rules: list[tuple[str, Fault]] = []
        self._lock = threading.Lock()
        self._httpd: _Server | None = None
        self._conns: set[socket.socket] = set()
        self._thread: threading.Thread | None = None

    # -- lifetime ------------------------------------------------------------------------------

    def start(self) -> StaticServer:
        """Bind 127.0.0.1 on an ephemeral port and serve in a daemon thread; returns self."""
        httpd = _Server(("127.0.0.1", 0), _Handler)
        httpd.owner = self
        scheme = "http"
        if self._tls is not None:
            ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
            ctx.load_cert_chain(*self._tls)
            httpd.socket = ctx.wrap_socket(httpd.socket, server_side=True)
            scheme = "https"
        self._httpd = httpd
        self.url = f"{scheme}://127.0.0.1:{httpd.server_address[1]}"
        self._thread = threading.Thread(
            target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving: close the listening socket and every open (keep-alive) connection,
        as a server that went away would."""
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._httpd = None
        with self._lock:
            conns = list(self._conns)
        for sock in conns:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None

    def __enter__(self) -> StaticServer:
        return self.start() if self._httpd is None else self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # -- faults and the log ----------------------------------------------------------------------

    def fault(self, pattern: str, **kwargs: object) -> Fault:
        """Add a fault rule for URL paths matching ``pattern`` (fnmatch); keyword arguments
        are `Fault`'s fields. Returns the rule (its ``failed`` counts flaky failures)."""
        rule = Fault(**kwargs)  # type: ignore[arg-type]
        with self._lock:
            self._rules.append((pattern, rule))
        return rule

    def clear_faults(self) -> None:
        """Remove every fault rule."""
        with self._lock:
            self._rules.clear()

    def reset_log(self) -> None:
        """Forget the logged requests and the in-flight maximum."""
        with self._lock:
            self.log = []
            self.max_in_flight = self._in_flight

    def requests(self, pattern: str = "*") -> list[Request]:
        """The logged requests whose path matches ``pattern`` (fnmatch)."""
        with self._lock:
            return [r for r in self.log if fnmatch.fnmatchcase(r.path, pattern)]

    # -- for the handler ---------------------------------------------------------------------------

    def _fault_for(self, path: str) -> Fault | None:
        with self._lock:
            hit = None
            for pattern, rule in self._rules:
                if fnmatch.fnmatchcase(path, pattern):
                    hit = rule
            return hit

    def _take_flaky(self, rule: Fault) -> bool:
        with self._lock:
            if rule.failed < rule.flaky:
                rule.failed += 1
                return True
            return False

    def _resolve(self, path: str) -> Path | None:
        """The file for a URL path, or None (absent, a folder, or outside the root)."""
        rel = path.lstrip("/")
        try:
            file = (self.root / rel).resolve()
        except (OSError, ValueError):
            return None
        if file != self.root and self.root not in file.parents:
            return None
        return file if file.is_file() and os.access(file, os.R_OK) else None

    def _connection(self, sock: socket.socket, on: bool) -> None:
        with self._lock:
            if on:
                self._conns.add(sock)
            else:
                self._conns.discard(sock)

    def _enter(self) -> None:
        with self._lock:
            self._in_flight += 1
            self.max_in_flight = max(self.max_in_flight, self._in_flight)

    def _leave(self) -> None:
        with self._lock:
            self._in_flight -= 1

    def _log(self, req: Request) -> None:
        with self._lock:
            self.log.append(req)
