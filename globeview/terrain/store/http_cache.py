"""A bounded, process-shared disk cache of byte pages fetched over HTTP (remote stores).

Entries are files ``<dir>/<key[:2]>/<key>`` holding a 24-byte header (magic, payload length,
a 16-byte BLAKE2b digest of the payload) and the payload. Keys are chosen by the caller
(`globeview.terrain.store.http` uses the chunk file's sha256 from the store's manifest, the page
size and the page index), so a rebuilt store, whose chunks have new digests, never reads a
stale entry.

- Bounded: `DiskCache.put` evicts the least recently used entries (by file mtime, refreshed
  on every hit) until the cache holds at most ``max_bytes``.
- Atomic: an entry is written to a unique temporary name in its folder and `os.replace`d, so
  a reader (another thread or process) sees a whole entry or none.
- Never fatal: a cache folder that cannot be created or written (read-only, disk full) only
  turns caching off for this process (`writable` False); a damaged entry (short, bad digest)
  is removed and reported as a miss, so the caller fetches it again.

One `DiskCache` per folder per process (`DiskCache.shared`), so every remote store opened in
the process counts against the same bound. Several processes sharing a folder each keep
their own tally; the bound then holds per process, and an entry one evicts is a miss (a
refetch) for the other, never a wrong read.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import struct
import threading
from collections import OrderedDict
from pathlib import Path
from typing import ClassVar

__all__ = ["DiskCache"]

_MAGIC = b"GVPG"
_HEADER = struct.Struct("<4sI16s")  # magic, payload length, blake2b-128 of the payload
_TMP_PREFIX = ".tmp-"


def _digest(data: bytes) -> bytes:
    return hashlib.blake2b(data, digest_size=16).digest()


class DiskCache:
    """Pages by key in a folder, at most ``max_bytes`` on disk (see the module docstring).

    Thread-safe. Keys must be file-name safe (``[0-9a-zA-Z_.-]``, at least 3 characters).
    """

    _shared: ClassVar[dict[tuple[str, int], DiskCache]] = {}
    _shared_lock: ClassVar[threading.Lock] = threading.Lock()

    def __init__(self, folder: Path, max_bytes: int) -> None:
        self.folder = Path(folder)
        self.max_bytes = max(0, int(max_bytes))
        self.writable = self.max_bytes > 0
        self._lock = threading.Lock()
        self._index: OrderedDict[str, int] | None = None  # key -> file size, LRU first
        self._total = 0

    @classmethod
    def shared(cls, folder: Path, max_bytes: int) -> DiskCache:
        """The process's cache of ``folder`` with bound ``max_bytes`` (created once)."""
        key = (os.path.abspath(folder), int(max_bytes))
        with cls._shared_lock:
            hit = cls._shared.get(key)
            if hit is None:
                hit = cls._shared[key] = cls(Path(folder), max_bytes)
            return hit

    # -- the index -------------------------------------------------------------------------------

    def _path(self, key: str) -> Path:
        return self.folder / key[:2] / key

    def _load_index(self) -> OrderedDict[str, int]:
        """Scan the folder once: entries oldest first (mtime), temporaries left by a crash
        removed. Called with the lock held."""
        if self._index is not None:
            return self._index
        found: list[tuple[float, str, int]] = []
        try:
            subs = list(os.scandir(self.folder))
        except OSError:
            subs = []
        for sub in subs:
            try:
                if not sub.is_dir(follow_symlinks=False):
                    continue
                for e in os.scandir(sub.path):
                    if not e.is_file(follow_symlinks=False):
                        continue
                    st = e.stat(follow_symlinks=False)
                    if e.name.startswith(_TMP_PREFIX):
                        _unlink(e.path)
                        continue
                    found.append((st.st_mtime, e.name, st.st_size))
            except OSError:
                continue
        found.sort()
        self._index = OrderedDict((name, size) for _, name, size in found)
        self._total = sum(size for _, _, size in found)
        return self._index

    @property
    def total_bytes(self) -> int:
        """Bytes of the entries this process knows of (after the first scan)."""
        with self._lock:
            self._load_index()
            return self._total

    # -- get / put -------------------------------------------------------------------------------

    def get(self, key: str) -> bytes | None:
        """The payload stored under ``key``, or None (absent, unreadable or damaged: a damaged
        entry is removed)."""
        if self.max_bytes <= 0:
            return None
        path = self._path(key)
        try:
            with open(path, "rb") as f:
                raw = f.read()
        except OSError:
            return None
        ok = len(raw) >= _HEADER.size
        if ok:
            magic, length, digest = _HEADER.unpack_from(raw)
            payload = raw[_HEADER.size :]
            ok = magic == _MAGIC and length == len(payload) and _digest(payload) == digest
        if not ok:
            self._drop(key)
            return None
        with contextlib.suppress(OSError):
            os.utime(path)  # most recently used, for this and other processes
        with self._lock:
            index = self._load_index()
            if key in index:
                index.move_to_end(key)
            else:  # written by another process since the scan
                index[key] = len(raw)
                self._total += len(raw)
        return payload

    def put(self, key: str, payload: bytes) -> bool:
        """Store ``payload`` under ``key`` (atomically), evicting the least recently used
        entries past the bound. False when not cached (caching off, entry larger than the
        bound, or the folder cannot be written: then caching stays off in this process)."""
        size = _HEADER.size + len(payload)
        if not self.writable or size > self.max_bytes:
            return False
        path = self._path(key)
        tmp = path.parent / f"{_TMP_PREFIX}{os.getpid()}-{threading.get_ident()}-{key}"
        with self._lock:
            index = self._load_index()
            old = index.pop(key, None)
            if old is not None:
                self._total -= old
            victims = []
            while index and self._total + size > self.max_bytes:
                victim, vsize = index.popitem(last=False)
                self._total -= vsize
                victims.append(victim)
            index[key] = size
            self._total += size
        for victim in victims:
            _unlink(self._path(victim))
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "wb") as f:
                f.write(_HEADER.pack(_MAGIC, len(payload), _digest(payload)))
                f.write(payload)
            os.replace(tmp, path)
        except OSError:
            _unlink(tmp)
            with self._lock:
                if self._index is not None and self._index.pop(key, None) is not None:
                    self._total -= size
                self.writable = False  # full or read-only: no caching, nothing else changes
            return False
        return True

    def _drop(self, key: str) -> None:
        _unlink(self._path(key))
        with self._lock:
            if self._index is not None:
                size = self._index.pop(key, None)
                if size is not None:
                    self._total -= size


def _unlink(path: str | Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)
