"""The pre-warmed fork server behind `zygote` (run as a script: ``python zygote_server.py
SOCKET``; the tests use `zygote`, not this file).

It imports what a `globeview` command imports (numpy, rasterio, pyproj, PIL and every
`globeview` module but the window's), starts no thread and loads no GL or Qt library, then
waits on the Unix socket SOCKET. Each connection is one command: a length-prefixed JSON request
(argv, env, cwd) with three file descriptors (stdin, stdout, stderr) passed alongside. The
server forks a child that becomes that command's process (its fds, environment, working folder,
``sys.argv``, signal handlers and warning filters as a fresh interpreter has them) and runs the
console script or ``-m globeview`` exactly as Python would, so its exit status, its stderr, an
uncaught Ctrl-C and a kill -9 are a real process's. The server answers ``{"pid": N}`` at once
and ``{"status": S, "cpu_s": C}`` (the raw wait status and the child's user+sys CPU seconds,
its waited-for children included) when the child ends. EOF on the server's stdin (the test
process is gone) kills any child still running and ends the server.
"""

from __future__ import annotations

import contextlib
import json
import os
import selectors
import signal
import socket
import struct
import sys
from dataclasses import dataclass
from typing import Any

# Modules outside globeview that the commands load, some only when they run (rasterio's
# submodules, dask for an ingest, PyWavelets, the GIF writer, the plugin metadata reader).
_HEAVY = (
    "numpy",
    "numpy.fft",
    "numpy.ma",
    "rasterio",
    "rasterio.warp",
    "rasterio.windows",
    "rasterio.features",
    "rasterio.vrt",
    "pyproj",
    "PIL.Image",
    "PIL.PngImagePlugin",
    "PIL.GifImagePlugin",
    "dask",
    "dask.callbacks",
    "dask.local",
    "dask.multiprocessing",
    "dask.threaded",
    "pywt",
    "psutil",
    "importlib_metadata",
    "packaging.version",
    "yaml",
    "lazy_importer",
    "multiprocessing.pool",
)
# Never imported here: the window (Qt), and nothing that loads a GL library (checked after).
_SKIP = ("globeview.ui", "globeview.__main__")
_FORBIDDEN_LIBS = ("libEGL", "libGL", "libQt6", "libgbm", "libLLVM")


@dataclass
class Request:
    """One command: ``argv`` (the console script's path or ``python -m globeview``, then its
    arguments), ``env`` (the whole environment), ``cwd``, the three fds to become 0, 1, 2, and
    whether the test process ignores SIGINT (a child started from it would inherit that)."""

    argv: list[str]
    env: dict[str, str]
    cwd: str
    fds: list[int]
    sigint_ignored: bool = False


def _import_tree(package: str) -> None:
    import importlib
    import pkgutil

    module = importlib.import_module(package)
    for info in pkgutil.iter_modules(getattr(module, "__path__", []), package + "."):
        if info.name.startswith(_SKIP):
            continue
        try:
            if info.ispkg:
                _import_tree(info.name)
            else:
                importlib.import_module(info.name)
        except Exception:  # noqa: BLE001  the child imports it again and meets the same error
            continue


def preload() -> None:
    """Import the commands' modules; refuse (exit 3) if that started a Python thread or mapped
    a GL or Qt library, which a fork would lose or share."""
    import importlib
    import threading

    for name in _HEAVY:
        importlib.import_module(name)
    _import_tree("globeview")
    if threading.active_count() != 1:
        sys.exit(f"zygote: importing started threads: {threading.enumerate()}")
    with open("/proc/self/maps", encoding="utf-8") as f:
        mapped = [line for line in f if any(lib in line for lib in _FORBIDDEN_LIBS)]
    if mapped:
        sys.exit(f"zygote: importing mapped a GL or Qt library: {mapped[0].split()[-1]}")


