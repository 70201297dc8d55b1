"""The tile builders' heap settings (render/heap.py, issue #27 item 2): with them a process
that allocates and frees a batch's worth of few-hundred-kB arrays over and over stops
faulting pages in for every batch; without them (glibc's defaults) it does. Counted in page
faults of fresh processes, not timed."""

from __future__ import annotations

import subprocess
import sys

import pytest

_SCRIPT = """
import resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from globeview.render.heap import keep_freed_heap
    assert keep_freed_heap() and keep_freed_heap()
def batch():
    # A tile batch's temporaries: 36 arrays of (8, 67 x 67) float64 (~290 kB each) alive
    # together, then freed.
    a = [np.ones((8, 67 * 67)) * k for k in range(36)]
    return sum(float(v[0, 0]) for v in a)
for _ in range(5):
    batch()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    batch()
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 20)
"""


def _faults_per_batch(mode: str) -> float:
    out = subprocess.run(
        [sys.executable, "-c", _SCRIPT, mode], capture_output=True, text=True, check=True
    )
    return float(out.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_batches_are_reused_without_page_faults() -> None:
    default = _faults_per_batch("default")
    kept = _faults_per_batch("keep")
    # A batch is ~10 MB: ~2 500 pages. Kept, the heap serves it again without the kernel.
    assert default > 1000, default
    assert kept < 50, kept
