"""HTTP GETs for remote stores: one request with redirects, retries, timeouts and a
process-wide bound on requests in flight; and the options of remote stores (`RemoteOptions`).

- `fetch` GETs a URL (a byte range, or the whole answer up to a limit). Attempts are
  retried after a connection error, a timeout (connect, status line, or a body that stalls:
  a per-attempt deadline is checked between reads), HTTP 5xx, 408 or 429, with exponential
  backoff (a server's Retry-After honoured up to `MAX_BACKOFF_S`); never after 404 or
  another 4xx. Failure is one `RemoteError` line naming the URL and the HTTP status.
- Hostile answers are bounded: a Content-Length beyond what was asked is refused before the
  body is read, a body shorter than announced is a failed attempt, a 200 to a range request
  is taken whole only up to `WHOLE_FILE_LIMIT`, redirects go to http(s) only and at most
  `MAX_REDIRECTS` deep.
- `GATE` holds at most `RemoteOptions.max_requests` requests in flight in the process.
- Connections are kept alive and reused (a few idle ones per host).

Standard library only (http.client): every knob is ours and testable against a local
server (`globeview.bench.http_server`). Units: bytes, seconds.
"""

from __future__ import annotations

import base64
import contextlib
import http.client
import re
import socket
import ssl
import threading
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

from globeview.errors import StoreError
from globeview.paths import cache_dir
from globeview.terrain.store.http_cache import DiskCache

__all__ = [
    "GATE",
    "MAX_BACKOFF_S",
    "MAX_REDIRECTS",
    "WHOLE_FILE_LIMIT",
    "Cancel",
    "RemoteError",
    "RemoteOptions",
    "fetch",
    "is_url",
    "looks_like_url",
]

#: Redirects followed per request (301/302/303/307/308, to http or https only).
MAX_REDIRECTS = 5
#: The largest whole file taken from a server that answers a range request with 200 (bytes).
WHOLE_FILE_LIMIT = 64 << 20
_RETRY_STATUS = frozenset({408, 429, 500, 502, 503, 504})
_REDIRECT_STATUS = frozenset({301, 302, 303, 307, 308})
_CONTENT_RANGE = re.compile(r"^bytes (\d+)-(\d+)/(\d+|\*)$")
_READ_PIECE = 256 << 10
#: Backoff between attempts doubles from `RemoteOptions.backoff_s` up to this (seconds).
MAX_BACKOFF_S = 4.0


def looks_like_url(text: object) -> bool:
    """Whether ``text`` is meant as a URL of a remote store: it starts with ``http://`` or
    ``https://`` (any case). `is_url` then says whether it is a usable one."""
    return isinstance(text, str) and text.strip()[:8].lower().startswith(("http://", "https://"))


def is_url(text: object) -> bool:
    """Whether ``text`` names a remote store: an ``http://`` or ``https://`` URL (any case)
    with a host, a valid port and no whitespace or control characters. Anything else (a path,
    ``file:``, ``ftp:``, ``http://`` alone) is not."""
    if not looks_like_url(text):
        return False
    assert isinstance(text, str)
    url = text.strip()
    if any(ord(c) <= 32 or ord(c) == 127 for c in url):
        return False  # urlsplit would silently drop a newline or a tab
    try:
        parts = urllib.parse.urlsplit(url)
        parts.port  # noqa: B018 - raises ValueError for a bad port
    except ValueError:
        return False
    return bool(parts.hostname)


class RemoteError(StoreError):
    """A remote read failed: ``url`` and the HTTP ``status`` (None for a connection error
    or timeout) are attributes; the message is one line naming both."""

    def __init__(self, message: str, url: str, status: int | None = None) -> None:
        super().__init__(message)
        self.url = url
        self.status = status


