"""Real `globeview` processes without the interpreter start: `run` and `popen` are
`subprocess.run` and `subprocess.Popen` for a ``globeview`` command line, served by a fork
server (`zygote_server`, one per test process, started at first use) that has already imported
numpy, rasterio, pyproj and globeview. Each command is still a process of its own: its own
argv, environment, working folder, stdin/stdout/stderr, exit status and signals (Ctrl-C,
kill -9), its stderr exactly what the user would see. What it saves is the 0.5-1 CPU-second
start (interpreter, imports) of every child.

Use it for tests about the process boundary (exit status, one line on stderr, nothing
half-written after a kill); tests about what a command prints call it in-process
(`inprocess_cli`), and the tests in `tests/cli/test_entry_points.py` start the real console
script and ``python -m globeview`` for every subcommand.

A command runs as a plain subprocess instead where forking cannot be the same process:
``GV_TEST_ZYGOTE=0`` (every command), an argv that is not the console script or ``python -m
globeview``, an environment that differs from this process's in a variable read at start-up
(anything but `_MAY_DIFFER`: PYTHONPATH, the locale, GDAL's and PROJ's settings, ...), or a
system without ``pidfd_open``.

CPU: a forked command's CPU is not in this process's RUSAGE_CHILDREN until the server ends;
`children_cpu` counts it (tests/cpu_durations.py adds it to each test's children).
"""

from __future__ import annotations

import atexit
import contextlib
import json
import locale
import os
import re
import select
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

SWITCH = "GV_TEST_ZYGOTE"
SERVER = Path(__file__).with_name("zygote_server.py")
CONSOLE_SCRIPT = Path(sys.executable).with_name("globeview")
START_TIMEOUT_S = 300.0  # wall seconds for its imports (~1.4 CPU-s) on a loaded machine
# Variables a command may see set differently from this process: each read when the command
# runs (globeview's settings, the test plugins' GVT_*, Qt's and the display's, the home and XDG
# folders, pytest's bookkeeping), never while the server imports; the three `globeview.cli.main`
# sets itself before its first GDAL or PROJ call (an in-process CLI test leaves them in this
# process's environment); the CA bundles rasterio and pyproj set when imported (the server
# imports both, which sets them to the same files); and PYTHONPATH where the server has none
# (the child puts its folders on sys.path as the interpreter's start would).
_MAY_DIFFER = re.compile(
    r"(GLOBEVIEW_\w+|GVT_\w+|DISPLAY|WAYLAND_DISPLAY|QT_QPA_PLATFORM|XDG_\w+|HOME|PYTEST_\w+"
    r"|COLUMNS|CPL_LOG|CPL_DEBUG|PROJ_DEBUG|GDAL_CURL_CA_BUNDLE|PROJ_CURL_CA_BUNDLE)"
)

_File = int | IO[Any] | None
#: This process's environment when the test session began (tests/conftest.py imports this
#: module first thing): the fork server starts with it whenever it is first used, not with
#: whatever a test had set then (an in-process `distributed` import sets OMP_NUM_THREADS,
#: ..., which `_environment_restored` undoes after that test: a server started inside it
#: then differed from every later test's environment).
_SESSION_ENV = dict(os.environ)
_cpu_s = 0.0
_warned: set[tuple[str, ...]] = set()


def children_cpu() -> float:
    """User+sys CPU seconds of the forked commands that have ended so far."""
    return _cpu_s


class _Server:
    """The fork server of this process: started once, ended at exit."""

    def __init__(self) -> None:
        self.folder = tempfile.mkdtemp(prefix="gv-zygote-")
        self.socket = os.path.join(self.folder, "s")
        self.env = dict(_SESSION_ENV)
        self.log = tempfile.TemporaryFile()  # noqa: SIM115  its stderr, for as long as it runs
        self.proc = subprocess.Popen(
            [sys.executable, str(SERVER), self.socket],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.log,
            env=self.env,
        )
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], START_TIMEOUT_S)
        line = self.proc.stdout.readline() if ready else b""
        self.log.seek(0)
        said = self.log.read().decode("utf-8", "replace")
        if line != b"ready\n" or said:
            self.close()
            raise RuntimeError(f"the globeview fork server did not start cleanly: {said}")
        atexit.register(self.close)

    def close(self) -> None:
        if self.proc.poll() is None:
            assert self.proc.stdin is not None
            self.proc.stdin.close()  # EOF: it kills what still runs and ends
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        with contextlib.suppress(OSError):
            os.unlink(self.socket)
            os.rmdir(self.folder)


