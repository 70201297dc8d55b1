"""The composed terrain's per-tile facts for the LOD, vectorised over arrays of keys: each
index stride's geometric error (the max over the layers covering the key, plus what the
border blend adds: `band_errors`), the composed height range, whether any layer has finer
data below, whether any covers it. Tiles finer than a layer's data take the `drawn_error`
bound measured on their own nodes, cached per ancestor up to `VIRTUAL_CACHE_BYTES`.
"""

from __future__ import annotations

import functools
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from globeview.errors import StoreError
from globeview.terrain.compose.drawn_error import AncestorErrors
from globeview.terrain.store.tile_store import TileStore

if TYPE_CHECKING:  # type hints only: the stack imports its parts, never the other way round
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.levels import LevelGrid

__all__ = ["N_STRIDES", "VIRTUAL_CACHE_BYTES", "StackMetadata", "TileMetadata"]

#: Number of index strides with recorded errors: 1, 2, 4, ..., 64.
N_STRIDES = 7

#: Bytes of ancestors' `AncestorErrors` tables kept (`StackMetadata.measured_virtual`;
#: ~0.16 MB each for 65-node tiles); past it the least recently used go.
VIRTUAL_CACHE_BYTES = 64 << 20

#: "Not looked up yet" in the ancestors' tables (None there means "no data").
_UNREAD = object()


@dataclass
class TileMetadata:
    """Vectorised per-tile facts for N keys.

    stride_error: (N, N_STRIDES) metres: max |height error| vs full resolution when the tile
        is drawn with index stride 1, 2, 4, ... 64 (height only; curvature is the renderer's).
    hmin, hmax: (N,) metres, height range of the composed surface in the tile.
    has_finer: (N,) bool: some visible layer has data finer than this tile's level here.
    covered: (N,) bool: some visible layer has data in the tile.
    """

    stride_error: np.ndarray
    hmin: np.ndarray
    hmax: np.ndarray
    has_finer: np.ndarray
    covered: np.ndarray


