"""Tiles handed from worker processes through shared memory (issue #27, item 2).

A worker's results used to travel pickled: ~142 kB of arrays a tile (vertices 107.6 kB,
albedo and normal texels 16.9 kB each at size 65) serialised in the worker, sent through a
pipe and copied into fresh arrays in the window's process. Instead the window's process
owns one `TileSlab`: a shared-memory segment of ``slots`` tile slots. Before a batch goes
to a worker it takes a slot per tile (`TileSlab.take`); the worker writes each tile's arrays
into its slot (`write_tiles`) and sends back only its key, centre and coast scale; the
window's `ReadyTile` (`TileSlab.tile`) views the slot, and the slot is free again once the
tile is uploaded (`ReadyTile.release`) or dropped (a weakref finalizer: a tile nobody
uploads, e.g. cancelled, frees its slot when it is collected).

Ownership keeps the segment from leaking: only the window's process creates and unlinks it
(`close`; and Python's resource tracker unlinks it if that process dies), workers only
attach. A worker killed in the middle of a batch leaves nothing behind but the slots of
that batch, which are reused only once every process of the broken pool is seen dead
(`TileSlab.free_when_dead`), so no late write of a dying worker lands in a slot given to
another batch. When no slots are free (the window is not uploading as fast as the workers
build) a batch travels pickled as before.

Layout of a slot: vertices (V, 6) float32, albedo (size, size, 4) uint8, normal (size,
size, 4) uint8, each at a 64-byte aligned offset.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import weakref
from dataclasses import dataclass
from multiprocessing import shared_memory
from multiprocessing.connection import wait as wait_sentinels
from typing import Any

import numpy as np

from globeview.render.tile_build import ReadyTile
from globeview.render.tile_mesh import FLOATS_PER_VERTEX, vertices_per_tile

log = logging.getLogger("globeview.render")

_ALIGN = 64


def _aligned(n: int) -> int:
    return (n + _ALIGN - 1) // _ALIGN * _ALIGN


@dataclass(frozen=True)
class SlabSpec:
    """What a worker needs to write into a slab: its segment's name, its slot count and the
    tiles' size (nodes a side)."""

    name: str
    slots: int
    tile_size: int

    def offsets(self) -> tuple[int, int, int]:
        """Byte offsets of (albedo, normal, next slot) in a slot; vertices are at 0."""
        s = self.tile_size
        albedo = _aligned(vertices_per_tile(s) * FLOATS_PER_VERTEX * 4)
        normal = albedo + _aligned(s * s * 4)
        return albedo, normal, normal + _aligned(s * s * 4)

    def views(
        self, buf: memoryview | np.ndarray, slot: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertices, albedo, normal) arrays over slot ``slot`` of ``buf`` (the segment)."""
        s = self.tile_size
        albedo_at, normal_at, slot_bytes = self.offsets()
        base = slot * slot_bytes
        verts = np.ndarray(
            (vertices_per_tile(s), FLOATS_PER_VERTEX), np.float32, buffer=buf, offset=base
        )
        albedo = np.ndarray((s, s, 4), np.uint8, buffer=buf, offset=base + albedo_at)
        normal = np.ndarray((s, s, 4), np.uint8, buffer=buf, offset=base + normal_at)
        return verts, albedo, normal


class TileSlab:
    """The window's shared-memory slots for tiles built in worker processes (module
    docstring). Thread-safe.

    Args:
        tile_size: nodes a tile side.
        slots: tiles the slab holds at once (each ~142 kB at size 65).
    """

    def __init__(self, tile_size: int, slots: int = 256) -> None:
        if slots < 1:
            raise ValueError(f"a tile slab needs at least 1 slot, got {slots}")
        probe = SlabSpec("", slots, tile_size)
        self._shm = shared_memory.SharedMemory(create=True, size=slots * probe.offsets()[2])
        _reserve(self._shm)
        self.spec = SlabSpec(self._shm.name, slots, tile_size)
        self._array: np.ndarray | None = np.ndarray(
            (self._shm.size,), np.uint8, buffer=self._shm.buf
        )
        self._lock = threading.Lock()
        self._free: list[int] = list(range(slots - 1, -1, -1))  # pop() takes slot 0 first
        self._taken: set[int] = set()
        #: Slots given up for good (a worker of a broken pool could not be seen dead).
        self.lost = 0

    @property
    def free_count(self) -> int:
        """Slots free now."""
        with self._lock:
            return len(self._free)

    @property
    def closed(self) -> bool:
        return self._array is None

    def take(self, n: int) -> list[int] | None:
        """``n`` free slots, or None (none taken) when fewer are free or the slab is
        closed: the batch then travels pickled."""
        with self._lock:
            if self._array is None or len(self._free) < n:
                return None
            out = [self._free.pop() for _ in range(n)]
            self._taken.update(out)
            return out

    def free(self, slots: list[int]) -> None:
        """Give ``slots`` back (a slot not taken is ignored: freeing is idempotent)."""
        with self._lock:
            for s in slots:
                if s in self._taken:
                    self._taken.remove(s)
                    self._free.append(s)

    def free_when_dead(self, procs: list[Any], slots: list[int], timeout_s: float = 5.0) -> None:
        """Give back the slots of a batch whose worker pool broke, once every process of
        that pool (`multiprocessing.Process`) has ended: one still running (being
        terminated) could write into them. Waits up to ``timeout_s`` seconds on their
        sentinels; slots of a pool not seen dead by then stay taken (counted in `lost`)."""
        sentinels = []
        for p in procs:
            try:
                sentinels.append(p.sentinel)
            except ValueError:  # closed: joined already
                continue
        pending = set(sentinels)
        if pending:
            for ready in wait_sentinels(list(pending), timeout=timeout_s):
                pending.discard(ready)
        if pending:
            with self._lock:
                self.lost += len(slots)
            log.warning(
                "tile workers did not end within %.0f s: %d shared tile slots given up",
                timeout_s,
                len(slots),
            )
            return
        self.free(slots)

    def tile(self, slot: int, center: np.ndarray, coast_scale: float) -> ReadyTile:
        """The `ReadyTile` a worker wrote into ``slot``: its arrays view the slot (valid
        until it is released), ``release`` frees the slot (also when the tile is
        collected unreleased)."""
        if self._array is None:
            raise RuntimeError("the tile slab is closed")
        verts, albedo, normal = self.spec.views(self._array, slot)
        tile = ReadyTile(np.asarray(center, dtype=np.float64), verts, albedo, normal, coast_scale)
        fin = weakref.finalize(tile, self.free, [slot])
        fin.atexit = False
        tile.release = fin
        return tile

    def close(self) -> None:
        """Unlink the segment (its name leaves /dev/shm at once) and unmap it once no tile
        views it any more. Idempotent.

        Not `SharedMemory.close` at once: numpy arrays over a buffer hold no export of it,
        so closing would unmap the memory under tiles not uploaded yet (a crash when they
        are read). Every tile views ``_array``, so the segment is closed when that array is
        collected, i.e. after the last tile."""
        with self._lock:
            array, self._array = self._array, None
            self._free.clear()
        if array is None:
            return
        with contextlib.suppress(FileNotFoundError):  # the resource tracker's doing
            self._shm.unlink()
        fin = weakref.finalize(array, self._shm.close)
        fin.atexit = False
        del array  # no tile left: closed here


def _reserve(shm: shared_memory.SharedMemory) -> None:
    """Give the segment its memory now: a tmpfs too small for it (a container's 64 MB
    /dev/shm shared with others) fails here with OSError, and the segment is unlinked,
    rather than with SIGBUS in a worker writing a tile into a page that cannot be had."""
    fd = getattr(shm, "_fd", -1)
    if fd < 0 or not hasattr(os, "posix_fallocate"):
        return
    try:
        os.posix_fallocate(fd, 0, shm.size)
    except OSError:
        shm.close()
        shm.unlink()
        raise


# -- in a worker process -----------------------------------------------------------------------
_attached: dict[str, shared_memory.SharedMemory] = {}


def _attach(spec: SlabSpec) -> shared_memory.SharedMemory:
    shm = _attached.get(spec.name)
    if shm is None:
        kwargs: dict[str, Any] = {"track": False} if sys.version_info >= (3, 13) else {}
        # Before 3.13 attaching registers the name with the resource tracker the worker
        # shares with the window's process (forkserver): a set, so nothing changes there.
        shm = _attached[spec.name] = shared_memory.SharedMemory(spec.name, **kwargs)
    return shm


def write_tiles(spec: SlabSpec, slots: list[int], tiles: list[ReadyTile]) -> None:
    """Write ``tiles`` into ``slots`` of the slab ``spec`` (in a worker process)."""
    buf = _attach(spec).buf
    assert buf is not None  # (None only once closed)
    for slot, tile in zip(slots, tiles, strict=True):
        verts, albedo, normal = spec.views(buf, slot)
        verts[...] = tile.vertices
        albedo[...] = tile.albedo
        normal[...] = tile.normal