_server: _Server | None = None


def close() -> None:
    """End this process's server (tests/conftest.py, when the session ends): its own CPU then
    counts among this process's children."""
    global _server
    if _server is not None:
        _server.close()
        _server = None


def _the_server() -> _Server:
    global _server
    if _server is None:
        _server = _Server()
    return _server


def _is_globeview(argv: Sequence[str]) -> bool:
    if not argv:
        return False
    if argv[0] == str(CONSOLE_SCRIPT):
        return True
    return len(argv) >= 3 and argv[0] == sys.executable and list(argv[1:3]) == ["-m", "globeview"]


def forkable(argv: Sequence[str], env: Mapping[str, str] | None) -> bool:
    """Whether the fork server can run ``argv`` in ``env`` as a fresh process would."""
    if os.environ.get(SWITCH, "1") == "0" or not hasattr(os, "pidfd_open"):
        return False
    if not _is_globeview(argv):
        return False
    base = _server.env if _server is not None else dict(os.environ)
    wanted = dict(os.environ if env is None else env)
    differ = {k for k in base.keys() | wanted.keys() if base.get(k) != wanted.get(k)}
    if "PYTHONPATH" not in base:
        differ.discard("PYTHONPATH")
    read_at_start = sorted(name for name in differ if not _MAY_DIFFER.fullmatch(name))
    if read_at_start and tuple(read_at_start) not in _warned:
        _warned.add(tuple(read_at_start))
        warnings.warn(
            f"zygote: `globeview` runs as a plain subprocess (slower): its environment differs "
            f"from the fork server's in {', '.join(read_at_start)}",
            stacklevel=3,
        )
    return not read_at_start


def _fd(target: _File, default: int, opened: list[int]) -> tuple[int, int | None]:
    """(the fd the child gets, the read end kept here for PIPE)."""
    if target is None:
        return default, None
    if target == subprocess.DEVNULL:
        fd = os.open(os.devnull, os.O_RDWR)
        opened.append(fd)
        return fd, None
    if target == subprocess.PIPE:
        r, w = os.pipe()
        opened.append(w)
        return w, r
    if isinstance(target, int):
        return target, None
    return target.fileno(), None


class ZygoteProcess:
    """A forked command, as `subprocess.Popen` offers it: ``pid``, ``returncode``,
    ``stdout``/``stderr`` (for PIPE), `poll`, `wait`, `communicate`, `send_signal`, `kill`."""

    def __init__(
        self, args: list[str], conn: socket.socket, pid: int, pipes: list[int | None], text: bool
    ) -> None:
        self.args = args
        self._text = text
        self.pid = pid
        self.returncode: int | None = None
        self._conn = conn
        self._reply = b""
        try:
            self._pidfd: int | None = os.pidfd_open(pid)  # signals never reach a reused pid
        except ProcessLookupError:
            self._pidfd = None
        out, err = pipes
        self.stdout = open(out, "rb") if out is not None else None  # noqa: SIM115
        self.stderr = open(err, "rb") if err is not None else None  # noqa: SIM115

    def _status(self, timeout: float | None) -> int | None:
        while b"\n" not in self._reply:
            ready, _, _ = select.select([self._conn], [], [], timeout)
            if not ready:
                return None
            chunk = self._conn.recv(4096)
            if not chunk:
                raise RuntimeError("the globeview fork server went away")
            self._reply += chunk
        global _cpu_s
        message = json.loads(self._reply)
        _cpu_s += message["cpu_s"]
        self.returncode = os.waitstatus_to_exitcode(message["status"])
        self._conn.close()
        if self._pidfd is not None:
            os.close(self._pidfd)
            self._pidfd = None
        return self.returncode

    def poll(self) -> int | None:
        return self.returncode if self.returncode is not None else self._status(0)

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None and self._status(timeout) is None:
            raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        assert self.returncode is not None
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.returncode is None and self._pidfd is not None:
            with contextlib.suppress(ProcessLookupError):
                signal.pidfd_send_signal(self._pidfd, sig)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def communicate(self, timeout: float | None = None) -> tuple[Any, Any]:
        """Read the PIPEs to their end, then wait; raises `subprocess.TimeoutExpired`. Text
        (as `subprocess` decodes it) where the process was started with ``text=True``."""
        end = None if timeout is None else time.monotonic() + timeout
        keys = {f.fileno(): name for name, f in (("out", self.stdout), ("err", self.stderr)) if f}
        streams = {f.fileno(): f for f in (self.stdout, self.stderr) if f is not None}
        got: dict[str, bytes] = dict.fromkeys(keys.values(), b"")
        while streams:
            left = None if end is None else max(end - time.monotonic(), 0.0)
            ready, _, _ = select.select(list(streams), [], [], left)
            if not ready:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
            for fd in ready:
                chunk = os.read(fd, 65536)
                if chunk:
                    got[keys[fd]] += chunk
                else:
                    streams.pop(fd).close()
        self.wait(None if end is None else max(end - time.monotonic(), 0.0))
        out, err = got.get("out"), got.get("err")
        return (_text(out), _text(err)) if self._text else (out, err)

    def __enter__(self) -> ZygoteProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        for f in (self.stdout, self.stderr):
            if f is not None:
                f.close()
        self.wait()


