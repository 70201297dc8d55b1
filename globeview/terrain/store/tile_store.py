"""Read access to a tile-pyramid store written by `globeview.terrain.ingest.driver`.

A store is a directory with ``manifest.json`` and, per level, one grid-registered raster
(EPSG:4326, float32, NaN = no data) split into chunk files ``level_LL_rRRRR_cCCCC.tif``
mosaicked by ``level_LL.vrt`` (since format 5, `globeview.terrain.store.level_chunks`). Tile
(L, x, y) is the (2^n+1) x (2^n+1) window of level L's raster starting at row (y - y0)*2^n
and column ((x - x0) mod 2^(L+1))*2^n, where (x0, y0, nx, ny) is the level's tile extent.

Heights are metres; tile metadata (``error``, ``hmin``, ``hmax``, stride errors) are metres.

Where the files are is a store backend's business (`globeview.terrain.store.backend`): a
folder (`local.LocalFiles`), a URL served by any static HTTP server (``http(s)://host/path/
store``, `http.RemoteSource`: a remote chunk's bytes come by HTTP range requests through a
disk cache), or what an installed backend reads. Tiles are read from the level's chunk files
(``level_LL_rRRRR_cCCCC.tif``) directly, the same way for every backend: only the chunks a
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

import functools
import json
import threading
from collections import OrderedDict
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np
import rasterio
from affine import Affine
from rasterio.windows import Window

from globeview.errors import GlobeviewError, StoreError
from globeview.terrain.levels import LevelGrid
from globeview.terrain.quadtree import TileKey
from globeview.terrain.store.backend import (
    RASTER_ERRORS,
    StoreFiles,
    TileNotReady,
    claimants,
    raise_interrupt,
    report_failure,
    take_error,
)
from globeview.terrain.store.identify import MANIFEST_NAME
from globeview.terrain.store.level_chunks import BLOCK, chunk_window
from globeview.terrain.store.local import LocalFiles
from globeview.terrain.store.schema import (
    FORMAT_VERSION,
    LevelRecord,
    ManifestError,
    PoleHeights,
    StoreHeader,
    StoreManifest,
    built_before_vdatums,
    chunk_file_name,
    chunk_grid_shape,
)

__all__ = ["TileStore"]

DEFAULT_CACHE_TILES = 256
#: Decoded raster blocks a store keeps (256 x 256 float32: 256 KB each, so 16 MB).
BLOCK_CACHE = 64
#: Chunk datasets a thread keeps open (least recently used closed first).
HANDLES_PER_THREAD = 32
# The per-tile arrays of a `LevelRecord` that `TileStore._lookup` serves.
_TileArray = Literal["error", "hmin", "hmax", "stride_error"]

# Reading a window of a level file damaged after the store was opened.
_READ_ERRORS: tuple[type[BaseException], ...] = (*RASTER_ERRORS, ValueError)

# What warming a block may meet (the loader's own read reports it).
_WARM_ERRORS: tuple[type[BaseException], ...] = (StoreError, *_READ_ERRORS)


def _short(exc: BaseException) -> str:
    """First line of an exception's message, at most 160 characters."""
    text = str(exc).strip()
    text = text.splitlines()[0] if text else type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."


def _check_level_file(path: str, ds: rasterio.DatasetReader, grid: LevelGrid) -> None:
    """StoreError unless ``ds`` is the raster the manifest describes for ``grid``."""
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
            f"cannot open {text}: store backend {who} failed ({type(why).__name__}: {_short(why)})"
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
    if version != FORMAT_VERSION:  # a bool (0/1) is never the current version
        raise StoreError(
            f"{where}: store format version {str(version)[:20]} is not supported (this "
            f"globeview reads version {FORMAT_VERSION}); re-run globeview ingest --force"
        )
    try:
        return StoreManifest.from_json(raw)
    except ManifestError as exc:
        raise StoreError(f"{where}: damaged {MANIFEST_NAME} ({_short(exc)})") from None


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