def _read_request(conn: socket.socket) -> Request:
    data, fds, _flags, _addr = socket.recv_fds(conn, 65536, 3)
    if len(data) < 4 or len(fds) != 3:
        raise OSError("zygote: malformed request")
    (size,) = struct.unpack("!I", data[:4])
    body = data[4:]
    while len(body) < size:
        chunk = conn.recv(size - len(body))
        if not chunk:
            raise OSError("zygote: request cut short")
        body += chunk
    fields = json.loads(body)
    return Request(
        fields["argv"], fields["env"], fields["cwd"], list(fds), bool(fields["sigint_ignored"])
    )


def _send(conn: socket.socket, message: dict[str, Any]) -> None:
    with contextlib.suppress(OSError):  # the test gave up on this child: nothing to tell
        conn.sendall(json.dumps(message).encode() + b"\n")


class Server:
    """Accepts commands, forks a child per command, reports each child's end."""

    def __init__(self, path: str) -> None:
        self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.listener.bind(path)
        self.listener.listen(64)
        self.selector = selectors.DefaultSelector()
        self.selector.register(self.listener, selectors.EVENT_READ, "accept")
        self.selector.register(sys.stdin.fileno(), selectors.EVENT_READ, "stdin")
        # pidfd -> (pid, the connection to answer)
        self.children: dict[int, tuple[int, socket.socket]] = {}

    def serve(self) -> Request | None:
        """Serve until the test process goes (returns None), or, in a forked child, return
        the child's request."""
        while True:
            for key, _ in self.selector.select():
                if key.data == "stdin":
                    self._stop()
                    return None
                if key.data == "accept":
                    request = self._fork()
                    if request is not None:
                        return request
                else:
                    self._reap(key.fd)

    def _fork(self) -> Request | None:
        conn, _ = self.listener.accept()
        try:
            request = _read_request(conn)
        except (OSError, ValueError, KeyError) as exc:
            _send(conn, {"error": str(exc)})
            conn.close()
            return None
        pid = os.fork()
        if pid == 0:
            self._close_in_child(conn)
            return request
        for fd in request.fds:
            os.close(fd)
        pidfd = os.pidfd_open(pid)
        self.children[pidfd] = (pid, conn)
        self.selector.register(pidfd, selectors.EVENT_READ, "child")
        _send(conn, {"pid": pid})
        return None

    def _reap(self, pidfd: int) -> None:
        pid, conn = self.children.pop(pidfd)
        self.selector.unregister(pidfd)
        os.close(pidfd)
        _, status, usage = os.wait4(pid, 0)
        _send(conn, {"status": status, "cpu_s": usage.ru_utime + usage.ru_stime})
        conn.close()

    def _close_in_child(self, conn: socket.socket) -> None:
        self.selector.close()
        self.listener.close()
        conn.close()
        for pidfd, (_pid, other) in self.children.items():
            os.close(pidfd)
            other.close()
        self.children.clear()

    def _stop(self) -> None:
        for pidfd, (pid, conn) in list(self.children.items()):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            self._reap(pidfd)
            conn.close()


def become(request: Request, warning_filters: list[Any], root_handlers: list[Any]) -> None:
    """Make this forked process the fresh interpreter ``request`` asks for."""
    import logging
    import tempfile
    import warnings

    for target, fd in enumerate(request.fds):
        os.dup2(fd, target)
        os.close(fd)
    os.chdir(request.cwd)
    _python_path(request.env.get("PYTHONPATH"))
    os.environ.clear()
    os.environ.update(request.env)
    sys.stdin = _stream(0, sys.stdin)
    sys.stdout = _stream(1, sys.stdout)
    sys.stderr = _stream(2, sys.stderr)
    sys.__stdin__, sys.__stdout__, sys.__stderr__ = sys.stdin, sys.stdout, sys.stderr  # type: ignore[misc]
    # A fresh interpreter installs Python's handler, unless it started with SIGINT ignored (a
    # background job of a shell): an ignored signal stays ignored across exec.
    ignored = request.sigint_ignored
    signal.signal(signal.SIGINT, signal.SIG_IGN if ignored else signal.default_int_handler)
    warnings.filters[:] = warning_filters  # type: ignore[index]
    warnings._filters_mutated()  # type: ignore[attr-defined]
    logging.getLogger().handlers[:] = root_handlers
    tempfile.tempdir = None  # chosen again from this environment's TMPDIR
    mp_process = sys.modules.get("multiprocessing.process")
    if mp_process is not None:
        mp_process.ORIGINAL_DIR = request.cwd  # type: ignore[attr-defined]