def popen(
    argv: Sequence[str],
    *,
    cwd: str | Path | None = None,
    env: Mapping[str, str] | None = None,
    stdin: _File = None,
    stdout: _File = None,
    stderr: _File = None,
    text: bool = False,
) -> ZygoteProcess | subprocess.Popen[Any]:
    """`subprocess.Popen(argv, cwd=, env=, stdin=, stdout=, stderr=, text=)`, forked from the
    server where `forkable` (``text`` decodes what `communicate` returns)."""
    argv = [str(a) for a in argv]
    if not forkable(argv, env) or stdin == subprocess.PIPE:
        return subprocess.Popen(
            argv, cwd=cwd, env=env, stdin=stdin, stdout=stdout, stderr=stderr, text=text
        )
    server = _the_server()
    opened: list[int] = []
    try:
        fds = [
            _fd(stdin, 0, opened),
            _fd(stdout, 1, opened),
            _fd(stderr, 2, opened),
        ]
        request = {
            "argv": argv,
            "env": dict(os.environ if env is None else env),
            "cwd": os.path.abspath(cwd if cwd is not None else os.getcwd()),
            "sigint_ignored": signal.getsignal(signal.SIGINT) == signal.SIG_IGN,
        }
        body = json.dumps(request).encode()
        conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        conn.connect(server.socket)
        socket.send_fds(conn, [struct.pack("!I", len(body)) + body], [fd for fd, _ in fds])
    finally:
        for fd in opened:
            os.close(fd)
    reply = b""
    while b"\n" not in reply:
        chunk = conn.recv(4096)
        if not chunk:
            raise RuntimeError("the globeview fork server went away")
        reply += chunk
    line, rest = reply.split(b"\n", 1)
    message = json.loads(line)
    if "pid" not in message:
        raise RuntimeError(f"the globeview fork server refused: {message}")
    proc = ZygoteProcess(argv, conn, message["pid"], [fds[1][1], fds[2][1]], text)
    proc._reply = rest
    return proc


def _text(data: bytes | None) -> str | None:
    """As `subprocess` decodes with ``text=True``: the locale's encoding, universal newlines."""
    if data is None:
        return None
    text = data.decode(locale.getpreferredencoding(False))
    return text.replace("\r\n", "\n").replace("\r", "\n")


def run(
    argv: Sequence[str],
    *,
    cwd: str | Path | None = None,
    env: Mapping[str, str] | None = None,
    capture_output: bool = False,
    text: bool = False,
    timeout: float | None = None,
) -> subprocess.CompletedProcess[Any]:
    """`subprocess.run` for a ``globeview`` command line (``input``, ``check`` and redirections
    aside): on timeout the command is killed and `subprocess.TimeoutExpired` raised."""
    pipe = subprocess.PIPE if capture_output else None
    proc = popen(argv, cwd=cwd, env=env, stdout=pipe, stderr=pipe, text=text)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise
    assert proc.returncode is not None
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
