"""Read access to a tile-pyramid store written by `globeview.terrain.ingest.driver`.

A store (format 7, `globeview.terrain.store.layout`) is a directory with ``manifest.json``,
per level a grid-registered raster of the whole globe (EPSG:4326, float32, NaN = no data)
stored as chunk files ``chunks/LL/<cy>/<cx>-<h16>.tif`` on the global chunk grid, only where
there is data, mosaicked over the level's bbox by ``level_LL.vrt``, and metadata shards
``meta/...gvm`` with the per-tile facts (`metadata.StoreMetadata`). Tile (L, x, y) is the
(2^n+1) x (2^n+1) window of level L's global nodes at row y*2^n, column x*2^n.

Heights are metres; tile metadata (``error``, ``hmin``, ``hmax``, stride errors) are metres.

Where the files are is a store backend's business (`globeview.terrain.store.backend`): a
folder (`local.LocalFiles`), a URL served by any static HTTP server (``http(s)://host/path/
store``, `http.RemoteSource`: a remote chunk's bytes come by HTTP range requests through a
disk cache), or what an installed backend reads. Tiles are read from the level's chunk files
directly, the same way for every backend: only the chunks a
tile's window touches are opened. A tile that cannot be read is one `StoreError` line naming
the file (a remote one: its URL and the HTTP status).

The manifest's format is defined once, as typed dataclasses, in
`globeview.terrain.store.schema` (ingest writes a `StoreManifest`, this module reads one).

A store is recognised *positively*: its manifest carries ``"format": "globeview-tile-store"``
and a ``format_version``, which only globeview writes. Anything else with a ``manifest.json``
is somebody else's folder (`identify.identify` says which), and `TileStore.open` checks the manifest
against the schema and every level file's shape, geotransform and dtype before it serves a
tile, so a damaged store is one `StoreError` line, never a traceback.
"""

from __future__ import annotations

import contextlib
import json
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import rasterio

from globeview.errors import GlobeviewError, StoreError
from globeview.terrain.levels import LevelGrid
from globeview.terrain.quadtree import TileKey
from globeview.terrain.store.backend import (
    RASTER_ERRORS,
    StoreFiles,
    TileNotReady,
    claimants,
    report_failure,
)
from globeview.terrain.store.blocks import BlockReader
from globeview.terrain.store.coverage import read_coverage
from globeview.terrain.store.handles import ChunkHandles, short_error
from globeview.terrain.store.identify import MANIFEST_NAME
from globeview.terrain.store.layout import generation_manifest_name
from globeview.terrain.store.local import LocalFiles
from globeview.terrain.store.metadata import ChunkFacts, StoreMetadata
from globeview.terrain.store.prefetch import Prefetcher
from globeview.terrain.store.schema import (
    DENSE_FORMAT_VERSIONS,
    FORMAT_VERSION,
    ManifestError,
    PoleHeights,
    StoreHeader,
    StoreManifest,
    built_before_vdatums,
)

__all__ = ["TileStore"]

DEFAULT_CACHE_TILES = 256


def _check_level_file(path: str, ds: rasterio.DatasetReader, grid: LevelGrid) -> None:
    """StoreError unless ``ds`` is the level VRT the manifest describes for ``grid`` (the
    level's bbox)."""
    want = grid.transform
    if (
        (ds.width, ds.height) != (grid.width, grid.height)
        or ds.count != 1
        or ds.dtypes[0] != "float32"
        or not ds.transform.almost_equals(want, precision=grid.d * 1e-6)
    ):
        raise StoreError(
            f"{path} does not match the store's manifest ({ds.width}x{ds.height} "
            f"{ds.dtypes[0]}, expected {grid.width}x{grid.height} float32 at the level's "
            "geotransform); re-run globeview ingest --force"
        )