def _python_path(value: str | None) -> None:
    """Put PYTHONPATH's folders where the interpreter's start puts them (after the script's
    folder, each made absolute, an empty entry the working folder). The client forks only where
    the server started without one. A folder providing a module this server has imported from
    elsewhere would shadow it in a fresh process, not here: that ends the command (exit 3)."""
    import importlib

    if not value:
        return
    entries = [os.path.abspath(p) for p in value.split(os.pathsep)]
    for entry in entries:
        clash = _shadowed(entry)
        if clash:
            sys.stderr.write(f"zygote: {clash} would shadow a loaded module; GV_TEST_ZYGOTE=0\n")
            os._exit(3)
    sys.path[1:1] = entries
    importlib.invalidate_caches()


def _shadowed(entry: str) -> str | None:
    """A path in folder ``entry`` that provides a module already loaded from another place."""
    names = os.listdir(entry) if os.path.isdir(entry) else []
    for name in names:
        module = sys.modules.get(name.split(".")[0])
        if module is None or name.endswith((".dist-info", ".egg-info", ".pth")):
            continue
        path = os.path.join(entry, name)
        loaded = [*getattr(module, "__path__", []), getattr(module, "__file__", None)]
        if path not in loaded:
            return path
    return None


def _stream(fd: int, like: Any) -> Any:
    """A text stream on ``fd`` as Python's startup (create_stdio) makes one: ``like``'s
    encoding and errors (the same locale), unbuffered under ``python -u``, else line-buffered
    on a terminal and for stderr."""
    import io

    write = fd != 0
    unbuffered = write and isinstance(like.buffer, io.FileIO)  # python -u, PYTHONUNBUFFERED
    mode = "wb" if write else "rb"
    buffer = open(fd, mode, buffering=0 if unbuffered else -1, closefd=False)  # noqa: SIM115
    return io.TextIOWrapper(
        buffer,
        encoding=like.encoding,
        errors=like.errors,
        newline="\n",
        line_buffering=not unbuffered and (os.isatty(fd) or fd == 2),
        write_through=unbuffered,
    )


def run_command(request: Request) -> None:
    """Run the command as Python runs a console script or ``-m globeview``: SystemExit,
    an uncaught exception or Ctrl-C leave this function as they would leave `__main__`."""
    import runpy

    argv = request.argv
    if len(argv) >= 3 and argv[1:3] == ["-m", "globeview"]:
        sys.argv = ["-m", *argv[3:]]
        sys.path[0] = request.cwd
        runpy.run_module("globeview", run_name="__main__", alter_sys=True)
    else:
        sys.argv = [argv[0], *argv[1:]]
        sys.path[0] = os.path.dirname(os.path.abspath(argv[0]))
        runpy.run_path(argv[0], run_name="__main__")


def main() -> Request | None:
    import gc
    import logging
    import warnings

    filters, handlers = list(warnings.filters), list(logging.getLogger().handlers)
    preload()
    # What the imports made is never collected here: a child's exit then leaves those pages
    # shared (with the collector walking them, every child's exit copied the whole heap).
    gc.collect()
    gc.freeze()
    server = Server(sys.argv[1])
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    request = server.serve()
    if request is not None:
        become(request, filters, handlers)
    return request


if __name__ == "__main__":
    _request = main()
    if _request is not None:
        run_command(_request)