@dataclass(frozen=True)
class RemoteOptions:
    """Every knob of remote stores, with defaults (validated: a bad value is a StoreError).

    Attributes:
        cache_dir: the disk cache folder; None = ``globeview.paths.cache_dir() / "http"``.
        cache_mb: disk cache bound, MB (0 turns the disk cache off).
        max_requests: HTTP requests in flight at once, process-wide.
        connect_timeout_s: to open a connection, seconds.
        read_timeout_s: for one response (status line to the last body byte), seconds.
        retries: further attempts after a connection error, a timeout, 5xx, 408 or 429.
        backoff_s: the wait before the first retry; doubles each retry (at most 4 s; a
            server's Retry-After within that is honoured).
        page_kb: the unit of range requests and of the disk cache, KB.
        max_manifest_mb: the largest manifest read, MB (a bigger answer is refused).
        fail_fast_s: after a chunk file's read failed (its retries spent), further reads of
            it fail at once for this long, seconds (the other tiles of a chunk a server
            answers 500 for show as failed in seconds, not one retry round each).

    A tile read that cannot succeed fails within `worst_case_s`.
    """

    cache_dir: Path | None = None
    cache_mb: float = 1024.0
    max_requests: int = 8
    connect_timeout_s: float = 5.0
    read_timeout_s: float = 10.0
    retries: int = 3
    backoff_s: float = 0.25
    page_kb: int = 64
    max_manifest_mb: float = 64.0
    fail_fast_s: float = 10.0

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> StoreError:
            return StoreError(f"remote option {name}={getattr(self, name)!r}: {why}")

        def number(name: str, lo: float, hi: float) -> None:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not lo <= v <= hi:
                raise bad(name, f"must be a number from {lo:g} to {hi:g}")

        number("cache_mb", 0, 1 << 20)
        number("connect_timeout_s", 0.01, 600)
        number("read_timeout_s", 0.01, 3600)
        number("backoff_s", 0, 60)
        number("max_manifest_mb", 0.001, 1024)
        number("fail_fast_s", 0, 3600)
        for name, lo, hi in (("max_requests", 1, 256), ("retries", 0, 20), ("page_kb", 4, 4096)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise bad(name, f"must be an integer from {lo} to {hi}")
        if self.cache_dir is not None and not isinstance(self.cache_dir, str | Path):
            raise bad("cache_dir", "must be a folder path")

    @property
    def folder(self) -> Path:
        """The disk cache folder in use."""
        return Path(self.cache_dir) if self.cache_dir is not None else cache_dir() / "http"

    @property
    def page_bytes(self) -> int:
        return int(self.page_kb) * 1024

    @property
    def worst_case_s(self) -> float:
        """Upper bound (seconds) on one failing read: every attempt's connect and read
        timeouts plus the backoffs (time queued behind `max_requests` not counted)."""
        waits = sum(min(self.backoff_s * 2**i, MAX_BACKOFF_S) for i in range(self.retries))
        return (self.retries + 1) * (self.connect_timeout_s + self.read_timeout_s) + waits

    def cache(self) -> DiskCache:
        """The process's disk cache for these options."""
        return DiskCache.shared(self.folder, int(self.cache_mb * (1 << 20)))


class _Gate:
    """At most ``limit`` holders at once, process-wide (the limit of each acquirer's options:
    one process normally uses one `RemoteOptions`). `in_flight` / `max_seen` for tests."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self.in_flight = 0
        self.max_seen = 0

    def acquire(self, limit: int) -> None:
        with self._cond:
            while self.in_flight >= limit:
                self._cond.wait()
            self.in_flight += 1
            self.max_seen = max(self.max_seen, self.in_flight)

    def release(self) -> None:
        with self._cond:
            self.in_flight -= 1
            self._cond.notify()


GATE = _Gate()
_Conn = http.client.HTTPConnection
_idle: dict[tuple[str, str, int], list[_Conn]] = {}
_idle_lock = threading.Lock()
_MAX_IDLE = 16


def _take_conn(scheme: str, host: str, port: int, opts: RemoteOptions) -> tuple[_Conn, bool]:
    """An idle keep-alive connection to (scheme, host, port), or a new one; and whether it
    was reused (a reused one may have been closed by the server meanwhile)."""
    with _idle_lock:
        pool = _idle.get((scheme, host, port))
        if pool:
            return pool.pop(), True
    conn: _Conn
    if scheme == "https":
        conn = http.client.HTTPSConnection(
            host, port, timeout=opts.connect_timeout_s, context=ssl.create_default_context()
        )
    else:
        conn = http.client.HTTPConnection(host, port, timeout=opts.connect_timeout_s)
    return conn, False


def _give_conn(scheme: str, host: str, port: int, conn: _Conn) -> None:
    with _idle_lock:
        pool = _idle.setdefault((scheme, host, port), [])
        if len(pool) < _MAX_IDLE:
            pool.append(conn)
            return
    conn.close()


@dataclass
class _Answer:
    status: int
    body: bytes
    total: int | None = None  # the file's size (Content-Range, or a 200's length)
    start: int = 0  # the body's first byte in the file


class _Retry(Exception):
    """One attempt failed in a way worth another (connection, timeout, 5xx, 429)."""

    def __init__(self, why: str, status: int | None = None, after: float | None = None):
        super().__init__(why)
        self.why = why
        self.status = status
        self.after = after


def _short_url(url: str) -> str:
    """A URL for messages: a password in it masked, at most 200 characters."""
    parts = urllib.parse.urlsplit(url)
    if parts.password is not None:
        host = parts.netloc.rsplit("@", 1)[-1]
        url = urllib.parse.urlunsplit(parts._replace(netloc=f"{parts.username}:***@{host}"))
    return url if len(url) <= 200 else url[:197] + "..."


class Cancel:
    """Cancels the fetches that carry it: after `cancel`, they raise `RemoteError` at once,
    and requests under way end within milliseconds (their sockets are shut down, so a read
    blocked on a slow server returns). A closed store cancels its reads this way instead of
    waiting out the timeouts."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self._lock = threading.Lock()
        self._conns: set[_Conn] = set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def cancel(self) -> None:
        self._event.set()
        with self._lock:
            conns = list(self._conns)
        for conn in conns:
            sock = conn.sock
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)

    def sleep(self, seconds: float) -> None:
        """Sleep, waking early when cancelled."""
        self._event.wait(seconds)

    def watch(self, conn: _Conn, on: bool) -> None:
        with self._lock:
            if on:
                self._conns.add(conn)
            else:
                self._conns.discard(conn)


