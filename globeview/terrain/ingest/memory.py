"""Giving freed heap memory back to the system between ingest tasks.

A chunk or error task allocates tens of MB of numpy temporaries (a chunk window is 1025^2
float32 nodes, 4 MB, and its kernels make several) and frees them when it returns; its result
(per-tile statistics, ~15 KB) and GDAL's handles stay. glibc's malloc raises its mmap
threshold when a large block is freed, so after the first tasks these temporaries come from
the heap arenas instead of fresh mappings, and the small long-lived blocks allocated between
them keep the arenas from shrinking: the freed memory stays in the process. Measured on a
build of 6 synthetic SRTM 3" tiles (`benchmarks/make_planet.py`): 375 MB RSS after the graph,
168 MB after one ``malloc_trim(0)``; a 2 000-tile build's process grew to 3.4 GiB this way
(docs/scale.md), most of it freed memory.

`release_if_grown` (called after every task, in the process that ran it) trims the arenas
when the resident set has grown by more than `TRIM_GROWTH_BYTES` since the last trim: the
process's RSS then stays within that margin (plus one task's temporaries) of what is live,
whatever the number of tasks, while the few trims cost no measurable CPU (trimming after
every task would make every task fault its temporaries in again). Where there is no glibc
(macOS, musl) it does nothing.
"""

from __future__ import annotations

import ctypes
import os
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["TRIM_GROWTH_BYTES", "release_if_grown", "resident_bytes", "run_task"]

#: RSS growth (bytes) since the last trim that triggers the next one.
TRIM_GROWTH_BYTES = 128 * 1024 * 1024

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
_lock = threading.Lock()
_floor: list[int] = []  # the RSS (bytes) after the last trim, or at the first check


def _load_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, or None where the C library has none."""
    try:
        libc = ctypes.CDLL(None)
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


_TRIM = _load_trim()


def resident_bytes() -> int | None:
    """This process's resident set size in bytes (``/proc/self/statm``), None where there
    is no /proc."""
    try:
        with open("/proc/self/statm", "rb") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


def release_if_grown(growth: int = TRIM_GROWTH_BYTES) -> bool:
    """Give the heap's free pages back (``malloc_trim(0)``) when this process's RSS exceeds
    the level after the last trim (or the first call) by more than ``growth`` bytes; returns
    whether it trimmed. Thread-safe; a no-op without glibc or /proc."""
    if _TRIM is None:
        return False
    with _lock:
        rss = resident_bytes()
        if rss is None:
            return False
        if not _floor:
            _floor.append(rss)
            return False
        if rss - _floor[0] <= growth:
            return False
        _TRIM(0)
        _floor[0] = resident_bytes() or rss
        return True


def run_task(func: Callable[..., Any], *args: Any) -> Any:
    """``func(*args)``, then `release_if_grown`: how the ingest graph runs each task (in the
    thread or process that runs it: a local thread pool, a spawned process, a dask worker)."""
    result = func(*args)
    release_if_grown()
    return result
