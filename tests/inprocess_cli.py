"""Running `globeview ARGS` inside the test process: `globeview.cli.main(argv)` with its
stdout and stderr captured at the file-descriptor level (Python's prints and GDAL's or PROJ's
C-level chatter alike), its exit status (argparse's `SystemExit` included), environment and
working folder set for the call and restored after, and the process-wide state `main` sets up
(the root logger's handler and level, warnings routed to logging) undone. The counting
SIGINT handler `globeview.interrupts` installs stays: it is process-wide by design and raises
KeyboardInterrupt as Python's default handler does.

For tests about what a command prints, writes and exits with: a child process costs 0.5-2
CPU-seconds of interpreter start, imports, plugin discovery and a GL context before the
command does anything. Tests about the process boundary itself (signals, a hung child, the
console script, exit codes of a real process under a fault) keep `subprocess`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO


@contextlib.contextmanager
def _environment(env: Mapping[str, str | None], cwd: Path | None) -> Iterator[None]:
    saved, here = dict(os.environ), os.getcwd()
    for name, value in env.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
    if cwd is not None:
        os.chdir(cwd)
    try:
        yield
    finally:
        os.chdir(here)
        os.environ.clear()
        os.environ.update(saved)


@contextlib.contextmanager
def _process_state() -> Iterator[None]:
    """Undo what `globeview.cli.main` sets up for a whole process."""
    import globeview.cli as cli

    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    captured = logging._warnings_showwarning is not None  # type: ignore[attr-defined]
    try:
        yield
    finally:
        cli._handler = None
        root.handlers[:] = handlers
        root.setLevel(level)
        if not captured:
            logging.captureWarnings(False)


@contextlib.contextmanager
def _fds_into(out: IO[bytes], err: IO[bytes]) -> Iterator[None]:
    """fds 1 and 2, and sys.stdout and sys.stderr on them, into ``out`` and ``err``."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved_fds = os.dup(1), os.dup(2)
    saved_py = sys.stdout, sys.stderr
    os.dup2(out.fileno(), 1)
    os.dup2(err.fileno(), 2)
    sys.stdout = open(1, "w", encoding="utf-8", errors="replace", closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", encoding="utf-8", errors="replace", closefd=False)  # noqa: SIM115
    try:
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(ValueError, OSError):  # main may close stderr (EPIPE)
                stream.flush()
        sys.stdout, sys.stderr = saved_py
        os.dup2(saved_fds[0], 1)
        os.dup2(saved_fds[1], 2)
        os.close(saved_fds[0])
        os.close(saved_fds[1])


def _status(exc: SystemExit) -> int:
    if exc.code is None:
        return 0
    if isinstance(exc.code, int):
        return exc.code
    sys.stderr.write(f"{exc.code}\n")
    return 1


def run_globeview(
    args: list[str], env: Mapping[str, str | None] | None = None, cwd: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """``globeview ARGS`` in this process, as `subprocess.run(..., capture_output=True,
    text=True)` would report it; ``env`` sets (a value) or removes (None) variables for the
    call, ``cwd`` is its working folder."""
    from globeview.cli import main

    with (
        _environment(env or {}, cwd),
        _process_state(),
        tempfile.TemporaryFile() as out,
        tempfile.TemporaryFile() as err,
    ):
        with _fds_into(out, err):
            try:
                code = main(list(args))
            except SystemExit as exc:
                code = _status(exc)
        texts = [_read(f) for f in (out, err)]
    return subprocess.CompletedProcess(["globeview", *args], code, texts[0], texts[1])


def _read(f: IO[bytes]) -> str:
    f.seek(0)
    return f.read().decode("utf-8", "replace")