def fetch(
    url: str,
    opts: RemoteOptions,
    byte_range: tuple[int, int] | None = None,
    limit: int | None = None,
    cancel: Cancel | None = None,
) -> _Answer:
    """GET ``url`` (bytes [start, end) when ``byte_range`` is given), with redirects,
    retries and timeouts; the body is at most ``limit`` bytes (a range request: its length,
    or `WHOLE_FILE_LIMIT` when the server answers 200 with the whole file). ``cancel``: see
    `Cancel`.

    Returns the 200/206 answer; raises `RemoteError` (one line, URL and status) otherwise.
    """
    attempts = opts.retries + 1
    last: _Retry | None = None
    for attempt in range(attempts):
        if attempt:
            wait = min(opts.backoff_s * 2 ** (attempt - 1), MAX_BACKOFF_S)
            if last is not None and last.after is not None:
                wait = min(max(wait, last.after), MAX_BACKOFF_S)
            if cancel is not None:
                cancel.sleep(wait)
            else:
                time.sleep(wait)
        if cancel is not None and cancel.cancelled:
            raise RemoteError(f"GET {_short_url(url)}: cancelled (the store was closed)", url)
        try:
            return _follow(url, opts, byte_range, limit, cancel)
        except _Retry as exc:
            last = exc
    assert last is not None
    tries = f" ({attempts} attempts)" if attempts > 1 else ""
    raise RemoteError(f"GET {_short_url(url)}: {last.why}{tries}", url, last.status)


def _follow(
    url: str,
    opts: RemoteOptions,
    byte_range: tuple[int, int] | None,
    limit: int | None,
    cancel: Cancel | None,
) -> _Answer:
    """One attempt, following redirects."""
    for _ in range(MAX_REDIRECTS + 1):
        answer, location = _request(url, opts, byte_range, limit, cancel)
        if location is None:
            assert answer is not None
            return answer
        nxt = urllib.parse.urljoin(url, location)
        if not is_url(nxt):
            raise RemoteError(
                f"GET {_short_url(url)}: redirected to {_short_url(nxt)!r}, not http(s)", url
            )
        url = nxt
    raise RemoteError(f"GET {_short_url(url)}: more than {MAX_REDIRECTS} redirects", url)


