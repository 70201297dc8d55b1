"""Composed heights of a tile: each visible layer's heights pasted in order (later layers
win where they have data), a layer over others feathered into them across its border band
(``B = L + w (U - L)``, `blend`), a layer asked for a tile finer than its finest level
answering with its finest ancestor upsampled bilinearly. Composed tiles are cached (the last
`TerrainStack.cache_tiles`), never across a change of the layers.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from globeview.terrain.interpolate import upsample_subtile
from globeview.terrain.quadtree import tile_bounds_arrays
from globeview.terrain.store.tile_store import TileStore

if TYPE_CHECKING:  # type hints only: the stack imports its parts, never the other way round
    from globeview.terrain.compose.stack import TerrainLayer, TerrainStack

__all__ = ["TileComposer"]

#: "Not read yet" for `TileComposer.paste`'s ``own`` (None means "read: no data").
_UNREAD: object = object()


class TileComposer:
    """`TerrainStack.heights`: the visible layers composed at a tile, cached."""

    def __init__(self, stack: TerrainStack) -> None:
        self._stack = stack
        self._lock = threading.Lock()
        # Composed tiles by (level, x, y); padded composed ancestors by (level, x, y, upto).
        self._cache: dict[tuple[int, ...], np.ndarray] = {}
        self._order: list[tuple[int, ...]] = []

    def clear(self) -> None:
        """Forget every composed tile (the layers changed)."""
        with self._lock:
            self._cache.clear()
            self._order.clear()

    def cached(self, ckey: tuple[int, ...]) -> np.ndarray | None:
        """The composed tile (or padded ancestor) cached under ``ckey``, else None."""
        with self._lock:
            return self._cache.get(ckey)

    def heights(self, key: tuple[int, int, int]) -> np.ndarray:
        """Composed (size, size) float32 heights of a tile (metres, row 0 at the north)."""
        key = (int(key[0]), int(key[1]), int(key[2]))
        with self._lock:
            hit = self._cache.get(key)
        if hit is not None:
            return hit
        version = self._stack.version
        out = self.compose(key, len(self._stack.visible_layers))
        if not np.isfinite(out).all():  # (nan_to_num's own checks cost more than a compose step)
            np.nan_to_num(out, copy=False, nan=0.0)
        with self._lock:
            if version != self._stack.version:  # the layers changed meanwhile: do not cache
                return out
            self._cache[key] = out
            self._order.append(key)
            if len(self._order) > self._stack.cache_tiles:
                self._cache.pop(self._order.pop(0), None)
        return out

    def compose(self, key: tuple[int, int, int], upto: int) -> np.ndarray:
        """The first ``upto`` visible layers composed at a tile (NaN where none has data)."""
        size = self._stack.tile_size
        layers = self._stack.visible_layers[:upto]
        first, own = self.opaque_layer(layers, key, self.layer_heights, self._tile_blends)
        out = np.full((size, size), np.nan, dtype=np.float32)
        for i in range(first, len(layers)):
            self.paste(i, layers[i].store, key, out, own.get(i, _UNREAD))
        return out

    def _tile_blends(self, st: TileStore, key: tuple[int, int, int]) -> bool:
        """Whether `paste` blends the layer into those below at this tile (`_blend_weight`
        is not None), without sampling the weights."""
        mask = self._stack.blend_mask(st)
        w_, s_, e_, n_ = (float(v) for v in tile_bounds_arrays(*key))
        return mask.touches_band_one(w_, s_, e_, n_)

    def opaque_layer(
        self,
        layers: list[TerrainLayer],
        key: tuple[int, int, int],
        heights_of: Callable[[TileStore, tuple[int, int, int]], np.ndarray | None],
        blends: Callable[[TileStore, tuple[int, int, int]], bool],
    ) -> tuple[int, dict[int, np.ndarray | None]]:
        """(first layer to paste, {layer: its own heights read on the way}).

        The highest layer with data at every node that does not blend here hides every layer
        below it: pasting it over them copies it whole (`np.copyto` where it has data, i.e.
        everywhere), so the composition may start there, bit for bit the same. Deep inside
        a detailed layer that skips the base's and the other layers' upsampling (issue #17:
        most of a tile's compose time). ``heights_of(st, key)`` gives a layer's own heights
        (None: no data), ``blends(st, key)`` whether it blends at the key.
        """
        seen: dict[int, np.ndarray | None] = {}
        for j in range(len(layers) - 1, -1, -1):
            st = layers[j].store
            h = seen[j] = heights_of(st, key)
            if h is None or np.isnan(h).any():
                continue
            if j == 0 or not self._stack.blend or not blends(st, key):
                return j, seen
        return 0, seen

    def paste(
        self,
        i: int,
        st: TileStore,
        key: tuple[int, int, int],
        out: np.ndarray,
        own: np.ndarray | object | None = _UNREAD,
    ) -> np.ndarray | None:
        """Compose visible layer ``i`` over ``out`` (the layers below, NaN where none has
        data) in place; returns the layer's own heights (None without data here). ``own``:
        the layer's own heights at the key when already read (None: it has none there)."""
        h = self.layer_heights(st, key) if own is _UNREAD else own
        if h is None:
            return None
        assert isinstance(h, np.ndarray)
        has = ~np.isnan(h)
        # A layer over another one feathers into it near its data's edge; the bottom layer
        # has nothing to blend into.
        w = self._blend_weight(st, key) if i > 0 and self._stack.blend else None
        mine = h
        if w is not None:
            f = key[0] - st.max_level
            if f > 0:
                # Finer than the layer's data: its band is the blend at the layer's finest
                # level, upsampled (so the band, like the layer, adds no detail below its
                # finest level and its errors stop there; finer data of a layer below is
                # given up inside the band only).
                # That holds at the layer's ragged data edge too: nodes inside a finest-level
                # cell with a nodata corner take the composed cell's interpolation (the layer
                # alone is NaN there), so every finer level draws one surface.
                ax, ay = key[1] >> f, key[2] >> f
                anc = self._stack._ring.composed_padded((st.max_level, ax, ay), i + 1)[1:-1, 1:-1]
                h = upsample_subtile(anc, f, key[1] - (ax << f), key[2] - (ay << f))
                has = ~np.isnan(h)
            else:
                # Where nothing lies below (NaN) the layer keeps its own heights.
                mixed = np.where(np.isnan(out), h, out + w * (h - out))
                h = np.where(has, mixed, np.nan).astype(np.float32)
        np.copyto(out, h, where=has)
        return mine

    def _blend_weight(self, st: TileStore, key: tuple[int, int, int]) -> np.ndarray | None:
        """(size, size) weight of a layer over those below at a tile's nodes; None where the
        whole tile is deeper inside the layer than its band (nothing to blend)."""
        mask = self._stack.blend_mask(st)
        w_, s_, e_, n_ = (float(v) for v in tile_bounds_arrays(*key))
        if not mask.touches_band_one(w_, s_, e_, n_):
            return None
        return mask.sample_grid(w_, s_, e_, n_, self._stack.tile_size).astype(np.float32)

    def layer_heights(self, st: TileStore, key: tuple[int, int, int]) -> np.ndarray | None:
        level, x, y = key
        lm = st.max_level
        if level <= lm:
            if not st.has_tile(level, x, y):
                return None
            return st.heights(key)
        f = level - lm
        ax, ay = x >> f, y >> f
        if not st.has_tile(lm, ax, ay):
            return None
        anc = st.heights((lm, ax, ay))
        return upsample_subtile(anc, f, x - (ax << f), y - (ay << f))

    def remember(self, ckey: tuple, value: np.ndarray, version: int) -> None:
        """Cache ``value`` under ``ckey`` unless the layers changed since ``version``."""
        with self._lock:
            if version != self._stack.version:  # the layers changed meanwhile: do not cache
                return
            self._cache[ckey] = value
            self._order.append(ckey)
            if len(self._order) > self._stack.cache_tiles:
                self._cache.pop(self._order.pop(0), None)
