"""A format-7 store's per-tile facts, looked up by tile key through its metadata shards.

The manifest names the top shard; every other shard is named by its parent's child table
(`shards.ChildRef`), so which shards exist is known without asking: a subtree without a
child record has no data ("no data here": the layer below shows through), and a chunk slot
a loaded shard does not list is NaN. Shards are read through a loader (the store backend's
`StoreFiles.read_small`: a local file, or an HTTP GET through the disk cache keyed by its
sha256), checked against the sha256 their parent records, decoded once and kept (bounded).

Per-tile facts (data or not, error, height range, stride errors; metres) are vectorised over
arrays of tile keys: keys are grouped by chunk, one dict hit per chunk.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from typing import Literal, NamedTuple

import numpy as np

from globeview.errors import StoreError
from globeview.terrain.levels import LevelGrid
from globeview.terrain.store.backend import TileNotReady
from globeview.terrain.store.layout import (
    ShardRef,
    chunk_code,
    chunk_file_name,
    chunk_grid_shape,
    chunk_levels_c0,
    chunk_tiles,
    shard_file_name,
    shard_of,
)
from globeview.terrain.store.schema import LevelRecord, StoreManifest
from globeview.terrain.store.shards import Coverage, Shard, ShardError, decode

__all__ = ["META_CACHE_SHARDS", "ChunkFacts", "StoreMetadata"]

#: Decoded shards kept (the top shard always): ~1 MB each at most for a full planet shard.
META_CACHE_SHARDS = 256

_TileArray = Literal["error", "hmin", "hmax", "stride_error"]
#: Reads a store file's bytes: (name, sha256, size) -> bytes (checked by the caller).
Loader = Callable[[str, str, int], bytes]


class ChunkFacts(NamedTuple):
    """One chunk's record: its file (None: no file), size, and k x k tile facts (metres):
    errors (k, k, 1 + n_strides) (column 0 the tile error), hmin, hmax (k, k), NaN without
    data."""

    file: str | None
    sha256: str
    bytes: int
    errors: np.ndarray
    hmin: np.ndarray
    hmax: np.ndarray
    flags: int = 0  # `layout.EXTRA_ROW` | `layout.EXTRA_COL`: it stores its closing row/column


class StoreMetadata:
    """The shard tree of a store, loaded on demand (thread-safe).

    Attributes:
        levels: the manifest's level records, finest last.
        grids: each level's bbox as a raster geometry (`LevelGrid`; what views sized by a
            level's data use: VRTs, `level_grid`).
        ncols: tile columns of each level on the globe (2^(L+1)).
        shards_loaded: shards read and decoded so far.
    """

    def __init__(self, manifest: StoreManifest, load: Loader, describe: Callable[[str], str]):
        self.tile_n = manifest.tile_n
        self.k = chunk_tiles(manifest.tile_n)
        self.max_level = manifest.max_level
        self.strides: tuple[int, ...] = manifest.strides
        self.levels: tuple[LevelRecord, ...] = manifest.levels
        self.grids = [lv.grid(manifest.tile_n) for lv in self.levels]
        self.ncols = [1 << (lv + 1) for lv in range(self.max_level + 1)]
        self._load, self._describe = load, describe
        self._top = manifest.shards.top
        self._lock = threading.RLock()
        self._shards: OrderedDict[ShardRef, dict[int, ChunkFacts]] = OrderedDict()
        self._children: dict[ShardRef, dict[tuple[int, int], tuple[str, int]]] = {}
        self._empty: dict[int, ChunkFacts] = {}
        self.shards_loaded = 0
        self._tables: dict[tuple[int, int], dict[int, np.ndarray]] = {}
        #: Runs a shard fetch in the background (`TileStore` sets it: a thread pool).
        self.background: Callable[[Callable[[], None]], object] | None = None
        self._pending: set[ShardRef] = set()
        #: The top shard's `Coverage` (None: a store written without one).
        self.coverage: Coverage | None = None

    # -- shards ---------------------------------------------------------------------------

    def load_top(self) -> None:
        """Read the top shard now (what opening a store costs besides its manifest)."""
        self._chunks_of(ShardRef(0, 0, 0, 0), top=True)

    def _ref_file(self, ref: ShardRef) -> tuple[str, str, int] | None:
        """(name, sha256, bytes) of shard ``ref``'s file; None when its parent lists none
        (no data in that subtree)."""
        if ref.is_top:
            return self._top.file, self._top.sha256, self._top.bytes
        parent = shard_of(ref.level - 1, ref.cy >> 1, ref.cx >> 1, self.tile_n, self.max_level)
        self._chunks_of(parent)
        hit = self._children.get(parent, {}).get((ref.cy, ref.cx))
        if hit is None:
            return None
        sha, size = hit
        return shard_file_name(ref, sha), sha, size

    def _chunks_of(self, ref: ShardRef, top: bool = False) -> dict[int, ChunkFacts]:
        """The chunk records of shard ``ref`` by (level, chunk code) key, loaded on first use."""
        if top:
            ref = shard_of(0, 0, 0, self.tile_n, self.max_level)
        with self._lock:
            hit = self._shards.get(ref)
            if hit is not None:
                self._shards.move_to_end(ref)
                return hit
            where = self._ref_file(ref)
            if where is None:
                return self._empty
            name, sha, size = where
            try:
                data = self._load(name, sha, size)
            except TileNotReady:
                # A thread that must not wait (a window's): fetched in the background, so a
                # later ask finds it cached; this one reads as "not loaded yet".
                self._load_later(ref)
                raise
            if hashlib.sha256(data).hexdigest() != sha:
                raise StoreError(
                    f"{self._describe(name)}: damaged metadata shard (checksum mismatch); "
                    "re-run globeview ingest --force"
                )
            try:
                shard = decode(data, ref, self.tile_n, len(self.strides))
            except ShardError as exc:
                raise StoreError(
                    f"{self._describe(name)}: damaged metadata shard ({exc})"
                ) from None
            self.shards_loaded += 1
            if ref.is_top:
                self.coverage = shard.coverage
            chunks = self._index(shard)
            self._children[ref] = {(c.cy, c.cx): (c.sha256, c.bytes) for c in shard.children}
            self._shards[ref] = chunks
            while len(self._shards) > META_CACHE_SHARDS:
                old = next(iter(self._shards))
                if old.is_top:
                    self._shards.move_to_end(old)
                    old = next(iter(self._shards))
                del self._shards[old]
            return chunks

    def _load_later(self, ref: ShardRef) -> None:
        """Fetch shard ``ref`` on the background thread (once at a time)."""
        if self.background is None or ref in self._pending:
            return
        self._pending.add(ref)

        def run() -> None:
            try:
                self._chunks_of(ref)
            except StoreError:
                pass  # a damaged or missing shard: the next ask reports it (one line)
            finally:
                self._pending.discard(ref)

        self.background(run)

    def _index(self, shard: Shard) -> dict[int, ChunkFacts]:
        k, ns1 = self.k, len(self.strides) + 1
        out: dict[int, ChunkFacts] = {}
        for i, (lv, cy, cx) in enumerate(shard.slots()):
            sha = shard.chunk_sha256[i]
            out[_key(lv, cy, cx)] = ChunkFacts(
                chunk_file_name(lv, cy, cx, sha) if sha else None,
                sha,
                int(shard.chunk_bytes[i]),
                shard.errors[i].reshape(k, k, ns1),
                shard.hmin[i].reshape(k, k),
                shard.hmax[i].reshape(k, k),
                int(shard.chunk_flags[i]) if shard.chunk_flags is not None else 0,
            )
        return out

    def chunk(self, level: int, cy: int, cx: int) -> ChunkFacts | None:
        """Chunk (level, cy, cx)'s record; None without data (or outside the level)."""
        rows, cols = chunk_grid_shape(level, self.tile_n)
        if not (0 <= level <= self.max_level and 0 <= cy < rows and 0 <= cx < cols):
            return None
        ref = shard_of(level, cy, cx, self.tile_n, self.max_level)
        return self._chunks_of(ref).get(_key(level, cy, cx))

    def iter_chunks(self) -> Iterator[tuple[int, int, int, ChunkFacts]]:
        """Every chunk record of the store, shard by shard from the top (loads them all)."""
        todo = [shard_of(0, 0, 0, self.tile_n, self.max_level)]
        while todo:
            ref = todo.pop()
            for key, facts in self._chunks_of(ref).items():
                yield (*_unkey(key), facts)
            depth_next = ref.level + ref.depth
            for cy, cx in sorted(self._children.get(ref, {})):
                todo.append(shard_of(depth_next, cy, cx, self.tile_n, self.max_level))

    # -- levels and chunks ------------------------------------------------------------------

    def level_grid(self, level: int) -> LevelGrid:
        """The level's bbox as a raster geometry."""
        return self.grids[level]

    def level_error(self, level: int) -> float | None:
        """Largest tile error of a level (metres)."""
        return self.levels[level].level_error

    def chunk_name(self, level: int, code: int) -> str:
        """The file name of chunk ``code`` (`layout.chunk_code`) of a level (it must have one)."""
        facts = self.chunk(level, code >> 32, code & 0xFFFFFFFF)
        if facts is None or facts.file is None:
            raise StoreError(f"chunk {level}/{code >> 32}/{code & 0xFFFFFFFF} has no file")
        return facts.file

    def chunk_sha256(self, level: int, code: int) -> str:
        facts = self.chunk(level, code >> 32, code & 0xFFFFFFFF)
        return facts.sha256 if facts is not None else ""

    def chunk_flags(self, level: int, cy: int, cx: int) -> int:
        """`layout.EXTRA_ROW` | `layout.EXTRA_COL` of a chunk with a file (0 without)."""
        facts = self.chunk(level, cy, cx)
        return facts.flags if facts is not None and facts.file is not None else 0

    def has_file(self, level: int, cy: int, cx: int) -> bool:
        """Whether chunk (cy, cx) of a level has a file (else it reads as NaN)."""
        facts = self.chunk(level, cy, cx)
        return facts is not None and facts.file is not None

    # -- per-tile facts (vectorised) ---------------------------------------------------------

    def _gather(self, level: int, x: np.ndarray, y: np.ndarray, attr: str) -> np.ndarray:
        """(n, m) float array of a chunk field at tiles (x, y) (flat), NaN without data."""
        m = len(self.strides) + 1 if attr == "errors" else 1
        out = np.full((x.size, m), np.nan, dtype=np.float32)
        if not 0 <= level <= self.max_level:
            return out
        nrows = 1 << level
        ok = (x >= 0) & (x < self.ncols[level]) & (y >= 0) & (y < nrows)
        c0 = chunk_levels_c0(self.tile_n)
        codes = np.where(ok, chunk_code(y >> c0, x >> c0), -1)
        uniq, inv = np.unique(codes, return_inverse=True)
        for j, code in enumerate(uniq):
            if code < 0:
                continue
            facts = self.chunk(level, int(code) >> 32, int(code) & 0xFFFFFFFF)
            if facts is None:
                continue
            sel = np.flatnonzero(inv == j)
            arr = getattr(facts, attr)
            v = arr[y[sel] & (self.k - 1), x[sel] & (self.k - 1)]
            out[sel] = v.reshape(sel.size, m)
        return out

    def _keys(self, x: np.ndarray | int, y: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        x_a, y_a = np.broadcast_arrays(np.asarray(x, dtype=np.int64), np.asarray(y, dtype=np.int64))
        return x_a, y_a

    def lookup(
        self, level: int, x: np.ndarray | int, y: np.ndarray | int, attr: _TileArray
    ) -> np.ndarray:
        """A per-tile fact at tiles (x, y) (float64; NaN where no data)."""
        x_a, y_a = self._keys(x, y)
        shape = x_a.shape
        if attr in ("hmin", "hmax"):
            return (
                self._gather(level, x_a.ravel(), y_a.ravel(), attr)
                .reshape(shape)
                .astype(np.float64)
            )
        e = self._gather(level, x_a.ravel(), y_a.ravel(), "errors").astype(np.float64)
        if attr == "error":
            return e[:, 0].reshape(shape)
        return e[:, 1:].reshape(*shape, len(self.strides))

    def has_data(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """Bool array: the tile holds data (False beyond max_level)."""
        return np.isfinite(self.lookup(level, x, y, "hmin"))

    def tile_error(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """Geometric error (metres, float32); NaN where there is no tile."""
        return self.lookup(level, x, y, "error").astype(np.float32)

    def tile_hrange(
        self, level: int, x: np.ndarray | int, y: np.ndarray | int
    ) -> tuple[np.ndarray, np.ndarray]:
        """(hmin, hmax) of the tiles' samples, metres, float32 (NaN where no tile)."""
        return (
            self.lookup(level, x, y, "hmin").astype(np.float32),
            self.lookup(level, x, y, "hmax").astype(np.float32),
        )

    def tile_stride_error(self, level: int, x: np.ndarray | int, y: np.ndarray | int) -> np.ndarray:
        """(..., 1 + n_strides) float32 bounds (metres); column 0 the tile error."""
        x_a, y_a = self._keys(x, y)
        e = self._gather(level, x_a.ravel(), y_a.ravel(), "errors")
        return e.reshape(*x_a.shape, len(self.strides) + 1)

    # -- one tile at a time (the compose path) -----------------------------------------------

    def has_tile(self, level: int, x: int, y: int) -> bool:
        """`has_data` for one tile, without numpy's per-call overhead."""
        return self._grown(level, x, y, 0)

    def has_data_near(self, level: int, x: int, y: int) -> bool:
        """Whether the tile or any of its 8 same-level neighbours has data."""
        return self._grown(level, x, y, 1)

    def _grown(self, level: int, x: int, y: int, grow: int) -> bool:
        if not (0 <= level <= self.max_level) or not (0 <= x < self.ncols[level]):
            return False
        if not 0 <= y < 1 << level:
            return False
        c0 = chunk_levels_c0(self.tile_n)
        code = (y >> c0) << 32 | (x >> c0)
        tables = self._tables.setdefault((level, grow), {})
        table = tables.get(code)
        if table is None:
            table = tables[code] = self._chunk_table(level, y >> c0, x >> c0, grow)
        return bool(table[(y & (self.k - 1)) + 1, (x & (self.k - 1)) + 1])

    def _chunk_table(self, level: int, cy: int, cx: int, grow: int) -> np.ndarray:
        """(k + 2)^2 bool: has data at the chunk's tiles and the ring around them (``grow``:
        it or one of its 8 neighbours), columns wrapping across the antimeridian."""
        k = self.k
        ys = cy * k - 1 + np.arange(k + 2)
        xs = (cx * k - 1 + np.arange(k + 2)) % self.ncols[level]
        yy, xx = np.meshgrid(ys, xs, indexing="ij")
        table = self.has_data(level, xx, yy)
        if grow:
            ys2 = cy * k - 2 + np.arange(k + 4)
            xs2 = (cx * k - 2 + np.arange(k + 4)) % self.ncols[level]
            yy, xx = np.meshgrid(ys2, xs2, indexing="ij")
            q = self.has_data(level, xx, yy)
            near = np.zeros((k + 2, k + 2), dtype=bool)
            for dy in range(3):
                for dx in range(3):
                    near |= q[dy : dy + k + 2, dx : dx + k + 2]
            table = near
        return table


def _key(level: int, cy: int, cx: int) -> int:
    """One int per chunk of any level: level in the top bits, then (cy << 32 | cx)."""
    return (level << 58) | (cy << 29) | cx


def _unkey(key: int) -> tuple[int, int, int]:
    return key >> 58, (key >> 29) & ((1 << 29) - 1), key & ((1 << 29) - 1)
