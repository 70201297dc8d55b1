"""Per-test CPU seconds, for finding where the suite's time goes on a loaded machine (wall
time there measures the neighbours). `pytest --cpu-durations=FILE` appends one JSON line per
test phase (setup, call, teardown) to FILE (FILE.gwN under pytest-xdist, one per worker):
nodeid, phase, `self` (this process's user+sys CPU seconds, all threads) and `children` (user+sys
of the child processes waited for during the phase: a CLI subprocess, a Qt helper, a command
forked by tests/zygote.py's server). Fixture costs land in the phase that built them (a session
fixture in its first user's setup)."""

from __future__ import annotations

import json
import os
import resource
import sys
import time
from collections.abc import Generator
from typing import IO

import pytest


def _children_cpu() -> float:
    """Waited-for children's CPU seconds, the commands forked by `zygote`'s server included
    (its children are not this process's until the server ends)."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    zygote = sys.modules.get("zygote")
    forked = zygote.children_cpu() if zygote is not None else 0.0
    return ru.ru_utime + ru.ru_stime + forked


class CpuDurations:
    """Appends each test phase's CPU seconds to one file."""

    def __init__(self, out: IO[str]) -> None:
        self._out = out

    def _measure(self, item: pytest.Item, phase: str) -> Generator[None, None, None]:
        own, kids, wall = time.process_time(), _children_cpu(), time.perf_counter()
        yield
        row = {
            "nodeid": item.nodeid,
            "phase": phase,
            "self": round(time.process_time() - own, 4),
            "children": round(_children_cpu() - kids, 4),
            "wall": round(time.perf_counter() - wall, 4),
        }
        self._out.write(json.dumps(row) + "\n")
        self._out.flush()

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_setup(self, item: pytest.Item) -> Generator[None, None, None]:
        yield from self._measure(item, "setup")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_call(self, item: pytest.Item) -> Generator[None, None, None]:
        yield from self._measure(item, "call")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_teardown(self, item: pytest.Item) -> Generator[None, None, None]:
        yield from self._measure(item, "teardown")


def addoption(parser: pytest.Parser) -> None:
    """`--cpu-durations=FILE` (see the module docstring)."""
    parser.addoption(
        "--cpu-durations",
        metavar="FILE",
        default=None,
        help="append each test phase's CPU seconds (own and children's) to FILE as JSON lines",
    )


def configure(config: pytest.Config) -> None:
    """Registers the recorder when `--cpu-durations` is given."""
    path = config.getoption("--cpu-durations")
    if not path:
        return
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker:
        path = f"{path}.{worker}"
    out = open(path, "a", encoding="utf-8")  # noqa: SIM115 (open for the whole session)
    config.add_cleanup(out.close)
    config.pluginmanager.register(CpuDurations(out), "cpu-durations")