def open_files(text: str, options: Any = None) -> StoreFiles:
    """The files of the store ``text`` names: from the first store backend that claims it
    and opens it (`backend.claimants`, in priority order); a path nobody claims is taken as a
    folder, whose backend says in one line why it is not a store. A backend that fails with
    anything but a one-line `GlobeviewError` is reported and skipped, like a failed plugin
    (StoreError naming it when no other backend opens the text)."""
    crashed: tuple[str, BaseException] | None = None
    for name, backend in claimants(text):
        try:
            files = backend.open(text, options)
            if not isinstance(files, StoreFiles):
                raise TypeError(f"open() returned {type(files).__name__}, not StoreFiles")
        except GlobeviewError:
            raise  # the backend's one line: not a store, unreachable, ...
        except Exception as exc:  # noqa: BLE001  a failing backend is skipped, like a plugin
            report_failure(name, "open", exc)
            crashed = crashed or (name, exc)
            continue
        return files
    if crashed is not None:
        who, why = crashed
        raise StoreError(
            f"cannot open {text}: store backend {who} failed ({type(why).__name__}: "
            f"{short_error(why)})"
        )
    return LocalFiles(Path(text))


def _checked_manifest(where: str, raw: dict[str, object]) -> StoreManifest:
    """The manifest of the store at ``where`` (a folder or URL) from its parsed JSON, checked:
    the format version this globeview reads, then the whole schema (StoreError one line)."""
    version = StoreHeader.peek(raw).format_version
    if built_before_vdatums(version):
        raise StoreError(
            f"{where}: store built before vertical datums (format version {version}, heights"
            " not ellipsoidal); rebuild it with globeview ingest --force"
        )
    if version in DENSE_FORMAT_VERSIONS and type(version) is int:
        raise StoreError(
            f"{where}: store of format version {version} (dense levels, an older globeview; "
            f"this one reads {FORMAT_VERSION}); rebuild it with globeview ingest --force"
        )
    if version != FORMAT_VERSION:  # a bool (0/1) is never the current version
        raise StoreError(
            f"{where}: store format version {str(version)[:20]} is not supported (this "
            f"globeview reads version {FORMAT_VERSION}); re-run globeview ingest --force"
        )
    try:
        return StoreManifest.from_json(raw)
    except ManifestError as exc:
        raise StoreError(f"{where}: damaged {MANIFEST_NAME} ({short_error(exc)})") from None


