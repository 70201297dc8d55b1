"""A build's freed memory goes back to the system (`terrain/ingest/memory.py`): the heap's
free pages are trimmed once a process's RSS has grown past the margin, not before, and every
task of the ingest graph runs through that check (so a worker's RSS does not grow with the
number of tasks it has run, issue #25's 2 000-tile build)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from globeview.terrain.ingest import memory
from globeview.terrain.ingest.driver import ingest

DATA = Path(__file__).resolve().parents[2] / "data"

needs_glibc = pytest.mark.skipif(
    memory._TRIM is None or memory.resident_bytes() is None,
    reason="malloc_trim and /proc/self/statm are glibc/Linux only",
)

MB = 1024 * 1024


@pytest.fixture
def fresh(monkeypatch: pytest.MonkeyPatch) -> None:
    """The module's state as in a new process (no trim yet)."""
    monkeypatch.setattr(memory, "_floor", [])


def _fragmented_free(total: int) -> list[bytes]:
    """Allocate ``total`` bytes in 96 KB heap blocks (under glibc's mmap threshold), each
    followed by a small block that stays, then free the large ones: the freed pages sit
    between live blocks, where free() cannot hand them back. Returns the survivors."""
    big, keep = [], []
    for _ in range(total // (96 * 1024)):
        a = np.ones(96 * 1024 // 8)  # touched: resident
        big.append(a)
        keep.append(bytes(2000) + b"x")  # a small live block (malloc's, not pymalloc's)
    del big
    return keep


@needs_glibc
def test_freed_heap_pages_go_back_once_rss_grew_past_the_margin(fresh: None) -> None:
    assert memory.release_if_grown(growth=32 * MB) is False  # the first call: the floor
    keep = _fragmented_free(160 * MB)
    before = memory.resident_bytes()
    assert before is not None
    assert memory.release_if_grown(growth=32 * MB) is True
    after = memory.resident_bytes()
    assert after is not None
    assert before - after > 80 * MB  # most of the 160 MB freed went back
    assert memory.release_if_grown(growth=32 * MB) is False  # the new floor: no growth
    assert keep


@needs_glibc
def test_no_trim_within_the_margin(fresh: None, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[int] = []
    monkeypatch.setattr(memory, "_TRIM", lambda pad: calls.append(pad) or 0)
    memory.release_if_grown()
    keep = [np.ones(8 * MB // 8)]  # 8 MB live: well within 128 MiB
    assert memory.release_if_grown() is False and calls == []
    memory._floor[0] -= memory.TRIM_GROWTH_BYTES + 1  # as if it had grown past the margin
    assert memory.release_if_grown() is True and calls == [0]
    assert keep


def test_every_task_of_the_graph_runs_through_the_check(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    checks: list[int] = []
    monkeypatch.setattr(memory, "release_if_grown", lambda: checks.append(1) or False)
    progress: list[int] = []
    ingest(
        [DATA / "topobathy_vancouver.tif"],
        tmp_path / "s",
        workers=1,
        on_progress=lambda done, total: progress.append(total),
    )
    # Every chunk and error task (what progress counts) and the pole task.
    assert progress and len(checks) == progress[-1] + 1
