"""Fixtures of the fault-injection suite: a scratch working folder and cache per test, and
small tmpfs mounts for full and read-only disks (root only; skipped otherwise)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import pytest

from .contract import Result, run_globeview, tmpfs


@dataclass
class Workdir:
    """Where one test runs `globeview`: ``cwd`` (outputs go here) and ``cache`` (its
    GLOBEVIEW_CACHE_DIR), both fresh."""

    cwd: Path
    cache: Path

    def run(self, *args: str, cache: Path | None = None) -> Result:
        return run_globeview(list(args), self.cwd, cache or self.cache)


@pytest.fixture
def work(tmp_path: Path) -> Workdir:
    cwd, cache = tmp_path / "cwd", tmp_path / "cache"
    cwd.mkdir()
    cache.mkdir()
    return Workdir(cwd, cache)


@pytest.fixture
def mount_tmpfs(tmp_path: Path) -> Iterator[Callable[..., Path]]:
    """``mount_tmpfs(name, size="256k", readonly=False)`` -> a fresh tmpfs mount point,
    unmounted when the test ends. Skips the test where mounting is impossible (not root)."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs (full / read-only disk) needs root")
    with ExitStack() as stack:

        def mount(name: str, size: str = "256k", readonly: bool = False) -> Path:
            try:
                return stack.enter_context(tmpfs(tmp_path / name, size, readonly))
            except OSError as exc:
                pytest.skip(str(exc))

        yield mount