class TileStore:
    """A tile pyramid on disk. Open with `TileStore.open(path)`; thread-safe reads.

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
        self._levels: tuple[LevelRecord, ...] = manifest.levels
        self._grids = [lv.grid(self.tile_n) for lv in self._levels]
        self._ncols = [g.ncols for g in self._grids]  # (a property computed on each use)
        # Chunk (cy, cx) of each level -> its index in the level's `chunks` (a missing one
        # reads as NaN), and the chunk grid's shape.
        self._chunk_index = [
            {(int(cy), int(cx)): i for i, (cy, cx) in enumerate(lv.chunks)} for lv in self._levels
        ]
        self._chunk_shape = [
            chunk_grid_shape(g, lv.chunk_nodes) for g, lv in zip(self._grids, self._levels)
        ]
        if files.check_on_open:  # a local store checks its files now (cheap); others on use
            for level in range(self.max_level + 1):
                self._check_level_files(level)
        self.tile_size = (1 << self.tile_n) + 1
        self._cache: OrderedDict[TileKey, np.ndarray] = OrderedDict()
        self._cache_tiles = max(1, int(cache_tiles))
        self._lock = threading.Lock()
        self._local = threading.local()
        self._all_handles: set[rasterio.DatasetReader] = set()
        #: GDAL block shape of each chunk file opened so far, by (level, chunk index).
        self._block_shapes: dict[tuple[int, int], tuple[int, int]] = {}
        self._pool: ThreadPoolExecutor | None = None
        #: `prefetch_bytes`: its threads, the tiles and the blocks it was asked for.
        self._bytes_pool: ThreadPoolExecutor | None = None
        self._keys_asked: set[tuple[int, int, int]] = set()
        self._bytes_asked: set[tuple[int, int, int, int]] = set()
        self._closed = False
        #: Decoded blocks by (level, chunk index, block row, block column).
        self._blocks: OrderedDict[tuple[int, int, int, int], np.ndarray] = OrderedDict()
        #: Raster blocks read from chunk files so far (each counted once per read, not per
        #: cache hit): 0 after a render means no byte of terrain arrived from this store.
        self.blocks_read = 0
        #: Tiles loading in the background for a thread that must not wait.
        self._loading: set[TileKey] = set()
        #: `_data_table`s by (level, grow); small, built on first use (races only rebuild).
        self._tables: dict[tuple[int, int], np.ndarray] = {}

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
    def offline(self) -> bool:
        """A remote store opened from its cached manifest (the server could not be reached):
        only tiles whose chunk bytes are in the disk cache load."""
        return bool(self._files.offline)

    def forbid_network_on(self, thread_ident: int) -> None:
        """Reads on this thread (a window's UI thread) never wait on the network: a tile of a
        remote store whose bytes are not cached raises `TileNotReady` at once and is
        loaded in the background (a later call finds it cached). No effect on a local store."""
        self._files.forbid_network_on(thread_ident)

    def verify(self) -> None:
        """Check every level file (the VRT and each chunk file) against its sha256 in the
        manifest (reads all data).

        Raises StoreError naming the first file that does not match.
        """
        for lv in self._levels:
            for name, want in ((lv.file, lv.sha256), *zip(lv.chunk_files(), lv.chunk_sha256)):
                if self._files.sha256(name) != want:
                    raise StoreError(
                        f"{self._files.describe(name)} is damaged (checksum mismatch); re-run "
                        "globeview ingest --force"
                    )

    # -- metadata (vectorised) ---------------------------------------------------------------

    def level_grid(self, level: int) -> LevelGrid:
        """Extent and raster geometry of a level."""
        return self._grids[level]

    def level_error(self, level: int) -> float | None:
        """Largest tile error of a level (metres)."""
        return self._levels[level].level_error

    def _lookup(
        self, level: int, x: np.ndarray | int, y: np.ndarray | int, attr: _TileArray
    ) -> np.ndarray:
        """A `LevelRecord` per-tile array at tiles (x, y), NaN outside the level's extent."""
        x_a, y_a = np.broadcast_arrays(np.asarray(x, dtype=np.int64), np.asarray(y, dtype=np.int64))
        if not (0 <= level <= self.max_level):
            tail = (len(self.strides),) if attr == "stride_error" else ()
            return np.full(x_a.shape + tail, np.nan)
        iy, ix, inside = self._grids[level].tile_slots(y_a, x_a)
        arr: np.ndarray = getattr(self._levels[level], attr)
        vals = arr[iy, ix]
        if vals.ndim > inside.ndim:
            return np.where(inside[..., None], vals, np.nan)
        return np.where(inside, vals, np.nan)

    def has_data(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """Bool array: tile inside the level's extent and not all NaN (False beyond
        max_level)."""
        if not (0 <= level <= self.max_level):
            return np.zeros(np.broadcast(np.asarray(x), np.asarray(y)).shape, dtype=bool)
        return np.isfinite(self._lookup(level, x, y, "hmin"))

    def tile_error(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """Geometric error (metres, float32): max |tile bilinear surface - finest data| over
        the tile. NaN where there is no tile."""
        return self._lookup(level, x, y, "error").astype(np.float32)

    def tile_hrange(
        self, level: int, x: np.ndarray | int, y: np.ndarray | int
    ) -> tuple[np.ndarray, np.ndarray]:
        """(hmin, hmax) of the tiles' samples, metres, float32 (NaN where no tile)."""
        return (
            self._lookup(level, x, y, "hmin").astype(np.float32),
            self._lookup(level, x, y, "hmax").astype(np.float32),
        )

    def tile_stride_error(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """(..., 7) float32 upper bounds (metres) on the max deviation from the finest data of
        the tile drawn every 1, 2, 4, ..., 64 samples (column 0 = the tile error)."""
        err = self._lookup(level, x, y, "error")
        if not (0 <= level <= self.max_level):
            stride = np.full((*err.shape, len(self.strides)), np.nan)
        else:
            stride = self._lookup(level, x, y, "stride_error")
        return np.concatenate([err[..., None], stride], axis=-1).astype(np.float32)

    # -- heights -------------------------------------------------------------------------------

    def _check_level_files(self, level: int) -> None:
        """Check that a level's files are there and its raster (the VRT) is the one the
        manifest describes (StoreError naming the file)."""
        files, lv = self._files, self._levels[level]
        for name in (lv.file, *lv.chunk_files()):
            if not files.exists(name):
                raise StoreError(
                    f"{files.describe(name)}: level file is missing; re-run globeview ingest "
                    "--force"
                )
        where = files.describe(lv.file)
        try:
            ds = files.open_raster(lv.file, lv.sha256)
        except RASTER_ERRORS as exc:
            raise StoreError(f"{where} is damaged: {_short(exc)}") from None
        try:
            _check_level_file(where, ds, self._grids[level])
        finally:
            files.close_raster(ds)

    def _open_chunk(self, level: int, index: int) -> rasterio.DatasetReader:
        """Open chunk ``index`` of a level (local or over HTTP), checked against the manifest;
        StoreError naming the file (a remote one: its URL and the HTTP status)."""
        lv = self._levels[level]
        cy, cx = (int(v) for v in lv.chunks[index])
        name = chunk_file_name(level, cy, cx)
        where = self._files.describe(name)
        grid = self._grids[level]
        take_error()
        try:
            ds = self._files.open_raster(name, lv.chunk_sha256[index])
        except RASTER_ERRORS as exc:
            err = take_error()
            if err is not None:
                raise err from None
            raise StoreError(f"{where} is damaged: {_short(exc)}") from None
        try:
            raise_interrupt()
            _check_chunk(where, ds, grid, chunk_window(grid, lv.chunk_nodes, cy, cx))
        except BaseException:
            ds.close()
            raise
        with self._lock:
            self._block_shapes[(level, index)] = ds.block_shapes[0]
        return ds

    def _chunk_where(self, level: int, index: int) -> str:
        """The path or URL of chunk ``index`` of a level, for messages."""
        cy, cx = (int(v) for v in self._levels[level].chunks[index])
        return self._files.describe(chunk_file_name(level, cy, cx))

    def _chunk_dataset(self, level: int, index: int) -> rasterio.DatasetReader:
        """This thread's handle on chunk ``index`` of a level (GDAL datasets are not
        thread-safe), opened on first use; a thread keeps its HANDLES_PER_THREAD most
        recently used ones open."""
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
        if self._closed:  # a worker thread still building after close() opens nothing
            raise StoreError(f"{self.location}: the store is closed")
        ds = self._open_chunk(level, index)
        with self._lock:
            if self._closed:  # close() ran while this thread was opening the file
                ds.close()
                raise StoreError(f"{self.location}: the store is closed")
            self._all_handles.add(ds)
        handles[key] = ds
        while len(handles) > HANDLES_PER_THREAD:
            self._close_handle(handles.popitem(last=False)[1])
        return ds

    def _drop_chunk_dataset(self, level: int, index: int) -> None:
        """Close this thread's handle on a chunk after a failed read (the next read opens
        it afresh: a server back up, a file replaced)."""
        handles = getattr(self._local, "handles", None)
        ds = handles.pop((level, index), None) if handles is not None else None
        if ds is not None:
            self._close_handle(ds)

    def _close_handle(self, ds: rasterio.DatasetReader) -> None:
        with self._lock:
            self._all_handles.discard(ds)
        self._files.close_raster(ds)

    def _read_padded(self, key: TileKey) -> np.ndarray:
        """A tile's nodes with one node beyond each edge: (tile_size + 2)^2 float32, NaN = no
        data. The interior is the tile (all NaN outside the level's extent, as `heights`
        serves it); the ring is the raster's next node on each side, which is the
        same-level neighbour's (neighbouring tiles share their edge nodes), wrapping across
        the antimeridian on a level that goes all the way round, NaN beyond the data."""
        size = self.tile_size
        out = np.full((size + 2, size + 2), np.nan, dtype=np.float32)
        if not (0 <= key.level <= self.max_level) or not 0 <= key.x < self._ncols[key.level]:
            return out  # no such tile (`heights` serves NaN, as it always did)
        grid = self._grids[key.level]
        n = grid.tile_nodes
        ncols = self._ncols[key.level]
        iy = key.y - grid.y0
        ix = (key.x - grid.x0) % ncols
        if not grid.global_lon and ix == ncols - 1 and grid.nx < ncols:
            ix = -1  # the tile just west of the extent: its east ring is the raster's column 1
        r0, c0 = iy * n - 1, ix * n - 1  # raster row/column of the padded window's corner
        r_lo, r_hi = max(r0, 0), min(r0 + size + 2, grid.height)
        c_lo, c_hi = max(c0, 0), min(c0 + size + 2, grid.width)
        if r_lo >= r_hi or c_lo >= c_hi:
            return out
        try:
            self._read_into(
                key.level, r_lo, c_lo, out[r_lo - r0 : r_hi - r0, c_lo - c0 : c_hi - c0]
            )
            if grid.global_lon:
                # Column -1 is the raster's column turn - 1, column turn + 1 its column 1
                # (column turn repeats column 0: -180 = +180).
                turn = ncols * n
                rows = slice(r_lo - r0, r_hi - r0)
                if c0 < 0:
                    self._read_into(key.level, r_lo, turn - 1, out[rows, :1])
                if c0 + size + 2 > grid.width:
                    self._read_into(key.level, r_lo, 1, out[rows, -1:])
        except TileNotReady:
            raise
        except StoreError as exc:
            # A chunk file damaged (truncated, rewritten) after the store was opened, or a
            # remote one that could not be fetched (the message names its URL and status).
            raise StoreError(f"cannot read tile {tuple(key)}: {exc}") from None
        # A node on the extent's edge belongs to the tile outside it too, which serves NaN:
        # blank each part of the window whose tile lies outside the extent.
        for dy, rows_ in ((-1, slice(0, 1)), (0, slice(1, size + 1)), (1, slice(size + 1, None))):
            for dx, cols_ in (
                (-1, slice(0, 1)),
                (0, slice(1, size + 1)),
                (1, slice(size + 1, None)),
            ):
                jx = ix + dx
                if grid.global_lon:
                    jx %= ncols
                if not (0 <= iy + dy < grid.ny and 0 <= jx < grid.nx):
                    out[rows_, cols_] = np.nan
        return out

    def _read_into(self, level: int, row: int, col: int, out: np.ndarray) -> None:
        """Fill ``out`` with the level raster's nodes from (row, col) on, chunk by chunk (a
        tile's padded window touches up to 4 chunks: its last row/column and its ring may
        lie in the next ones); a chunk without a file (all NaN) reads as NaN."""
        grid = self._grids[level]
        c_n = self._levels[level].chunk_nodes
        rows_c, cols_c = self._chunk_shape[level]
        h, w = out.shape
        for cy in range(min(row // c_n, rows_c - 1), min((row + h - 1) // c_n, rows_c - 1) + 1):
            cr0 = cy * c_n
            cr1 = grid.height if cy == rows_c - 1 else cr0 + c_n
            r_a, r_b = max(row, cr0), min(row + h, cr1)
            for cx in range(min(col // c_n, cols_c - 1), min((col + w - 1) // c_n, cols_c - 1) + 1):
                cc0 = cx * c_n
                cc1 = grid.width if cx == cols_c - 1 else cc0 + c_n
                c_a, c_b = max(col, cc0), min(col + w, cc1)
                part = out[r_a - row : r_b - row, c_a - col : c_b - col]
                index = self._chunk_index[level].get((cy, cx))
                if index is None:
                    part[...] = np.nan
                else:
                    self._read_chunk(level, index, r_a - cr0, c_a - cc0, part)

    def _read_chunk(self, level: int, index: int, row: int, col: int, out: np.ndarray) -> None:
        """Fill ``out`` with chunk ``index``'s nodes from (row, col) of the chunk on, from
        whole GDAL blocks kept decoded in `_blocks`: a tile window spans up to 4 blocks, and
        a view's tiles share them (a 67 x 67 window read cost ~0.11 ms, a copy out of cached
        blocks ~0.01 ms; each 256 x 256 block is read and inflated once). The chunk's file
        is opened only when a block is not cached."""
        shape = self._block_shapes.get((level, index))
        if shape is None:
            shape = self._chunk_dataset(level, index).block_shapes[0]
        bh, bw = shape
        h, w = out.shape
        for bi in range(row // bh, (row + h - 1) // bh + 1):
            for bj in range(col // bw, (col + w - 1) // bw + 1):
                block = self._block(level, index, bi, bj, bh, bw)
                r_a, r_b = max(row, bi * bh), min(row + h, (bi + 1) * bh)
                c_a, c_b = max(col, bj * bw), min(col + w, (bj + 1) * bw)
                out[r_a - row : r_b - row, c_a - col : c_b - col] = block[
                    r_a - bi * bh : r_b - bi * bh, c_a - bj * bw : c_b - bj * bw
                ]

    def _block(self, level: int, index: int, bi: int, bj: int, bh: int, bw: int) -> np.ndarray:
        """GDAL block (bi, bj) of a chunk file, decoded (an LRU of BLOCK_CACHE blocks)."""
        key = (level, index, bi, bj)
        with self._lock:
            hit = self._blocks.get(key)
            if hit is not None:
                self._blocks.move_to_end(key)
                return hit
        ds = self._chunk_dataset(level, index)
        r0, c0 = bi * bh, bj * bw
        window = Window(c0, r0, min(bw, ds.width - c0), min(bh, ds.height - r0))
        take_error()
        try:
            block = ds.read(1, window=window)
        except _READ_ERRORS as exc:
            self._drop_chunk_dataset(level, index)
            err = take_error()
            if err is not None:
                raise err from None
            raise StoreError(f"{self._chunk_where(level, index)}: {_short(exc)}") from None
        raise_interrupt()
        with self._lock:
            self.blocks_read += 1
            self._blocks[key] = block
            while len(self._blocks) > BLOCK_CACHE:
                self._blocks.popitem(last=False)
        return block

    def heights_padded(self, key: TileKey | tuple[int, int, int]) -> np.ndarray:
        """A tile's heights with one node beyond each edge ((tile_size + 2)^2 float32 metres,
        NaN = no data; see `_read_padded`), from the same LRU cache as `heights`; read-only
        and shared."""
        key = TileKey(*key)
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        try:
            tile = self._read_padded(key)
        except TileNotReady:
            # On a thread that must not wait (`forbid_network_on`): load it in the
            # background (once, however often it is asked meanwhile: a cursor moving over
            # it asks every frame); the caller shows it as loading and asks again.
            with self._lock:
                fresh = key not in self._loading and not self._closed
                self._loading.add(key)
            if fresh:
                (future,) = self.prefetch([key])
                future.add_done_callback(functools.partial(self._loaded, key))
            raise
        tile.flags.writeable = False
        with self._lock:
            self._cache[key] = tile
            self._cache.move_to_end(key)
            while len(self._cache) > self._cache_tiles:
                self._cache.popitem(last=False)
        return tile

    def _loaded(self, key: TileKey, _future: Future) -> None:
        with self._lock:
            self._loading.discard(key)

    def heights(self, key: TileKey | tuple[int, int, int]) -> np.ndarray:
        """Heights (metres) of a tile's (tile_size x tile_size) nodes, float32, NaN = no data.

        Row r, column c is the node at lon = west + c*d, lat = north - r*d. Served from an
        LRU cache (thread-safe); the returned array is read-only and shared (a view of the
        padded tile `heights_padded` caches: one window read serves both).
        """
        return self.heights_padded(key)[1:-1, 1:-1]

    def has_tile(self, level: int, x: int, y: int) -> bool:
        """`has_data` for one tile, without numpy's per-call overhead (the compose path asks
        it for every layer of every tile)."""
        return self._table_lookup(level, x, y, 0)

    def has_data_near(self, level: int, x: int, y: int) -> bool:
        """Whether the tile or any of its 8 same-level neighbours has data (a tile's ring of
        neighbour nodes may hold data when the tile itself has none)."""
        return self._table_lookup(level, x, y, 1)

    def _table_lookup(self, level: int, x: int, y: int, grow: int) -> bool:
        if not (0 <= level <= self.max_level):
            return False
        grid = self._grids[level]
        ncols = self._ncols[level]
        iy = y - grid.y0
        ix = (x - grid.x0) % ncols
        if ix >= grid.nx and grid.nx < ncols:
            # Just east (nx) or just west (ncols - 1) of the extent: the table's border.
            ix = grid.nx if ix == grid.nx else (-1 if ix == ncols - 1 else -2)
        if not (-1 <= iy <= grid.ny and -1 <= ix <= grid.nx) or not (0 <= x < ncols):
            return False
        return bool(self._data_table(level, grow)[iy + 1, ix + 1])

    def _data_table(self, level: int, grow: int) -> np.ndarray:
        """(ny + 2, nx + 2) bool: whether tile (iy, ix) of the level has data (``grow`` = 1:
        it or one of its 8 neighbours), at [iy + 1, ix + 1], iy and ix from -1 (the tiles
        just outside the extent) to ny and nx; columns wrap across the antimeridian on a
        level that goes all the way round. Built once per level (a race only rebuilds it)."""
        hit = self._tables.get((level, grow))
        if hit is not None:
            return hit
        grid = self._grids[level]
        has = np.isfinite(self._levels[level].hmin)
        if grid.global_lon:
            has = np.concatenate([has[:, -1:], has, has[:, :1]], axis=1)
        else:
            has = np.pad(has, ((0, 0), (1, 1)))
        table = np.pad(has, ((1, 1), (0, 0)))
        if grow:
            q = np.pad(table, 1)
            rows, cols = table.shape
            near = np.zeros_like(table)
            for dy in range(3):
                for dx in range(3):
                    near |= q[dy : dy + rows, dx : dx + cols]
            table = near
        self._tables[(level, grow)] = table
        return table

    def cached(self, key: TileKey | tuple[int, int, int]) -> bool:
        """Whether a tile is in the cache now."""
        with self._lock:
            return TileKey(*key) in self._cache

    def prefetch_bytes(self, keys: Iterable[TileKey | tuple[int, int, int]]) -> list[Future]:
        """A remote store: fetch the compressed bytes of the blocks these tiles need, several
        requests at once (`RemoteOptions.max_requests` threads), into the caches, decoding
        nothing: the tile loader, which builds one tile at a time, then finds them there
        instead of paying a round trip per page in turn. Returns the futures of the blocks
        queued (none for a local store, or when every block was asked for before).

        Cheap on the calling thread (the renderer's, each frame while tiles are missing):
        tile-to-block geometry only, keys seen before skipped; chunk headers are opened in
        the background threads. Failures are left to the loader's reads (one line each)."""
        files = self._files
        if not files.is_remote or self._closed:
            return []
        todo: list[tuple[int, int, int, int]] = []
        with self._lock:
            if len(self._bytes_asked) > 200_000:  # a long session: forget, re-ask is cheap
                self._bytes_asked.clear()
                self._keys_asked.clear()
            for k in keys:
                key = (int(k[0]), int(k[1]), int(k[2]))
                if key in self._keys_asked:
                    continue
                self._keys_asked.add(key)
                for block in self._tile_blocks(key):
                    if block not in self._bytes_asked and block not in self._blocks:
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

    def _tile_blocks(self, key: tuple[int, int, int]) -> list[tuple[int, int, int, int]]:
        """(level, chunk index, block row, block column) of the chunk blocks a tile's padded
        window touches (the antimeridian wrap of a global level aside: its ring column is
        read by the loader itself)."""
        level, x, y = key
        if not (0 <= level <= self.max_level):
            return []
        grid = self._grids[level]
        n = grid.tile_nodes
        iy, ix = y - grid.y0, (x - grid.x0) % self._ncols[level]
        if not (0 <= iy < grid.ny and 0 <= ix < grid.nx):
            return []
        c_n = self._levels[level].chunk_nodes
        rows_c, cols_c = self._chunk_shape[level]
        r_lo, r_hi = max(iy * n - 1, 0), min(iy * n + n + 2, grid.height)
        c_lo, c_hi = max(ix * n - 1, 0), min(ix * n + n + 2, grid.width)
        out = []
        for cy in range(min(r_lo // c_n, rows_c - 1), min((r_hi - 1) // c_n, rows_c - 1) + 1):
            for cx in range(min(c_lo // c_n, cols_c - 1), min((c_hi - 1) // c_n, cols_c - 1) + 1):
                index = self._chunk_index[level].get((cy, cx))
                if index is None:
                    continue
                bh, bw = self._block_shapes.get((level, index), (BLOCK, BLOCK))
                ra, rb = max(r_lo - cy * c_n, 0), r_hi - cy * c_n
                ca, cb = max(c_lo - cx * c_n, 0), c_hi - cx * c_n
                out += [
                    (level, index, bi, bj)
                    for bi in range(ra // bh, (rb - 1) // bh + 1)
                    for bj in range(ca // bw, (cb - 1) // bw + 1)
                ]
        return out

    def _warm_block(self, level: int, index: int, bi: int, bj: int) -> None:
        """Fetch one block's compressed bytes into the remote caches (a background thread)."""
        files = self._files
        if self._closed or not files.is_remote:
            return
        try:
            ds = self._chunk_dataset(level, index)  # the chunk's header: its block offsets
            off = ds.get_tag_item(f"BLOCK_OFFSET_{bj}_{bi}", "TIFF", bidx=1)
            size = ds.get_tag_item(f"BLOCK_SIZE_{bj}_{bi}", "TIFF", bidx=1)
            if off and size:
                cy, cx = (int(v) for v in self._levels[level].chunks[index])
                files.warm(chunk_file_name(level, cy, cx), int(off), int(size))
        except _WARM_ERRORS:
            pass  # the loader's own read reports it (one line), or finds the bytes later
        take_error()

    def prefetch(self, keys: Iterable[TileKey | tuple[int, int, int]]) -> list[Future]:
        """Load tiles into the cache in background threads; returns their futures."""
        if self._closed:
            raise StoreError(f"{self.path}: the store is closed")
        with self._lock:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="tileload")
            pool = self._pool
        return [pool.submit(self.heights, TileKey(*k)) for k in keys]

    # -- lifetime --------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the prefetch threads and close every dataset handle (a remote store first
        cancels its HTTP reads, so a slow server does not hold the close)."""
        self._closed = True
        self._files.close()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self._bytes_pool is not None:
            self._bytes_pool.shutdown(wait=True, cancel_futures=True)
            self._bytes_pool = None
        with self._lock:
            for ds in self._all_handles:
                self._files.close_raster(ds)  # (a remote one in its opening thread's context)
            self._all_handles.clear()
            self._cache.clear()
            self._blocks.clear()
        self._local = threading.local()

    def __enter__(self) -> TileStore:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
