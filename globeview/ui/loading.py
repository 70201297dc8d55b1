"""Opening sources off the UI thread.

`DemLoader` opens a source (`globeview.terrain.sources.open_source`: a DEM file, ingested into
the cache once; a store folder; a store URL; whatever an installed store backend reads) in a
worker thread and reports back through Qt signals, which arrive on the UI thread (queued
connections). One source at a time; further requests wait in a queue.

Progress and cancellation: the ingest calls the loader's hook after each task (the status
bar's progress), and once Cancel is pressed the hook raises `LoadCancelled`, which aborts the
ingest and leaves no store behind; a store being opened when Cancel is pressed is discarded.

A DEM file without a coordinate reference system: the loader asks for one on the UI thread
(`DemLoader.ask_crs`, by default the dialog of `globeview.ui.crs_dialog`, which checks it as
``--crs`` is checked) and opens the file again with it; cancelling the dialog reports the
file's one-line error.
"""

from __future__ import annotations

import errno
import logging
import os
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

from PyQt6.QtCore import QObject, pyqtSignal
from PyQt6.QtWidgets import QWidget

from globeview.errors import GlobeviewError
from globeview.terrain.compose.blend import BlendMask
from globeview.terrain.sources import open_source
from globeview.terrain.store.tile_store import TileStore
from globeview.ui.crs_dialog import ask_crs

log = logging.getLogger("globeview.ui")


class LoadCancelled(Exception):
    """Raised inside the worker (through the progress hook) to abort an ingest."""


def missing_path_error(path: str | Path) -> GlobeviewError:
    """The one-line error for a path of any kind (a DEM or an overlay) the window is asked to
    open that does not resolve: a symbolic link loop, a dangling symbolic link, or a plain
    missing file. (A source that reaches the loader gets `open_source`'s words.)"""
    p = Path(path)
    if p.is_symlink():
        try:
            p.resolve(strict=True)
        except (RuntimeError, OSError) as exc:
            # A loop: RuntimeError up to Python 3.12, OSError(ELOOP) from 3.13.
            if isinstance(exc, RuntimeError) or exc.errno == errno.ELOOP:
                return GlobeviewError(f"{p} is a symbolic link loop (it never reaches a file)")
            return GlobeviewError(f"{p} is a broken symbolic link (to {os.readlink(p)})")
    return GlobeviewError(f"file not found: {p}")


def open_store(
    path: str | Path,
    on_progress: Callable[[int, int], None] | None = None,
    vdatum: str | None = None,
    crs: str | None = None,
) -> TileStore:
    """`open_source` as the window uses it, on the loader's thread: a store over a network
    also gets what the UI thread reads first fetched here (`warm_remote_store`).

    Raises:
        GlobeviewError: one line for a source that cannot be opened.
    """
    store = open_source(path, crs=crs, vdatum=vdatum, on_progress=on_progress)
    if store.is_remote:
        # The manifest was fetched here, on the loader's thread (the remote reader's timeouts
        # and retries bound the wait; Cancel discards the result).
        try:
            warm_remote_store(store)
        except BaseException:
            store.close()
            raise
    return store


def warm_remote_store(store: TileStore) -> None:
    """Fetch, on the calling (loader) thread, what the window's UI thread reads of a remote
    store before any frame can have fetched it: its blend mask (`BlendMask`, made the first
    time the layer is composed or selected; from the coverage in the top shard the open
    fetched, or for a store built before it, a few dozen coarse tiles read whole).
    The UI thread never waits for the network (`FileOpening.add_store`), and a mask it could
    not build would fail the LOD selection; later reads (the border band's difference tables,
    tiles finer than the layer's data) are bounded without the tiles until they arrive.
    Raises `StoreError` (one line) when those tiles cannot be read: the layer is not added."""
    BlendMask(store)  # a store without a coverage: its level's tiles into the caches


class _Request(NamedTuple):
    path: str
    vdatum: str | None
    crs: str | None


def _ask_with_dialog(parent: QObject | None) -> Callable[[str, BaseException], str | None]:
    """The default `DemLoader.ask_crs`: the modal dialog of `globeview.ui.crs_dialog` over
    the loader's window."""

    def ask(path: str, exc: BaseException) -> str | None:
        return ask_crs(parent if isinstance(parent, QWidget) else None, path, str(exc))

    return ask


