"""Suite-wide guard: where the project's test command runs (./test sets
GLOBEVIEW_REQUIRE_GL=1), a missing headless OpenGL must fail the run, not quietly skip every
rendering test. Run plain `pytest` on a machine without EGL and those tests skip instead."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cpu_durations
import pytest

PROBE = "from globeview.render.offscreen import create_headless_context as c; c().release()"


def pytest_addoption(parser: pytest.Parser) -> None:
    cpu_durations.addoption(parser)


def pytest_configure(config: pytest.Config) -> None:
    cpu_durations.configure(config)


def pytest_unconfigure(config: pytest.Config) -> None:
    zygote = sys.modules.get("zygote")  # the CLI tests' fork server, where one was started
    if zygote is not None:
        zygote.close()


def pytest_sessionstart(session: pytest.Session) -> None:
    if os.environ.get("GLOBEVIEW_REQUIRE_GL") != "1":
        return
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return  # the controlling process probed once for all its workers
    # Probe in a child process: once a thread of this process has had an EGL context current,
    # libglvnd will not make Qt's GLX context current here (the window tests need that).
    probe = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True)
    if probe.returncode != 0:
        reason = (probe.stderr.strip().splitlines() or ["unknown error"])[-1]
        pytest.exit(f"headless OpenGL is required by ./test: {reason}", returncode=1)


# Marks by folder: every test under tests/ui needs a real window, every test under tests/bench
# runs a benchmark (./test --fast leaves both out).
_FOLDER_MARKS = {"ui": "gui", "bench": "bench"}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    tests_dir = Path(__file__).resolve().parent
    for item in items:
        try:
            folder = item.path.resolve().relative_to(tests_dir).parts[0]
        except ValueError:
            continue
        mark = _FOLDER_MARKS.get(folder)
        if mark is not None:
            item.add_marker(mark)
