"""A build's freed memory goes back to the system (`terrain/ingest/memory.py`): the heap's
free pages are trimmed once a process's RSS has grown past the margin, not before, and every
task of the ingest graph runs through that check (so a worker's RSS does not grow with the
number of tasks it has run, issue #25's 2 000-tile build)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from globeview.terrain.ingest import driver as driver_mod
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


#: Run in a new interpreter: a pytest worker that ran other tests has a fragmented heap whose
#: free holes the blocks below would partly fill (their small survivors too, so the large ones
#: coalesce and free() itself gives some back): 63 of the 160 MB went back in one CI run.
_FRAGMENT_AND_TRIM = """
import json
import numpy as np
from globeview.terrain.ingest import memory

MB = 1024 * 1024
assert memory.release_if_grown(growth=32 * MB) is False  # the first call: the floor
# 160 MB in 96 KB heap blocks (under glibc's mmap threshold), each followed by a small block
# that stays (malloc's, not pymalloc's), then the large ones freed: the freed pages sit
# between live blocks, where free() cannot hand them back.
big, keep = [], []
for _ in range(160 * MB // (96 * 1024)):
    big.append(np.ones(96 * 1024 // 8))  # touched: resident
    keep.append(bytes(2000) + b"x")
del big
before = memory.resident_bytes()
trimmed = memory.release_if_grown(growth=32 * MB)
after = memory.resident_bytes()
again = memory.release_if_grown(growth=32 * MB)
print(json.dumps(dict(before=before, after=after, trimmed=trimmed, again=again, kept=len(keep))))
"""


@needs_glibc
def test_freed_heap_pages_go_back_once_rss_grew_past_the_margin() -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[2])
    run = subprocess.run(
        [sys.executable, "-c", _FRAGMENT_AND_TRIM],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["trimmed"] is True  # grew by ~160 MB, past the 32 MB margin
    assert got["before"] - got["after"] > 80 * MB  # most of the 160 MB freed went back
    assert got["again"] is False  # the new floor: no growth since
    assert got["kept"] > 1000


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


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="counts /proc/self/fd")
def test_sources_are_not_held_open_while_the_build_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """40 one-degree tiles (tiny rasters): once planned, the driver holds no file of them
    (the tasks reopen what they read, a bounded number per thread)."""
    import rasterio
    from affine import Affine

    paths = []
    for i in range(40):
        p = tmp_path / f"t{i:02d}.tif"
        data = np.full((8, 8), 100.0 + i, dtype=np.float32)
        with rasterio.open(
            p, "w", driver="GTiff", width=8, height=8, count=1, dtype="float32",
            crs="EPSG:4326", transform=Affine(1 / 8, 0, i % 8, 0, -1 / 8, 40 + i // 8),
        ) as ds:  # fmt: skip
            ds.write(data, 1)
        paths.append(p)

    class Planned(Exception):
        pass

    seen: list[int] = []

    def stop(*args: object, **kw: object) -> None:
        seen.append(_open_fds())
        raise Planned

    monkeypatch.setattr(driver_mod, "_plan_build", stop)
    before = _open_fds()
    with pytest.raises(Planned):
        ingest(paths, tmp_path / "s", workers=2)
    assert seen and seen[0] - before < 10  # not one per source