class DemLoader(QObject):
    """Loads DEMs one at a time in a worker thread.

    Signals (all delivered on the UI thread):
        started(str): a file's load began.
        progress(int, int): done / total steps of the running load (total 0: unknown).
        loaded(str, object): the path and its `TileStore`.
        failed(str, object): the path and the exception.
        cancelled(str): the load was cancelled (its result, if any, discarded).
        idle(): the queue is empty.

    Attributes:
        ask_crs: called on the UI thread as ``ask_crs(path, error)`` when a DEM file has no
            CRS; returns the CRS to open it with (a text ``--crs`` takes), or None to give up
            (the file's error is reported). Default: a dialog over the loader's window.
    """

    started = pyqtSignal(str)
    progress = pyqtSignal(int, int)
    loaded = pyqtSignal(str, object)
    failed = pyqtSignal(str, object)
    cancelled = pyqtSignal(str)
    idle = pyqtSignal()
    _done = pyqtSignal(str, object, object)  # worker -> UI thread

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="globeview-load")
        self._queue: deque[_Request] = deque()
        self._current: _Request | None = None
        self._future: Future | None = None
        self._cancel = threading.Event()
        self.ask_crs: Callable[[str, BaseException], str | None] | None = _ask_with_dialog(parent)
        self._done.connect(self._on_done)

    @property
    def busy(self) -> bool:
        return self._current is not None

    def load(self, path: str | Path, vdatum: str | None = None, crs: str | None = None) -> None:
        """Queue a source for loading; ``vdatum`` and ``crs`` override a DEM file's vertical
        datum ("egm96", "ellipsoid") and CRS (what ``--crs`` takes); None: from the file."""
        self._queue.append(_Request(str(path), vdatum, crs))
        self._next()

    def cancel(self) -> None:
        """Cancel the running load and drop the queued ones."""
        self._queue.clear()
        if self._current is not None:
            self._cancel.set()

    def _next(self) -> None:
        if self._current is not None:
            return
        if not self._queue:
            self.idle.emit()
            return
        request = self._current = self._queue.popleft()
        self._cancel.clear()
        self.started.emit(request.path)
        self.progress.emit(0, 0)
        self._future = self._pool.submit(self._work, request)

    def _work(self, request: _Request) -> None:
        """Worker thread: never touches widgets, only emits signals."""

        def hook(done: int, total: int) -> None:
            if self._cancel.is_set():
                raise LoadCancelled
            self.progress.emit(int(done), int(total))

        try:
            store = open_store(request.path, hook, request.vdatum, request.crs)
        except BaseException as exc:  # noqa: BLE001  delivered to the UI thread, never lost
            self._done.emit(request.path, None, exc)
            return
        self._done.emit(request.path, store, None)

    def _on_done(self, path: str, store: object, exc: object) -> None:
        from globeview.terrain.dem.reader import NoCrsError  # deferred: DEM files only

        request = self._current
        self._future = None
        if (
            isinstance(exc, NoCrsError)
            and request is not None
            and request.crs is None
            and self.ask_crs is not None
            and not self._cancel.is_set()
        ):
            crs = self.ask_crs(path, exc)  # modal; the loader stays busy meanwhile
            if crs and not self._cancel.is_set():
                self._current = None
                self._queue.appendleft(request._replace(crs=crs))
                self._next()
                return
        self._current = None
        if self._cancel.is_set() or isinstance(exc, LoadCancelled):
            log.info("load of %s cancelled", path)
            self.cancelled.emit(path)
        elif exc is not None:
            self.failed.emit(path, exc)
        else:
            self.loaded.emit(path, store)
        self._next()

    def wait(self, timeout_s: float | None = None) -> None:
        """Block until the running load's worker returns (shutdown and tests)."""
        fut = self._future
        if fut is not None:
            fut.result(timeout=timeout_s)

    def shutdown(self) -> None:
        """Cancel everything and stop the worker (waits for a running ingest to end)."""
        self.cancel()
        self._pool.shutdown(wait=True, cancel_futures=True)
