"""The C heap of a process that builds tiles (issue #27, item 2).

A batch of tile builds allocates and frees ~10 MB of numpy temporaries, each of a few
hundred kB ((B, 67 x 67) float64 grids). With glibc's default settings the freed memory goes
back to the kernel after every batch (the top of the heap is trimmed past twice the largest
block freed; blocks over the mmap threshold are unmapped), and the next batch takes it again
page by page: a page fault and a zeroed page per 4 kB. Measured on the 2-core development
machine, that kernel time was two thirds of a batch's mesh stage (1.44 -> 0.48 ms CPU a tile
with the heap kept; `benchmarks/bench_tiles.py` shows it in every stage).

`keep_freed_heap` raises the trim and mmap thresholds so that a few tens of MB of freed heap
stay with the process for the next batch. It changes the process's allocator for good (an
RSS that stays up to `TRIM_BYTES` higher per malloc arena after a peak), so it is called by
what builds tiles many at a time: `TileBuilder` (the renderer's and the loader's thread) and
each tile worker process. A no-op where the C library has no ``mallopt`` (not glibc).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import threading

#: mallopt parameters (glibc's malloc.h).
_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3

#: Freed heap kept before the top is given back to the kernel (bytes).
TRIM_BYTES = 64 << 20
#: Blocks at least this large get their own mapping (bytes): a batch's arrays stay below.
MMAP_BYTES = 16 << 20
#: Extra heap asked for whenever the heap grows (bytes): fewer, larger brk calls.
TOP_PAD_BYTES = 8 << 20

_done = False
_lock = threading.Lock()


def keep_freed_heap() -> bool:
    """Keep freed heap for the next allocations (module docstring); once per process.
    Returns whether the allocator took the settings (False: not glibc, or refused)."""
    global _done
    with _lock:
        if _done:
            return True
        name = ctypes.util.find_library("c")
        try:
            libc = ctypes.CDLL(name)
            mallopt = libc.mallopt
        except (OSError, AttributeError, TypeError):
            return False
        mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        mallopt.restype = ctypes.c_int
        ok = all(
            mallopt(param, value) == 1
            for param, value in (
                (_M_MMAP_THRESHOLD, MMAP_BYTES),
                (_M_TRIM_THRESHOLD, TRIM_BYTES),
                (_M_TOP_PAD, TOP_PAD_BYTES),
            )
        )
        _done = ok
        return ok
