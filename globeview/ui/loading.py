"""Opening DEMs off the UI thread.

`DemLoader` ingests a DEM (or opens an existing tile store) in a worker thread and reports
back through Qt signals, which arrive on the UI thread (queued connections). One file at a
time; further requests wait in a queue.

Progress and cancellation: `globeview.terrain.ingest.driver.ingest` has no progress callback or
cancellation hook yet, so the progress is indeterminate and "cancel" can only be honoured
between files: the running ingest finishes (its store lands in the cache, complete, for the
next time) and its result is discarded. If ``ingest`` grows an ``on_progress(done, total)``
keyword whose exception aborts the build, this loader uses it (see `_ingest_kwargs`).
"""

from __future__ import annotations

import errno
import inspect
import logging
import os
import threading
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

from PyQt6.QtCore import QObject, pyqtSignal

from globeview.errors import GlobeviewError
from globeview.terrain.store.tile_store import MANIFEST_NAME, TileStore

log = logging.getLogger("globeview.ui")


class LoadCancelled(Exception):
    """Raised inside the worker (through the progress hook) to abort an ingest."""


def missing_path_error(path: str | Path) -> GlobeviewError:
    """The one-line error for a path that cannot be opened because it does not resolve: a
    symbolic link loop, a dangling symbolic link, or a plain missing file."""
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


def open_store(path: str | Path, on_progress=None, vdatum: str | None = None) -> TileStore:
    """A tile store for ``path``: a store directory or a store URL (http/https, read remotely)
    is opened as is; a DEM file is ingested
    into the user cache once (an unchanged file opens instantly the next time). ``vdatum``
    ("egm96" or "ellipsoid") overrides the DEM's vertical datum (None: from the file).

    Raises:
        GlobeviewError: the path is neither a DEM globeview can read nor a tile store.
    """
    from globeview.plugins.store_sources import is_store_url, open_store_url
    from globeview.terrain.embedded import store_path_for
    from globeview.terrain.ingest.driver import ingest

    if is_store_url(str(path)):
        # A store over HTTP: the manifest is fetched here, on the loader's thread (the
        # remote reader's timeouts and retries bound the wait; Cancel discards the result).
        store = open_store_url(str(path))
        try:
            warm_remote_store(store)
        except BaseException:
            store.close()
            raise
        return store
    p = Path(path)
    if p.is_dir():
        if (p / MANIFEST_NAME).exists():
            return TileStore.open(p)
        raise GlobeviewError(f"{p} is a folder but not a globeview tile store")
    if not p.exists():
        raise missing_path_error(p)
    out = store_path_for(p, vdatum=vdatum)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # $GLOBEVIEW_CACHE_DIR under a file, a read-only home, ...
        raise GlobeviewError(
            f"cannot ingest {p.name}: the cache folder {out.parent} cannot be made "
            f"({exc.strerror or exc}); set GLOBEVIEW_CACHE_DIR to a writable folder"
        ) from None
    ingest([p], out, vdatum=vdatum, **_ingest_kwargs(ingest, on_progress))
    return TileStore.open(out)


def warm_remote_store(store: TileStore) -> None:
    """Fetch, on the calling (loader) thread, what the window's UI thread reads of a remote
    store before any frame can have fetched it: the tiles of its blend mask (`BlendMask`, a
    few dozen coarse tiles, read whole the first time the layer is composed or selected).
    The UI thread never waits for the network (`MainWindow.add_store`), and a mask it could
    not build would fail the LOD selection; later reads (the border band's difference tables,
    tiles finer than the layer's data) are bounded without the tiles until they arrive.
    Raises `StoreError` (one line) when those tiles cannot be read: the layer is not added."""
    from globeview.terrain.compose.blend import BlendMask

    BlendMask(store)  # reads the mask level's tiles into the store's and the disk cache


def _ingest_kwargs(ingest_fn, on_progress) -> dict:
    """Pass a progress hook when ``ingest`` accepts one (forward compatible)."""
    if on_progress is not None and "on_progress" in inspect.signature(ingest_fn).parameters:
        return {"on_progress": on_progress}
    return {}


class DemLoader(QObject):
    """Loads DEMs one at a time in a worker thread.

    Signals (all delivered on the UI thread):
        started(str): a file's load began.
        progress(int, int): done / total steps of the running load (total 0: unknown).
        loaded(str, object): the path and its `TileStore`.
        failed(str, object): the path and the exception.
        cancelled(str): the load was cancelled (its result, if any, discarded).
        idle(): the queue is empty.
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
        self._queue: deque[tuple[str, str | None]] = deque()
        self._current: str | None = None
        self._future: Future | None = None
        self._cancel = threading.Event()
        self._done.connect(self._on_done)

    @property
    def busy(self) -> bool:
        return self._current is not None

    def load(self, path: str | Path, vdatum: str | None = None) -> None:
        """Queue a file (or store folder) for loading; ``vdatum`` overrides a DEM's vertical
        datum ("egm96", "ellipsoid"; None: from the file, see `globeview.terrain.dem.vdatum`)."""
        self._queue.append((str(path), vdatum))
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
        path, vdatum = self._queue.popleft()
        self._current = path
        self._cancel.clear()
        self.started.emit(path)
        self.progress.emit(0, 0)
        self._future = self._pool.submit(self._work, path, vdatum)

    def _work(self, path: str, vdatum: str | None = None) -> None:
        """Worker thread: never touches widgets, only emits signals."""

        def hook(done: int, total: int) -> None:
            if self._cancel.is_set():
                raise LoadCancelled
            self.progress.emit(int(done), int(total))

        try:
            store = open_store(path, hook, vdatum)
        except BaseException as exc:  # noqa: BLE001  delivered to the UI thread, never lost
            self._done.emit(path, None, exc)
            return
        self._done.emit(path, store, None)

    def _on_done(self, path: str, store: object, exc: object) -> None:
        self._current = None
        self._future = None
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