class TileStore:
    """A tile pyramid on disk or elsewhere. Open with `TileStore.open(path)`; thread-safe
    reads.

    Made of parts with one job each: the manifest's lookups (`metadata.StoreMetadata`), each
    thread's open chunk files (`handles.ChunkHandles`), block reads and their cache
    (`blocks.BlockReader`) and the background work (`prefetch.Prefetcher`); the store itself
    opens, keeps the LRU of read tiles and closes. Its files come from a store backend
    (`backend.StoreFiles`).

    Attributes:
        path: the store directory (a remote store: its URL's path, so ``path.name`` names
            it too).
        url: the store's URL (no trailing slash) when it is read over HTTP, else None.
        location: the folder or the URL, for people.
        manifest: the checked manifest (`StoreManifest`: sources with their vertical datums,
            ingest parameters, levels with their per-tile metadata).
        tile_n: tiles have 2^tile_n node intervals a side.
        tile_size: samples per tile side, 2^tile_n + 1.
        max_level: finest level.
        strides: the sample strides of `tile_stride_error`'s columns 1..
        bounds: data footprint (west, south, east, north), degrees; west > east crosses the
            antimeridian.
        pole_heights: {"north": metres or None, "south": metres or None}: the single height of
            each pole point when the data reaches it (every level's pole row holds it).
    """

    def __init__(
        self, files: StoreFiles, manifest: StoreManifest, cache_tiles: int = DEFAULT_CACHE_TILES
    ) -> None:
        self.path = files.path
        self.url: str | None = files.base_url
        self.location = files.location
        self._files = files
        self.manifest = manifest
        self.tile_n = manifest.tile_n
        self.max_level = manifest.max_level
        self.strides: tuple[int, ...] = manifest.strides
        w, s, e, n = manifest.bounds
        self.bounds: tuple[float, float, float, float] = (w, s, e, n)
        self.pole_heights = (manifest.pole_heights or PoleHeights()).as_dict()
        self.tile_size = (1 << self.tile_n) + 1
        self._meta = StoreMetadata(manifest, files.read_small, files.describe)
        self._meta_pool: ThreadPoolExecutor | None = None
        self._meta.background = self._fetch_shard
        self._meta.load_top()  # the top shard: levels 0..c0+1 and where the others are
        if files.check_on_open:  # a local store checks its level VRTs now (cheap)
            for level in range(self.max_level + 1):
                try:
                    self._check_level_files(level)
                except StoreError:
                    if not self._vrt_of_other_generation(level):
                        raise
        self._handles = ChunkHandles(files, self._meta)
        self._blocks = BlockReader(self._handles, self._meta, self.tile_size)
        self._prefetch = Prefetcher(
            files, self._meta, self._handles, self._blocks, self.heights, str(self.path)
        )
        self._cache: OrderedDict[TileKey, np.ndarray] = OrderedDict()
        self._cache_tiles = max(1, int(cache_tiles))
        self._lock = threading.Lock()
        self._closed = False

    # -- opening ---------------------------------------------------------------------------

    @classmethod
    def open(
        cls,
        path: str | Path,
        cache_tiles: int = DEFAULT_CACHE_TILES,
        remote_options: Any = None,
    ) -> TileStore:
        """Open the store ``path`` names through the store backend that claims it
        (`open_files`): a folder, an ``http(s)://`` URL (read over HTTP with
        ``remote_options``, default `http.RemoteOptions()`), or what an installed backend
        reads. Reads only the manifest (fast); no checksum pass.

        Raises:
            StoreError: not a directory, no/unreadable/corrupt manifest, unsupported
                format_version, or a missing level file; for a URL: unreachable, HTTP 404
                (not a store) or another HTTP error, a manifest over its size bound.
        """
        return cls.from_files(open_files(str(path), remote_options), cache_tiles)

    @classmethod
    def from_files(cls, files: StoreFiles, cache_tiles: int = DEFAULT_CACHE_TILES) -> TileStore:
        """The store whose files ``files`` are: its manifest read, parsed and checked (the
        same checks, in the same words, for every backend)."""
        name = MANIFEST_NAME
        data = files.read_manifest(name)
        try:
            raw = json.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, ValueError, RecursionError) as exc:
            raise StoreError(
                f"{files.describe(name)}: unreadable manifest ({type(exc).__name__})"
            ) from None
        if not isinstance(raw, dict):
            raise StoreError(f"{files.describe(name)}: unreadable manifest (not a JSON object)")
        if not files.is_ours(raw):
            raise StoreError(f"{files.location} is not a globeview tile store ({name} is not ours)")
        return cls(files, _checked_manifest(files.location, raw), cache_tiles)

    @property
    def is_remote(self) -> bool:
        """Whether the store is read over a network (its tiles may not be here yet)."""
        return bool(self._files.is_remote)

    @property
    def max_requests(self) -> int:
        """Reads the store's backend may have in flight at once (a remote store's
        `RemoteOptions.max_requests`; 1 for a local one)."""
        return max(1, int(self._files.max_requests))

    @property
    def offline(self) -> bool:
        """A remote store opened from its cached manifest (the server could not be reached):
        only tiles whose chunk bytes are in the disk cache load."""
        return bool(self._files.offline)

    def forbid_network_on(self, thread_ident: int) -> None:
        """Reads on this thread (a window's UI thread) never wait on the network: a tile of a
        remote store whose bytes are not cached raises `TileNotReady` at once and is
        loaded in the background (a later call finds it cached). No effect on a local store."""
        self._files.forbid_network_on(thread_ident)

    def verify(self, full: bool = True) -> int:
        """Check every store file the manifest and shards record (level VRTs, shards as they
        load, each chunk file): its size, and with ``full`` its sha256 (reads all data).
        Returns the number of chunk files checked.

        Raises StoreError naming the first file that does not match.
        """
        checked = 0
        for lv in self._meta.levels:
            try:
                self._check_file(lv.file, lv.sha256, None, full)
            except StoreError:
                if not self._vrt_of_other_generation(lv.level):
                    raise
        for _lv, _cy, _cx, facts in self.iter_chunks():
            if facts.file is not None:
                self._check_file(facts.file, facts.sha256, facts.bytes, full)
                checked += 1
        return checked

    def _check_file(self, name: str, sha256: str, size: int | None, full: bool) -> None:
        if size is not None and self._files.size(name) != size:
            raise StoreError(
                f"{self._files.describe(name)} is damaged (size mismatch); re-run globeview "
                "ingest --force"
            )
        if full and self._files.sha256(name) != sha256:
            raise StoreError(
                f"{self._files.describe(name)} is damaged (checksum mismatch); re-run "
                "globeview ingest --force"
            )

    def iter_chunks(self) -> Iterator[tuple[int, int, int, ChunkFacts]]:
        """(level, cy, cx, facts) of every chunk record of the store, shard by shard from the
        top (reads every shard): the per-tile facts a whole-store comparison or report needs.
        ``facts.errors[j, i]`` etc. are tile (cx * k + i, cy * k + j) of the level, k =
        ``manifest.chunk_tiles``; NaN where a tile has no data."""
        return self._meta.iter_chunks()

    def _fetch_shard(self, job: Callable[[], None]) -> None:
        """Run a metadata shard's fetch on the store's shard thread (a remote store read on a
        thread that must not wait)."""
        if getattr(self, "_closed", False):
            return
        if self._meta_pool is None:
            self._meta_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="shards")
        with contextlib.suppress(RuntimeError):  # shut down: the store is closing
            self._meta_pool.submit(job)

    @property
    def shards_loaded(self) -> int:
        """Metadata shards read so far (the top one at open)."""
        return self._meta.shards_loaded

    # -- metadata (the manifest's lookups, `StoreMetadata`) -----------------------------------

    def level_grid(self, level: int) -> LevelGrid:
        """The level's bbox (the tiles of its chunks with data) as a raster geometry."""
        return self._meta.level_grid(level)

    def level_error(self, level: int) -> float | None:
        """Largest tile error of a level (metres)."""
        return self._meta.level_error(level)

    def has_data(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """Bool array: tile inside the level's extent and not all NaN (False beyond
        max_level)."""
        return self._meta.has_data(level, x, y)

    def tile_error(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """Geometric error (metres, float32): max |tile bilinear surface - finest data| over
        the tile. NaN where there is no tile."""
        return self._meta.tile_error(level, x, y)

    def tile_hrange(
        self, level: int, x: np.ndarray | int, y: np.ndarray | int
    ) -> tuple[np.ndarray, np.ndarray]:
        """(hmin, hmax) of the tiles' samples, metres, float32 (NaN where no tile)."""
        return self._meta.tile_hrange(level, x, y)

    def tile_stride_error(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """(..., 7) float32 upper bounds (metres) on the max deviation from the finest data of
        the tile drawn every 1, 2, 4, ..., 64 samples (column 0 = the tile error)."""
        return self._meta.tile_stride_error(level, x, y)

    def has_tile(self, level: int, x: int, y: int) -> bool:
        """`has_data` for one tile, without numpy's per-call overhead (the compose path asks
        it for every layer of every tile)."""
        return self._meta.has_tile(level, x, y)

    def has_data_near(self, level: int, x: int, y: int) -> bool:
        """Whether the tile or any of its 8 same-level neighbours has data (a tile's ring of
        neighbour nodes may hold data when the tile itself has none)."""
        return self._meta.has_data_near(level, x, y)

    def coverage(self, level: int) -> np.ndarray:
        """Which nodes of ``level`` hold data over the level's bbox (`level_grid`): a bool
        raster, rows north to south (`coverage.read_coverage`). From the top shard when the
        ingest stored that level's there (no chunk read: a remote store's first frame needs
        none), else read from the level's tiles."""
        stored = self._meta.coverage
        grid = self._meta.grids[level] if 0 <= level <= self.max_level else None
        if stored is not None and grid is not None and stored.level == level:
            cells = self.tile_size - 1
            shape = (grid.ny * cells + 1, grid.nx * cells + 1)
            if (stored.row0, stored.col0) == (grid.y0 * cells, grid.x0 * cells) and (
                stored.bits.shape == shape
            ):
                return stored.bits
        return read_coverage(self, level).bits

    # -- heights -------------------------------------------------------------------------------

    def _check_level_files(self, level: int) -> None:
        """Check that a level's files are there and its raster (the VRT) is the one the
        manifest describes (StoreError naming the file)."""
        files, lv = self._files, self._meta.levels[level]
        if not files.exists(lv.file):
            raise StoreError(
                f"{files.describe(lv.file)}: level file is missing; re-run globeview ingest --force"
            )
        where = files.describe(lv.file)
        try:
            ds = files.open_raster(lv.file, lv.sha256)
        except RASTER_ERRORS as exc:
            raise StoreError(f"{where} is damaged: {short_error(exc)}") from None
        try:
            _check_level_file(where, ds, self._meta.grids[level])
        finally:
            files.close_raster(ds)

    def _vrt_of_other_generation(self, level: int) -> bool:
        """Whether a level VRT that does not match this manifest is the previous or the next
        generation's (or not there yet, or gone with it): an update replaces the VRTs just
        after it switches ``manifest.json`` (`generations.commit_generation`), so a reader
        opening in between, or a store whose update was killed there, has the previous
        generation's, and a reader that opened the manifest just before an update's switch
        may find the next one's. Tiles are never read through the VRTs: the store is sound."""
        g = self.manifest.generation
        for other in (g - 1, g + 1):
            if other < 0:
                continue
            try:
                raw = self._files.read_manifest(generation_manifest_name(other))
                m = StoreManifest.from_json(json.loads(raw))
            except (StoreError, ValueError, ManifestError, RecursionError):
                continue  # (a JSON or UTF-8 error is a ValueError)
            if level >= len(m.levels):
                return True
            try:
                if self._files.sha256(m.levels[level].file) == m.levels[level].sha256:
                    return True
            except StoreError:
                continue
        return False

    def heights_padded(self, key: TileKey | tuple[int, int, int]) -> np.ndarray:
        """A tile's heights with one node beyond each edge ((tile_size + 2)^2 float32 metres,
        NaN = no data; see `BlockReader.read_padded`), from the same LRU cache as `heights`;
        read-only and shared."""
        key = TileKey(*key)
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        try:
            tile = self._blocks.read_padded(key)
        except TileNotReady:
            # On a thread that must not wait (`forbid_network_on`): load it in the
            # background; the caller shows it as loading and asks again.
            self._prefetch.load_later(key)
            raise
        tile.flags.writeable = False
        with self._lock:
            self._cache[key] = tile
            self._cache.move_to_end(key)
            while len(self._cache) > self._cache_tiles:
                self._cache.popitem(last=False)
        return tile

    def heights(self, key: TileKey | tuple[int, int, int]) -> np.ndarray:
        """Heights (metres) of a tile's (tile_size x tile_size) nodes, float32, NaN = no data.

        Row r, column c is the node at lon = west + c*d, lat = north - r*d. Served from an
        LRU cache (thread-safe); the returned array is read-only and shared (a view of the
        padded tile `heights_padded` caches: one window read serves both).
        """
        return self.heights_padded(key)[1:-1, 1:-1]

    def cached(self, key: TileKey | tuple[int, int, int]) -> bool:
        """Whether a tile is in the cache now."""
        with self._lock:
            return TileKey(*key) in self._cache

    @property
    def blocks_read(self) -> int:
        """Raster blocks read from chunk files so far (each counted once per read, not per
        cache hit): 0 after a render means no byte of terrain arrived from this store."""
        return self._blocks.blocks_read

    # -- background work (`Prefetcher`) --------------------------------------------------------

    def prefetch(self, keys: Iterable[TileKey | tuple[int, int, int]]) -> list[Future]:
        """Load tiles into the cache in background threads; returns their futures."""
        return self._prefetch.prefetch(keys)

    def prefetch_bytes(self, keys: Iterable[TileKey | tuple[int, int, int]]) -> list[Future]:
        """A remote store: fetch the compressed bytes of the blocks these tiles need into its
        caches, several requests at once (`Prefetcher.prefetch_bytes`); returns the futures
        of the blocks queued (none for a local store)."""
        return self._prefetch.prefetch_bytes(keys)

    # -- lifetime --------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the prefetch threads and close every dataset handle (a remote store first
        cancels its HTTP reads, so a slow server does not hold the close)."""
        self._closed = True
        self._prefetch.closed = self._handles.closed = True  # nothing new from here on
        self._files.close()
        if self._meta_pool is not None:
            self._meta_pool.shutdown(wait=True, cancel_futures=True)
        self._prefetch.close()
        self._handles.close()
        with self._lock:
            self._cache.clear()
        self._blocks.clear()

    def __enter__(self) -> TileStore:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
