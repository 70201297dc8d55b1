"""Open chunk files of a store: each thread's handles on them (GDAL datasets are not
thread-safe), opened through the store's backend and checked against the manifest on first
use, the least recently used closed past `HANDLES_PER_THREAD`, all closed with the store.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import rasterio
from affine import Affine

from globeview.errors import StoreError
from globeview.interrupts import deferred_sigint
from globeview.terrain.levels import LevelGrid
from globeview.terrain.store.backend import (
    RASTER_ERRORS,
    StoreFiles,
    raise_interrupt,
    take_error,
)
from globeview.terrain.store.layout import EXTRA_COL, EXTRA_ROW, chunk_window
from globeview.terrain.store.metadata import StoreMetadata

__all__ = ["HANDLES_PER_THREAD", "ChunkHandles", "short_error"]

#: Chunk datasets a thread keeps open (least recently used closed first).
HANDLES_PER_THREAD = 32


def short_error(exc: BaseException) -> str:
    """First line of an exception's message, at most 160 characters."""
    text = str(exc).strip()
    text = text.splitlines()[0] if text else type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."


def _check_chunk(where: str, ds: rasterio.DatasetReader, grid: LevelGrid, window: tuple) -> None:
    """StoreError unless ``ds`` is the chunk file the manifest describes (its window of
    ``grid``'s raster: size, float32, the level's geotransform moved to its corner)."""
    r0, c0, h, w = window
    want = grid.transform @ Affine.translation(c0, r0)
    if (
        (ds.width, ds.height) != (w, h)
        or ds.count != 1
        or ds.dtypes[0] != "float32"
        or not ds.transform.almost_equals(want, precision=grid.d * 1e-6)
    ):
        raise StoreError(
            f"{where} does not match the store's manifest ({ds.width}x{ds.height} "
            f"{ds.dtypes[0]}, expected {w}x{h} float32 at its place in the level); re-run "
            "globeview ingest --force"
        )


class ChunkHandles:
    """Each thread's open chunk datasets of one store.

    Attributes:
        block_shapes: GDAL block shape of each chunk file opened so far, by (level, chunk
            index) (what block reads and byte prefetches plan with).
        closed: set by `close`: a thread still reading afterwards opens nothing.
    """

    def __init__(self, files: StoreFiles, meta: StoreMetadata) -> None:
        self._files = files
        self._meta = meta
        self._lock = threading.Lock()
        self._local = threading.local()
        self._all: set[rasterio.DatasetReader] = set()
        self.block_shapes: dict[tuple[int, int], tuple[int, int]] = {}
        self.closed = False

    def where(self, level: int, index: int) -> str:
        """The path or URL of chunk ``index`` of a level, for messages."""
        return self._files.describe(self._meta.chunk_name(level, index))

    def explain(self, level: int, index: int, exc: BaseException) -> BaseException:
        """`StoreFiles.explain` for chunk ``index`` of a level (a remote chunk gone because
        the store was updated says so)."""
        return self._files.explain(self._meta.chunk_name(level, index), exc)

    def dataset(self, level: int, index: int) -> rasterio.DatasetReader:
        """This thread's handle on chunk ``index`` of a level, opened on first use; a thread
        keeps its HANDLES_PER_THREAD most recently used ones open."""
        handles: OrderedDict[tuple[int, int], rasterio.DatasetReader] | None = getattr(
            self._local, "handles", None
        )
        if handles is None:
            handles = self._local.handles = OrderedDict()
        key = (level, index)
        ds = handles.get(key)
        if ds is not None:
            handles.move_to_end(key)
            return ds
        if self.closed:  # a worker thread still building after close() opens nothing
            raise StoreError(f"{self._files.location}: the store is closed")
        ds = self._open(level, index)
        with self._lock:
            if self.closed:  # close() ran while this thread was opening the file
                ds.close()
                raise StoreError(f"{self._files.location}: the store is closed")
            self._all.add(ds)
        handles[key] = ds
        while len(handles) > HANDLES_PER_THREAD:
            self._close(handles.popitem(last=False)[1])
        return ds

    def drop(self, level: int, index: int) -> None:
        """Close this thread's handle on a chunk after a failed read (the next read opens
        it afresh: a server back up, a file replaced)."""
        handles = getattr(self._local, "handles", None)
        ds = handles.pop((level, index), None) if handles is not None else None
        if ds is not None:
            self._close(ds)

    def close(self) -> None:
        """Close every thread's handles (a remote one in its opening thread's context) and
        open no more."""
        self.closed = True
        with self._lock:
            for ds in self._all:
                self._files.close_raster(ds)
            self._all.clear()
        self._local = threading.local()

    def _open(self, level: int, index: int) -> rasterio.DatasetReader:
        """Open chunk ``index`` (its code, `layout.chunk_code`) of a level through the backend,
        checked against the store's geometry; StoreError naming the file (a remote one: its
        URL and the HTTP status)."""
        name = self._meta.chunk_name(level, index)
        sha = self._meta.chunk_sha256(level, index)
        where = self._files.describe(name)
        tile_n = self._meta.tile_n
        grid = LevelGrid(level, tile_n, 0, 0, 1 << (level + 1), 1 << level)
        cy, cx = index >> 32, index & 0xFFFFFFFF
        flags = self._meta.chunk_flags(level, cy, cx)
        gr0, gc0, h, w = chunk_window(
            level, tile_n, cy, cx, bool(flags & EXTRA_ROW), bool(flags & EXTRA_COL)
        )
        take_error()
        # A Ctrl-C while GDAL opens the file (through Python callbacks, for a remote one) is
        # raised when it returns, in place of its result or its error.
        with deferred_sigint():
            try:
                ds = self._files.open_raster(name, sha)
            except RASTER_ERRORS as exc:
                err = take_error()
                if err is not None:
                    raise err from None
                raise StoreError(f"{where} is damaged: {short_error(exc)}") from None
            try:
                raise_interrupt()
                _check_chunk(where, ds, grid, (gr0, gc0, h, w))
            except BaseException:
                ds.close()
                raise
        with self._lock:
            self.block_shapes[(level, index)] = ds.block_shapes[0]
        return ds

    def _close(self, ds: rasterio.DatasetReader) -> None:
        with self._lock:
            self._all.discard(ds)
        self._files.close_raster(ds)