def _request(
    url: str,
    opts: RemoteOptions,
    byte_range: tuple[int, int] | None,
    limit: int | None,
    cancel: Cancel | None = None,
) -> tuple[_Answer | None, str | None]:
    """One HTTP exchange: (answer, None) or (None, redirect location). Raises `_Retry` for
    what deserves another attempt and `RemoteError` for what does not."""
    parts = urllib.parse.urlsplit(url)
    scheme = parts.scheme.lower()
    host = parts.hostname or ""
    try:
        port = parts.port or (443 if scheme == "https" else 80)
    except ValueError:
        raise RemoteError(f"GET {_short_url(url)}: bad port", url) from None
    target = urllib.parse.urlunsplit(("", "", parts.path or "/", parts.query, ""))
    headers = {"User-Agent": "globeview", "Accept-Encoding": "identity"}
    if parts.username is not None:  # http://user:password@host/...: HTTP basic auth
        cred = (
            f"{urllib.parse.unquote(parts.username)}:{urllib.parse.unquote(parts.password or '')}"
        )
        headers["Authorization"] = "Basic " + base64.b64encode(cred.encode()).decode("ascii")
    if byte_range is not None:
        headers["Range"] = f"bytes={byte_range[0]}-{byte_range[1] - 1}"
    GATE.acquire(opts.max_requests)
    try:
        for fresh_try in range(2):
            conn, reused = _take_conn(scheme, host, port, opts)
            if cancel is not None:
                cancel.watch(conn, True)
            try:
                return _exchange(
                    url,
                    conn,
                    reused and not fresh_try,
                    target,
                    headers,
                    opts,
                    byte_range,
                    limit,
                    (scheme, host, port),
                )
            except _Stale:
                continue  # the server closed an idle keep-alive connection: a new one
            finally:
                if cancel is not None:
                    cancel.watch(conn, False)
        raise AssertionError("unreachable")
    finally:
        GATE.release()


class _Stale(Exception):
    """A reused keep-alive connection the server had closed (try a fresh one at once)."""


def _exchange(
    url: str,
    conn: _Conn,
    reused: bool,
    target: str,
    headers: dict[str, str],
    opts: RemoteOptions,
    byte_range: tuple[int, int] | None,
    limit: int | None,
    where: tuple[str, str, int],
) -> tuple[_Answer | None, str | None]:
    """One request on ``conn`` and its judged answer (the connection pooled or closed).
    Raises `_Stale` when a reused connection turns out closed by the server."""
    try:
        if conn.sock is None:
            conn.timeout = opts.connect_timeout_s
            conn.connect()
        assert conn.sock is not None
        conn.sock.settimeout(opts.read_timeout_s)
        deadline = time.monotonic() + opts.read_timeout_s
        conn.request("GET", target, headers=headers)
        resp = conn.getresponse()
    except (http.client.RemoteDisconnected, BrokenPipeError, ConnectionResetError) as exc:
        conn.close()
        if reused:
            raise _Stale() from None
        raise _Retry(_why(exc)) from None
    except ssl.SSLCertVerificationError as exc:
        conn.close()  # no retry: the certificate will not change in a second
        raise RemoteError(f"GET {_short_url(url)}: {_why(exc)}", url) from None
    except (OSError, http.client.HTTPException) as exc:
        conn.close()
        raise _Retry(_why(exc)) from None
    try:
        answer, location, keep = _answer(url, resp, byte_range, limit, deadline)
    except BaseException:
        conn.close()
        raise
    if keep and not resp.will_close:
        _give_conn(*where, conn)
    else:
        conn.close()
    return answer, location


def _why(exc: BaseException) -> str:
    """A short reason for a connection-level failure."""
    if isinstance(exc, socket.timeout | TimeoutError):
        return "timed out"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused"
    if isinstance(exc, http.client.IncompleteRead):
        return f"connection closed after {len(exc.partial)} of the bytes announced"
    if isinstance(exc, http.client.RemoteDisconnected | ConnectionResetError | BrokenPipeError):
        return "connection closed by the server"
    if isinstance(exc, socket.gaierror):
        return "host not found"
    if isinstance(exc, ssl.SSLError):
        return f"TLS error ({exc.reason or type(exc).__name__})"
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text[:120]


