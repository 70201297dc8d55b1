"""Read access to a tile-pyramid store written by `globeview.terrain.ingest`.

A store is a directory with ``manifest.json`` and one grid-registered GeoTIFF per level
(``level_LL.tif``, EPSG:4326, float32, NaN = no data). Tile (L, x, y) is the
(2^n+1) x (2^n+1) window of level L's raster starting at row (y - y0)*2^n and column
((x - x0) mod 2^(L+1))*2^n, where (x0, y0, nx, ny) is the level's tile extent.

Heights are metres; tile metadata (``error``, ``hmin``, ``hmax``, stride errors) are metres.
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections import OrderedDict
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from types import TracebackType

import numpy as np
import rasterio
from rasterio.windows import Window

from globeview.errors import StoreError
from globeview.terrain.levels import LevelGrid
from globeview.terrain.quadtree import TileKey

__all__ = ["FORMAT_VERSION", "TileStore"]

FORMAT_VERSION = 2
MANIFEST_NAME = "manifest.json"
DEFAULT_CACHE_TILES = 256


class _Level:
    """Per-level metadata as numpy arrays (ny, nx); NaN where a tile has no data."""

    def __init__(self, entry: dict, tile_n: int, n_strides: int) -> None:
        ext = entry["extent"]
        self.grid = LevelGrid(
            int(entry["level"]),
            tile_n,
            int(ext["x0"]),
            int(ext["y0"]),
            int(ext["nx"]),
            int(ext["ny"]),
        )
        shape = (self.grid.ny, self.grid.nx)
        self.file: str = entry["file"]
        self.sha256: str = entry.get("sha256", "")
        self.error = _array(entry["error"], shape)
        self.hmin = _array(entry["hmin"], shape)
        self.hmax = _array(entry["hmax"], shape)
        stride = _array(entry["stride_error"], (*shape, n_strides), nested_null=True)
        self.stride = stride
        self.pole_heights: dict[str, float | None] = dict(entry.get("pole_heights") or {})
        self.level_error = entry.get("level_error")


def _array(data: list, shape: tuple[int, ...], nested_null: bool = False) -> np.ndarray:
    if nested_null:
        # Rows hold either a list of strides or null: expand nulls to NaN rows.
        n = shape[-1]
        data = [[c if c is not None else [None] * n for c in row] for row in data]
    a = np.array(data, dtype=np.float64)
    if a.size == 0:
        a = a.reshape(shape)
    if a.shape != shape:
        raise ValueError(f"array of shape {a.shape}, expected {shape}")
    return a


class TileStore:
    """A tile pyramid on disk. Open with `TileStore.open(path)`; thread-safe reads.

    Attributes:
        path: the store directory.
        manifest: the parsed manifest (dict).
        tile_n: tiles have 2^tile_n node intervals a side.
        tile_size: samples per tile side, 2^tile_n + 1.
        max_level: finest level.
        bounds: data footprint (west, south, east, north), degrees; west > east crosses the
            antimeridian.
        pole_heights: {"north": metres or None, "south": metres or None}: the single height of
            each pole point when the data reaches it (every level's pole row holds it).
    """

    def __init__(self, path: Path, manifest: dict, cache_tiles: int = DEFAULT_CACHE_TILES) -> None:
        self.path = path
        self.manifest = manifest
        try:
            self.tile_n = int(manifest["tile_n"])
            self.max_level = int(manifest["max_level"])
            self.strides: tuple[int, ...] = tuple(int(s) for s in manifest["strides"])
            self.bounds = tuple(float(v) for v in manifest["bounds"])
            self.pole_heights: dict[str, float | None] = dict(manifest.get("pole_heights") or {})
            self._levels = [_Level(e, self.tile_n, len(self.strides)) for e in manifest["levels"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise StoreError(f"{path}: damaged {MANIFEST_NAME} ({exc})") from None
        if len(self._levels) != self.max_level + 1 or any(
            lv.grid.level != i for i, lv in enumerate(self._levels)
        ):
            raise StoreError(f"{path}: damaged {MANIFEST_NAME} (levels do not match max_level)")
        for lv in self._levels:
            if not (path / lv.file).is_file():
                raise StoreError(f"{path}: level file {lv.file} is missing; re-run the ingest")
        self.tile_size = (1 << self.tile_n) + 1
        self._cache: OrderedDict[TileKey, np.ndarray] = OrderedDict()
        self._cache_tiles = max(1, int(cache_tiles))
        self._lock = threading.Lock()
        self._local = threading.local()
        self._all_handles: list[rasterio.DatasetReader] = []
        self._pool: ThreadPoolExecutor | None = None
        self._closed = False

    # -- opening ---------------------------------------------------------------------------

    @classmethod
    def open(cls, path: str | Path, cache_tiles: int = DEFAULT_CACHE_TILES) -> TileStore:
        """Open a store directory. Reads only the manifest (fast); no checksum pass.

        Raises:
            StoreError: not a directory, no/unreadable/corrupt manifest, unsupported
                format_version, or a missing level file.
        """
        p = Path(path)
        mpath = p / MANIFEST_NAME
        if not p.is_dir():
            raise StoreError(f"tile store not found: {p}")
        if not mpath.is_file():
            raise StoreError(f"{p} is not a globeview tile store (no {MANIFEST_NAME})")
        try:
            manifest = json.loads(mpath.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise StoreError(f"{mpath}: unreadable manifest ({type(exc).__name__})") from None
        if not isinstance(manifest, dict):
            raise StoreError(f"{mpath}: unreadable manifest (not a JSON object)")
        version = manifest.get("format_version")
        if version != FORMAT_VERSION:
            raise StoreError(
                f"{p}: store format version {version!r} is not supported (this globeview "
                f"reads version {FORMAT_VERSION}); re-run globeview ingest"
            )
        return cls(p, manifest, cache_tiles)

    def verify(self) -> None:
        """Check every level file against its sha256 in the manifest (reads all data).

        Raises StoreError naming the first level that does not match.
        """
        for lv in self._levels:
            h = hashlib.sha256()
            with (self.path / lv.file).open("rb") as f:
                for chunk in iter(lambda f=f: f.read(1 << 20), b""):
                    h.update(chunk)
            if h.hexdigest() != lv.sha256:
                raise StoreError(f"{self.path / lv.file} is damaged (checksum mismatch)")

    # -- metadata (vectorised) ---------------------------------------------------------------

    def level_grid(self, level: int) -> LevelGrid:
        """Extent and raster geometry of a level."""
        return self._levels[level].grid

    def level_error(self, level: int) -> float | None:
        """Largest tile error of a level (metres)."""
        return self._levels[level].level_error

    def _lookup(self, level: int, x: np.ndarray, y: np.ndarray, attr: str) -> np.ndarray:
        x_a, y_a = np.broadcast_arrays(np.asarray(x, dtype=np.int64), np.asarray(y, dtype=np.int64))
        if not (0 <= level <= self.max_level):
            tail = (len(self.strides),) if attr == "stride" else ()
            return np.full(x_a.shape + tail, np.nan)
        lv = self._levels[level]
        iy, ix, inside = lv.grid.tile_slots(y_a, x_a)
        arr = getattr(lv, attr)
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
            stride = self._lookup(level, x, y, "stride")
        return np.concatenate([err[..., None], stride], axis=-1).astype(np.float32)

    # -- heights -------------------------------------------------------------------------------

    def _dataset(self, level: int) -> rasterio.DatasetReader:
        """This thread's handle on a level raster (GDAL datasets are not thread-safe)."""
        handles = getattr(self._local, "handles", None)
        if handles is None:
            handles = self._local.handles = {}
        ds = handles.get(level)
        if ds is None:
            try:
                ds = rasterio.open(self.path / self._levels[level].file)
            except rasterio.errors.RasterioIOError as exc:
                raise StoreError(f"cannot read level {level} of {self.path}: {exc}") from None
            handles[level] = ds
            with self._lock:
                self._all_handles.append(ds)
        return ds

    def _read_tile(self, key: TileKey) -> np.ndarray:
        size = self.tile_size
        out = np.full((size, size), np.nan, dtype=np.float32)
        if not (0 <= key.level <= self.max_level):
            return out
        grid = self._levels[key.level].grid
        iy, ix, inside = grid.tile_slots(np.array(key.y), np.array(key.x))
        if not bool(inside):
            return out
        n = grid.tile_nodes
        try:
            out[:] = self._dataset(key.level).read(
                1, window=Window(int(ix) * n, int(iy) * n, size, size)
            )
        except rasterio.errors.RasterioIOError as exc:
            raise StoreError(f"cannot read tile {tuple(key)} of {self.path}: {exc}") from None
        return out

    def heights(self, key: TileKey | tuple[int, int, int]) -> np.ndarray:
        """Heights (metres) of a tile's (tile_size x tile_size) nodes, float32, NaN = no data.

        Row r, column c is the node at lon = west + c*d, lat = north - r*d. Served from an
        LRU cache (thread-safe); the returned array is read-only and shared.
        """
        key = TileKey(*key)
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        tile = self._read_tile(key)
        tile.flags.writeable = False
        with self._lock:
            self._cache[key] = tile
            self._cache.move_to_end(key)
            while len(self._cache) > self._cache_tiles:
                self._cache.popitem(last=False)
        return tile

    def cached(self, key: TileKey | tuple[int, int, int]) -> bool:
        """Whether a tile is in the cache now."""
        with self._lock:
            return TileKey(*key) in self._cache

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
        """Stop the prefetch threads and close every dataset handle."""
        self._closed = True
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        with self._lock:
            for ds in self._all_handles:
                ds.close()
            self._all_handles.clear()
            self._cache.clear()
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
