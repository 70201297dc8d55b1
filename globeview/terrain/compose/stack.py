"""`TerrainStack`: the visible DEM layers composed into one terrain.

Each DEM layer is its own tile store (a global base, regional detail on top). The stack
answers, for any tile key of the ellipsoidal quadtree, what the composed surface is:

- **heights**: each visible layer's heights pasted in order (later layers win where they have
  data). A layer over others feathers into them across a border band inside its data's edge
  (``B = L + w (U - L)``, w from `globeview.terrain.compose.blend`), so there is no cliff where 30 m
  data meets the 20' base. A layer asked for a tile finer than its finest level answers with
  its finest ancestor tile upsampled bilinearly — exactly the surface it stands for, so that
  part adds no geometric error. Where no layer has data the surface is the ellipsoid (height 0).
- **metadata**, vectorised over arrays of keys for the LOD providers: geometric error per
  index stride (the max over the layers covering the key, plus a bound on what the blend adds
  in border bands), height range, and whether any layer has finer data below the key.

Heights are metres above the ellipsoid; keys are (level, x, y) with y = 0 at the north pole
(see quadtree.py).

The stack keeps the layer list and its change events; the work is done by parts with one job
each, which it composes: per-tile facts (`metadata.StackMetadata`) with the border blend's
error bound (`band_errors.BandErrors`), composed heights (`heights.TileComposer`) and the
apron ring and padded tiles (`ring.RingComposer`).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
from psygnal import Signal

from globeview.errors import StoreError
from globeview.terrain.compose.band_errors import BandErrors
from globeview.terrain.compose.blend import BlendMask
from globeview.terrain.compose.heights import TileComposer
from globeview.terrain.compose.metadata import StackMetadata, TileMetadata
from globeview.terrain.compose.ring import RingComposer
from globeview.terrain.interpolate import bilinear
from globeview.terrain.quadtree import TileKey, key_for_lonlat, tile_bounds
from globeview.terrain.store.tile_store import TileStore

__all__ = ["TerrainLayer", "TerrainStack"]


@dataclass
class TerrainLayer:
    """One DEM layer: a tile store plus its display state."""

    store: TileStore
    name: str
    visible: bool = True


@dataclass
class TerrainStack:
    """Visible DEM layers composed by priority (later layers on top)."""

    layers: list[TerrainLayer] = field(default_factory=list)
    cache_tiles: int = 512
    #: Feather each layer into those below across its border band
    #: (`globeview.terrain.compose.blend`);
    #: False pastes them as they are (a cliff at each border: what benchmarks compare with).
    blend: bool = True
    #: Opaque slot for the LOD layer's per-terrain cache (`globeview.lod.tile_cache` fills it
    #: so the cache lives and dies with the terrain); terrain code never reads it.
    lod_cache: object = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.version = 0
        self._lock = threading.Lock()
        self._masks: dict[TileStore, BlendMask] = {}
        # The parts, each with one job (they reach each other through the stack).
        self._meta = StackMetadata(self)
        self._band = BandErrors(self)
        self._tiles = TileComposer(self)
        self._ring = RingComposer(self)
        self._check_sizes()

    # -- layer management --------------------------------------------------------------------
    @classmethod
    def from_stores(cls, stores: list[TileStore], names: list[str] | None = None) -> TerrainStack:
        names = names or [s.path.name for s in stores]
        return cls([TerrainLayer(s, n) for s, n in zip(stores, names, strict=True)])

    def add(self, store: TileStore, name: str | None = None) -> TerrainLayer:
        layer = TerrainLayer(store, name or store.path.name)
        self._check_sizes([*self.layers, layer])
        self.layers.append(layer)
        self._changed()
        return layer

    def remove(self, name: str) -> None:
        """Remove the layers called ``name`` (none: nothing changes, no event)."""
        kept = [ly for ly in self.layers if ly.name != name]
        if len(kept) != len(self.layers):
            self.layers = kept
            self._changed()

    def set_visible(self, name: str, visible: bool) -> None:
        """Show or hide the layers called ``name``; an event only if one changed."""
        hits = [ly for ly in self.layers if ly.name == name and ly.visible != visible]
        for ly in hits:
            ly.visible = visible
        if hits:
            self._changed()

    def move(self, name: str, index: int) -> None:
        """Move a layer to a new position (0 = bottom); an event only if the order changed."""
        layer = next(ly for ly in self.layers if ly.name == name)
        before = list(self.layers)
        self.layers.remove(layer)
        self.layers.insert(index, layer)
        if any(a is not b for a, b in zip(before, self.layers, strict=True)):
            self._changed()

    #: Emitted (no arguments) after every change of the layers: added, removed, moved, shown
    #: or hidden. The model (`globeview.model.Globe`) connects to it (psygnal holds a bound
    #: method weakly: a stack does not keep the globes shown on it alive).
    changed = Signal()

    def _changed(self) -> None:
        self.version += 1
        # Keyed by the store objects (not id(): a removed store's id may be reused by the
        # next one opened); forget removed stores.
        kept = {ly.store for ly in self.layers}
        self._tiles.clear()
        self._band.clear()
        self._meta.clear(kept)
        with self._lock:
            self._masks = {st: m for st, m in self._masks.items() if st in kept}
        self.changed.emit()

    def _check_sizes(self, layers: list[TerrainLayer] | None = None) -> None:
        sizes = {ly.store.tile_size for ly in (self.layers if layers is None else layers)}
        if len(sizes) > 1:
            raise StoreError(
                f"DEM layers use different tile sizes {sorted(sizes)}; re-ingest with one --tile-n"
            )

    @property
    def visible_layers(self) -> list[TerrainLayer]:
        return [ly for ly in self.layers if ly.visible]

    def prefetch_bytes(self, keys: np.ndarray) -> int:
        """Hand tiles about to be built ((N, 3) level, x, y, most wanted first) to each
        visible remote layer's `TileStore.prefetch_bytes` (a tile finer than a layer's data
        needs the layer's ancestor tile): their bytes arrive several requests at once instead
        of one page at a time in the loader. Returns the blocks queued; no-op without remote
        layers. (B, issue #18.)"""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        queued = 0
        for layer in self.visible_layers:
            st = layer.store
            if not st.is_remote or not len(keys):
                continue
            shift = np.maximum(keys[:, 0] - st.max_level, 0)
            mine = np.stack([keys[:, 0] - shift, keys[:, 1] >> shift, keys[:, 2] >> shift], 1)
            _, first = np.unique(mine, axis=0, return_index=True)
            queued += len(st.prefetch_bytes(mine[np.sort(first)].tolist()))
        return queued

    @property
    def tile_size(self) -> int:
        return self.layers[0].store.tile_size if self.layers else 65

    @property
    def max_level(self) -> int:
        """Finest level any visible layer has (0 with no layers)."""
        return max((ly.store.max_level for ly in self.visible_layers), default=0)

    # -- what the parts compute -----------------------------------------------------------------
    def metadata(self, level: int, x: np.ndarray, y: np.ndarray) -> TileMetadata:
        """Metadata of the N tiles (level, x[i], y[i]) (`StackMetadata`)."""
        return self._meta.metadata(level, x, y)

    def heights(self, key: tuple[int, int, int]) -> np.ndarray:
        """Composed (size, size) float32 heights of a tile (metres, row 0 at the north;
        `TileComposer`)."""
        return self._tiles.heights(key)

    def heights_apron(self, key: tuple[int, int, int]) -> np.ndarray:
        """The tile's composed heights with one node beyond each edge, (size + 2, size + 2)
        float32 metres, row 0 north, for `build_tile_mesh`'s ``apron`` (`RingComposer`)."""
        return self._ring.heights_apron(key)

    # -- the border blend ----------------------------------------------------------------------
    def blend_weight(self, i: int, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Weight (0..1) of visible layer ``i`` over the layers below at points (degrees): 1
        deep inside its data, falling to 0 across its border band (the bottom layer: 1)."""
        lon = np.asarray(lon, dtype=np.float64)
        if i == 0:
            return np.ones(lon.shape)
        mask = self.blend_mask(self.visible_layers[i].store)
        return mask.sample(lon, np.asarray(lat, dtype=np.float64))

    def blend_mask(self, st: TileStore) -> BlendMask:
        """The layer's blend weight raster (built once per store)."""
        with self._lock:
            hit = self._masks.get(st)
        if hit is None:
            hit = BlendMask(st)
            with self._lock:
                self._masks[st] = hit
        return hit

    def height_at(self, lon: float, lat: float, level: int | None = None) -> float:
        """Composed height (m) at a point, bilinear in the tile at ``level`` (default: the
        finest level any visible layer has, capped at 12)."""
        level = min(self.max_level, 12) if level is None else level
        kx, ky = key_for_lonlat(level, np.array([lon]), np.array([lat]))
        key = (level, int(np.asarray(kx).reshape(-1)[0]), int(np.asarray(ky).reshape(-1)[0]))
        h = self.heights(key)
        w, s, e, n = tile_bounds(TileKey(*key))
        size = h.shape[0]
        c = (lon - w) / (e - w) * (size - 1)
        r = (n - lat) / (n - s) * (size - 1)
        return float(bilinear(h, np.array([r]), np.array([c]))[0])