def _answer(
    url: str,
    resp: http.client.HTTPResponse,
    byte_range: tuple[int, int] | None,
    limit: int | None,
    deadline: float,
) -> tuple[_Answer | None, str | None, bool]:
    """Judge a response and read its body (bounded, before ``deadline``): (answer, redirect
    location, whether the connection can be reused)."""
    status = resp.status
    reason = (resp.reason or "").strip()[:40]
    if status in _REDIRECT_STATUS:
        location = resp.getheader("Location")
        if not location:
            raise RemoteError(f"GET {_short_url(url)}: HTTP {status} without a Location", url)
        return None, location, False
    if status in _RETRY_STATUS:
        after = resp.getheader("Retry-After")
        wait = float(after) if after and after.strip().isdigit() else None
        raise _Retry(f"HTTP {status} {reason}".rstrip(), status, wait)
    if status not in (200, 206):
        raise RemoteError(f"GET {_short_url(url)}: HTTP {status} {reason}".rstrip(), url, status)
    encoding = (resp.getheader("Content-Encoding") or "identity").strip().lower()
    if encoding != "identity":  # asked for identity: compressed bytes are not the file's
        raise RemoteError(
            f"GET {_short_url(url)}: the server sent a {encoding[:20]}-encoded answer (a range"
            " of the file's own bytes is needed)",
            url,
            status,
        )
    length_h = resp.getheader("Content-Length")
    try:
        length = int(length_h) if length_h is not None else None
    except ValueError:
        raise _Retry(f"bad Content-Length {str(length_h)[:20]!r}") from None
    if length is not None and length < 0:
        raise _Retry(f"bad Content-Length {length}")
    total: int | None = None
    start = 0
    if status == 206:
        if byte_range is None:
            raise RemoteError(f"GET {_short_url(url)}: HTTP 206 to a plain request", url, 206)
        m = _CONTENT_RANGE.match((resp.getheader("Content-Range") or "").strip())
        if m is None:
            raise RemoteError(f"GET {_short_url(url)}: HTTP 206 without a Content-Range", url)
        start, end = int(m.group(1)), int(m.group(2)) + 1
        total = int(m.group(3)) if m.group(3) != "*" else None
        want = byte_range[1] - byte_range[0]
        if start != byte_range[0] or end - start > want or end <= start:
            raise RemoteError(
                f"GET {_short_url(url)}: server sent bytes {start}-{end - 1} for "
                f"{byte_range[0]}-{byte_range[1] - 1}",
                url,
                206,
            )
        cap = end - start
    elif byte_range is not None:
        cap = WHOLE_FILE_LIMIT  # a server ignoring Range: the whole file, when small
    else:
        cap = limit if limit is not None else WHOLE_FILE_LIMIT
    if length is not None and length > cap:
        what = "a range" if status == 206 else "the file"
        raise RemoteError(
            f"GET {_short_url(url)}: {length} bytes announced for {what}, more than "
            f"{cap} (server {'ignores Range requests' if byte_range else 'answer too large'})",
            url,
            status,
        )
    body = _read_body(resp, length, cap, deadline, url)
    if status == 200:
        total = len(body)
    elif length is None and len(body) != cap:
        raise _Retry(f"connection closed after {len(body)} of {cap} bytes")
    return _Answer(status, body, total, start), None, length is not None


def _read_body(
    resp: http.client.HTTPResponse, length: int | None, cap: int, deadline: float, url: str
) -> bytes:
    """The body, at most ``cap`` bytes, read piecewise so that a stalled or trickling
    server cannot hold a read past ``deadline`` (the socket timeout bounds each recv)."""
    want = length if length is not None else cap + 1
    pieces: list[bytes] = []
    got = 0
    try:
        while got < want:
            if time.monotonic() > deadline:
                raise _Retry("timed out reading the body")
            piece = resp.read(min(_READ_PIECE, want - got))
            if not piece:
                break
            pieces.append(piece)
            got += len(piece)
    except (OSError, http.client.HTTPException) as exc:
        raise _Retry(_why(exc)) from None
    if length is not None and got < length:
        raise _Retry(f"connection closed after {got} of {length} bytes")
    if got > cap:
        raise RemoteError(f"GET {_short_url(url)}: answer larger than {cap} bytes", url)
    return b"".join(pieces)
