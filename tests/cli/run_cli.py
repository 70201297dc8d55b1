"""Running the installed `globeview` command in a process of its own (forked from `zygote`'s
pre-warmed server: a real process without the interpreter start), and reading its one-line
errors: shared by the CLI tests of this folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import zygote
from inprocess_cli import run_globeview

GLOBEVIEW = Path(sys.executable).with_name("globeview")


def globeview(*args: str, cache: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    """``globeview ARGS`` with its own cache folder; stdout and stderr captured as text."""
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(cache)}
    env.pop("GLOBEVIEW_DEBUG", None)
    return zygote.run(
        [str(GLOBEVIEW), *args], capture_output=True, text=True, timeout=timeout, env=env
    )


def globeview_here(*args: str, cache: Path) -> subprocess.CompletedProcess:
    """`globeview` as `globeview` does it, but run in this process (`inprocess_cli`): for tests
    about what a command prints and exits with, not about the process (signals, timeouts)."""
    env = {"GLOBEVIEW_CACHE_DIR": str(cache), "GLOBEVIEW_DEBUG": None}
    return run_globeview(list(args), env=env)


def one_error_line(res: subprocess.CompletedProcess) -> str:
    """The run's error line, after checking it is the only line, exit status 2, no traceback."""
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("globeview: error: "), lines[0]
    assert "Traceback" not in res.stderr
    return lines[0]
