"""A store's background work: tiles loaded into its cache on worker threads (`prefetch`), a
tile a no-wait thread asked for loaded once in the background (`load_later`), and for a
remote store the compressed bytes of the blocks tiles need fetched several requests at once
(`prefetch_bytes`)."""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from globeview.errors import StoreError
from globeview.terrain.quadtree import TileKey
from globeview.terrain.store.backend import RASTER_ERRORS, StoreFiles, take_error
from globeview.terrain.store.blocks import BlockKey, BlockReader
from globeview.terrain.store.handles import ChunkHandles
from globeview.terrain.store.metadata import StoreMetadata

__all__ = ["Prefetcher"]

# What warming a block may meet (the loader's own read reports it).
_WARM_ERRORS: tuple[type[BaseException], ...] = (StoreError, *RASTER_ERRORS, ValueError)


class Prefetcher:
    """The thread pools of one store and what they were asked for.

    ``load(key)`` is the store's cached tile read (`TileStore.heights`); ``where`` names the
    store in messages.

    Attributes:
        loading: tiles loading in the background for a thread that must not wait.
        closed: set by `close`.
    """

    def __init__(
        self,
        files: StoreFiles,
        meta: StoreMetadata,
        handles: ChunkHandles,
        blocks: BlockReader,
        load: Callable[[TileKey], np.ndarray],
        where: str,
    ) -> None:
        self._files = files
        self._meta = meta
        self._handles = handles
        self._blocks = blocks
        self._load = load
        self._where = where
        self._lock = threading.Lock()
        self._pool: ThreadPoolExecutor | None = None
        #: `prefetch_bytes`: its threads, the tiles and the blocks it was asked for.
        self._bytes_pool: ThreadPoolExecutor | None = None
        self._keys_asked: set[tuple[int, int, int]] = set()
        self._bytes_asked: set[BlockKey] = set()
        self.loading: set[TileKey] = set()
        self.closed = False

    def prefetch(self, keys: Iterable[TileKey | tuple[int, int, int]]) -> list[Future]:
        """Load tiles into the cache in background threads; returns their futures."""
        if self.closed:
            raise StoreError(f"{self._where}: the store is closed")
        with self._lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="tileload")
            pool = self._pool
        return [pool.submit(self._load, TileKey(*k)) for k in keys]

    def load_later(self, key: TileKey) -> None:
        """Load a tile in the background for a thread that must not wait (once, however
        often it is asked meanwhile: a cursor moving over it asks every frame)."""
        with self._lock:
            fresh = key not in self.loading and not self.closed
            self.loading.add(key)
        if fresh:
            (future,) = self.prefetch([key])
            future.add_done_callback(functools.partial(self._loaded, key))

    def _loaded(self, key: TileKey, _future: Future) -> None:
        with self._lock:
            self.loading.discard(key)

    def prefetch_bytes(self, keys: Iterable[TileKey | tuple[int, int, int]]) -> list[Future]:
        """A remote store: fetch the compressed bytes of the blocks these tiles need, several
        requests at once (`StoreFiles.max_requests` threads), into the caches, decoding
        nothing: the tile loader, which builds one tile at a time, then finds them there
        instead of paying a round trip per page in turn. Returns the futures of the blocks
        queued (none for a local store, or when every block was asked for before).

        Cheap on the calling thread (the renderer's, each frame while tiles are missing):
        tile-to-block geometry only, keys seen before skipped; chunk headers are opened in
        the background threads. Failures are left to the loader's reads (one line each)."""
        files = self._files
        if not files.is_remote or self.closed:
            return []
        todo: list[BlockKey] = []
        with self._lock:
            if len(self._bytes_asked) > 200_000:  # a long session: forget, re-ask is cheap
                self._bytes_asked.clear()
                self._keys_asked.clear()
            for k in keys:
                key = (int(k[0]), int(k[1]), int(k[2]))
                if key in self._keys_asked:
                    continue
                self._keys_asked.add(key)
                for block in self._blocks.tile_blocks(key):
                    if block not in self._bytes_asked and not self._blocks.holds(block):
                        self._bytes_asked.add(block)
                        todo.append(block)
            if not todo:
                return []
            if self._bytes_pool is None:
                self._bytes_pool = ThreadPoolExecutor(
                    max_workers=max(1, files.max_requests), thread_name_prefix="tilebytes"
                )
            pool = self._bytes_pool
        return [pool.submit(self._warm_block, *block) for block in todo]

    def _warm_block(self, level: int, index: int, bi: int, bj: int) -> None:
        """Fetch one block's compressed bytes into the remote caches (a background thread)."""
        files = self._files
        if self.closed or not files.is_remote:
            return
        try:
            ds = self._handles.dataset(level, index)  # the chunk's header: its block offsets
            off = ds.get_tag_item(f"BLOCK_OFFSET_{bj}_{bi}", "TIFF", bidx=1)
            size = ds.get_tag_item(f"BLOCK_SIZE_{bj}_{bi}", "TIFF", bidx=1)
            if off and size:
                files.warm(self._meta.chunk_name(level, index), int(off), int(size))
        except _WARM_ERRORS:
            pass  # the loader's own read reports it (one line), or finds the bytes later
        take_error()

    def close(self) -> None:
        """Stop the threads (the running tasks finish; queued ones are dropped)."""
        self.closed = True
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self._bytes_pool is not None:
            self._bytes_pool.shutdown(wait=True, cancel_futures=True)
            self._bytes_pool = None