class StackMetadata:
    """`TerrainStack.metadata`: the per-tile facts of the stack's visible layers. Caches
    each layer's per-level facts (`_layer_table`) and the ancestors' error tables."""

    def __init__(self, stack: TerrainStack) -> None:
        self._stack = stack
        self._lock = threading.Lock()
        self._tables: dict[tuple[TileStore, int], tuple] = {}
        # Error tables of the ancestors of tiles finer than a layer's data (what they hold,
        # level, x, y), built on first request (`measured_virtual`).
        self._virtual: OrderedDict[tuple, AncestorErrors | None] = OrderedDict()
        self._virtual_sizes: dict[tuple, int] = {}  # bytes held by each entry of _virtual
        self._virtual_bytes = 0  # their sum

    def clear(self, kept: set[TileStore]) -> None:
        """The layers changed: forget the ancestors' tables (what lies below a layer may
        differ) and the tables of stores no longer in the stack."""
        with self._lock:
            self._virtual.clear()
            self._virtual_sizes.clear()
            self._virtual_bytes = 0
            self._tables = {k: v for k, v in self._tables.items() if k[0] in kept}

    def metadata(self, level: int, x: np.ndarray, y: np.ndarray) -> TileMetadata:
        """Metadata of the N tiles (level, x[i], y[i])."""
        return self.of_layers(level, x, y, len(self._stack.visible_layers))

    def of_layers(self, level: int, x: np.ndarray, y: np.ndarray, upto: int) -> TileMetadata:
        """Metadata of the first ``upto`` visible layers composed (see `metadata`)."""
        x = np.asarray(x, dtype=np.int64)
        y = np.asarray(y, dtype=np.int64)
        n = len(x)
        err = np.zeros((n, N_STRIDES), dtype=np.float64)
        hmin = np.full(n, np.inf)
        hmax = np.full(n, -np.inf)
        has_finer = np.zeros(n, dtype=bool)
        covered = np.zeros(n, dtype=bool)
        for i, layer in enumerate(self._stack.visible_layers[:upto]):
            st = layer.store
            lm = st.max_level
            la = min(level, lm)
            f = level - la
            grid, table = self._layer_table(st, la)
            iy, ix, inside = grid.tile_slots(y >> f, x >> f)
            rows = table[iy, ix]
            ok = inside & (rows[:, 0] > 0)
            if not ok.any():
                continue
            if f == 0:
                e = rows[:, 3:]
                if level < lm:
                    has_finer |= ok
            else:
                # Finer than the layer's data: its finest ancestor, upsampled. Each such tile's
                # errors are measured on its own nodes (`drawn_error`): the ancestor's
                # whole-tile errors (stride s here is stride s / 2^f there) bound them too,
                # but loosely, so refining below the data never lowered an error.
                e = self._virtual_errors(st, level, x, y, ok, rows)
            blended = ok & covered  # this layer over data of layers below: its border band
            if i > 0 and self._stack.blend and blended.any():
                e = e + self._stack._band.blend_error(i, st, level, x, y, blended, e, err)
            covered |= ok
            err = np.where(ok[:, None], np.maximum(err, e), err)
            hmin = np.where(ok, np.minimum(hmin, rows[:, 1]), hmin)
            hmax = np.where(ok, np.maximum(hmax, rows[:, 2]), hmax)
        # Where a layer covers only part of the tile, the rest is the ellipsoid (height 0).
        hmin = np.where(covered, np.minimum(hmin, 0.0), 0.0)
        hmax = np.where(covered, np.maximum(hmax, 0.0), 0.0)
        return TileMetadata(err, hmin, hmax, has_finer, covered)

    def _virtual_errors(
        self,
        st: TileStore,
        level: int,
        x: np.ndarray,
        y: np.ndarray,
        ok: np.ndarray,
        rows: np.ndarray,
    ) -> np.ndarray:
        """(N, N_STRIDES) metres: stride errors of tiles (level, x, y) finer than layer
        ``st``'s data, where ``ok``; ``rows`` their ancestors' `_layer_table` rows.

        The `drawn_error` bound on each tile's part of its ancestor (plus the ancestor's
        stride-1 error) where measured (`measured_virtual`), else the ancestor's whole-tile
        errors (stride s here is stride s / 2^f there, 0 below one ancestor cell)."""
        f = level - st.max_level
        old = np.zeros((len(x), N_STRIDES))
        if f < N_STRIDES:
            old[:, f:] = rows[:, 3 : 3 + N_STRIDES - f]
        new = self.measured_virtual(
            (st, -1),
            level,
            st.max_level,
            x,
            y,
            ok,
            rows[:, 3],
            functools.partial(self._stack._tiles.layer_heights, st),
        )
        return np.where(np.isfinite(new), new, old)

    def measured_virtual(
        self,
        tag: tuple,
        level: int,
        lm: int,
        x: np.ndarray,
        y: np.ndarray,
        ok: np.ndarray,
        base: np.ndarray,
        ancestor: Callable[[tuple[int, int, int]], np.ndarray | None],
    ) -> np.ndarray:
        """(N, N_STRIDES) metres: the `drawn_error` bound on the tiles (level, x, y) where
        ``ok``, whose nodes are their ancestor's bilinear surface at level ``lm`` <
        ``level``, ``ancestor(key)`` that ancestor's nodes and ``base`` (N,) its stride-1
        error; inf where not measured (not ``ok``, a pole row (drawn as a fan), no data).
        The ancestors' tables are built once per ancestor and ``tag`` (what the nodes are),
        kept until the layers change."""
        n = len(x)
        out = np.full((n, N_STRIDES), np.inf)
        idx = np.flatnonzero(ok & (y > 0) & (y < (1 << level) - 1))
        if not len(idx):
            return out
        version = self._stack.version  # a table built while the layers change is not kept
        f = level - lm
        codes = (x[idx] >> f) << 32 | (y[idx] >> f)
        # Descendants grouped by ancestor: sorted once, each group a slice.
        order = np.argsort(codes, kind="stable")
        idx, codes = idx[order], codes[order]
        xs, ys = x[idx], y[idx]
        uniq, starts = np.unique(codes, return_index=True)
        ends = np.append(starts[1:], len(codes))
        term = np.full((len(idx), N_STRIDES), np.inf)
        # One pass per ancestor (a few per level: descendants share them), vectorised over
        # its descendants.
        for code, a, b in zip(uniq.tolist(), starts.tolist(), ends.tolist(), strict=True):
            ax, ay = code >> 32, code & 0xFFFFFFFF
            key = (*tag, lm, ax, ay)
            with self._lock:
                hit = self._virtual.get(key, _UNREAD)
            if isinstance(hit, AncestorErrors) or hit is None:
                tables = hit
            else:
                try:
                    anc = ancestor((lm, ax, ay))
                except StoreError:
                    # Unreadable now (a remote store's tile that failed, or one not fetched
                    # yet on the UI thread, which never waits for the network): not measured
                    # (the caller's bound stands) and nothing kept, so a later call measures
                    # it once the tile is there.
                    continue
                tables = AncestorErrors(anc) if anc is not None else None
            if tables is not None:
                term[a:b] = tables.bounds(f, xs[a:b] - (ax << f), ys[a:b] - (ay << f))
            with self._lock:  # (re)counted after bounds: its tables grow on first use
                if self._stack.version == version:
                    self._account_virtual(key, tables)
        # NaN (nodes without data): nothing measured, the caller's bound stands.
        term[np.isnan(term).any(axis=1)] = np.inf
        out[idx] = base[idx, None] + term
        return out

    def _account_virtual(self, key: tuple, tables: AncestorErrors | None) -> None:
        """Keep (or re-measure, after its tables grew) ``tables`` under ``key`` as the most
        recently used, and drop the least recently used past `VIRTUAL_CACHE_BYTES` (the
        newest always stays). Sizes are kept per entry so this is O(1) a call, not a sum
        over the cache. Holds _lock."""
        size = tables.nbytes if tables is not None else 0
        self._virtual_bytes += size - self._virtual_sizes.get(key, 0)
        self._virtual_sizes[key] = size
        self._virtual[key] = tables
        self._virtual.move_to_end(key)
        while self._virtual_bytes > VIRTUAL_CACHE_BYTES and len(self._virtual) > 1:
            gone, _ = self._virtual.popitem(last=False)
            self._virtual_bytes -= self._virtual_sizes.pop(gone)

    def _layer_table(self, st: TileStore, level: int) -> tuple[LevelGrid, np.ndarray]:
        """A layer's per-tile facts at a level as one dense (ny, nx, 3 + N_STRIDES) table:
        [has data, hmin, hmax, stride errors...] (built once, then looked up per frame)."""
        key = (st, level)
        with self._lock:  # tile loader threads call metadata too (renderer.build_mesh)
            hit = self._tables.get(key)
        if hit is not None:
            return hit
        grid = st.level_grid(level)
        ys, xs = np.mgrid[grid.y0 : grid.y0 + grid.ny, grid.x0 : grid.x0 + grid.nx]
        xs = xs % grid.ncols
        valid = st.has_data(level, xs, ys)
        lo, hi = st.tile_hrange(level, xs, ys)
        errs = st.tile_stride_error(level, xs, ys)
        table = np.concatenate(
            [valid[..., None], lo[..., None], hi[..., None], errs], axis=-1
        ).astype(np.float64)
        table = np.nan_to_num(table, nan=0.0)
        with self._lock:
            self._tables[key] = (grid, table)
        return grid, table
