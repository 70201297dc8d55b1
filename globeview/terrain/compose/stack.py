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
"""

from __future__ import annotations

import functools
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from psygnal import Signal

from globeview.errors import StoreError
from globeview.terrain.compose.blend import BlendMask, interpolation_error, weight_change_bound
from globeview.terrain.compose.drawn_error import AncestorErrors
from globeview.terrain.interpolate import bilinear, linear_weights, upsample_subtile
from globeview.terrain.quadtree import (
    TileKey,
    key_for_lonlat,
    node_spacing,
    tile_bounds,
    tile_bounds_arrays,
)
from globeview.terrain.store.tile_store import TileStore

#: Number of index strides with recorded errors: 1, 2, 4, ..., 64.
N_STRIDES = 7

#: Most tiles of a layer's border band whose |upper - lower| is measured exactly at one level
#: (one-time work, ~1 ms a tile); finer levels bound it from the finest level within this.
DIFF_TABLE_TILES = 1024
#: Seconds before the band tiles a `_difference_table` could not read (a remote store's tile
#: that failed, or one not fetched yet on a thread that may not wait for the network: the
#: window's UI thread) are tried again; until then they are bounded by their height ranges.
DIFF_RETRY_S = 2.0

#: Bytes of ancestors' `AncestorErrors` tables kept (`TerrainStack._measured_virtual`;
#: ~0.16 MB each for 65-node tiles); past it the least recently used go.
VIRTUAL_CACHE_BYTES = 64 << 20


#: "Not read yet" for `TerrainStack._paste`'s ``own`` (None means "read: no data").
_UNREAD = object()


@dataclass
class TerrainLayer:
    """One DEM layer: a tile store plus its display state."""

    store: TileStore
    name: str
    visible: bool = True


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
        # Composed tiles by (level, x, y); padded composed ancestors by (level, x, y, upto).
        self._cache: dict[tuple[int, ...], np.ndarray] = {}
        self._order: list[tuple[int, ...]] = []
        self._tables: dict[tuple[TileStore, int], tuple] = {}
        self._masks: dict[TileStore, BlendMask] = {}
        self._diffs: dict[tuple, tuple] = {}
        # _diffs entries with unread band tiles: key -> (time.monotonic() to retry, tiles).
        self._diffs_unread: dict[tuple, tuple[float, list[tuple[int, int]]]] = {}
        self._band_counts: dict[tuple[TileStore, int], int] = {}  # band tiles per level
        # Error tables of the ancestors of tiles finer than a layer's data (what they hold,
        # level, x, y), built on first request (`_measured_virtual`).
        self._virtual: OrderedDict[tuple, AncestorErrors | None] = OrderedDict()
        self._virtual_sizes: dict[tuple, int] = {}  # bytes held by each entry of _virtual
        self._virtual_bytes = 0  # their sum
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
        with self._lock:
            self._cache.clear()
            self._order.clear()
            self._diffs.clear()  # |upper - lower| bounds depend on which layers lie below
            self._diffs_unread.clear()
            self._band_counts.clear()
            self._virtual.clear()
            self._virtual_sizes.clear()
            self._virtual_bytes = 0
            # Keyed by the store objects (not id(): a removed store's id may be reused by the
            # next one opened); forget removed stores.
            kept = {ly.store for ly in self.layers}
            self._masks = {st: m for st, m in self._masks.items() if st in kept}
            self._tables = {k: v for k, v in self._tables.items() if k[0] in kept}
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

    # -- vectorised metadata -------------------------------------------------------------------
    def metadata(self, level: int, x: np.ndarray, y: np.ndarray) -> TileMetadata:
        """Metadata of the N tiles (level, x[i], y[i])."""
        return self._metadata(level, x, y, len(self.visible_layers))

    def _metadata(self, level: int, x: np.ndarray, y: np.ndarray, upto: int) -> TileMetadata:
        """Metadata of the first ``upto`` visible layers composed (see `metadata`)."""
        x = np.asarray(x, dtype=np.int64)
        y = np.asarray(y, dtype=np.int64)
        n = len(x)
        err = np.zeros((n, N_STRIDES), dtype=np.float64)
        hmin = np.full(n, np.inf)
        hmax = np.full(n, -np.inf)
        has_finer = np.zeros(n, dtype=bool)
        covered = np.zeros(n, dtype=bool)
        for i, layer in enumerate(self.visible_layers[:upto]):
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
            if i > 0 and self.blend and blended.any():
                e = e + self._blend_error(i, st, level, x, y, blended, e, err)
            covered |= ok
            err = np.where(ok[:, None], np.maximum(err, e), err)
            hmin = np.where(ok, np.minimum(hmin, rows[:, 1]), hmin)
            hmax = np.where(ok, np.maximum(hmax, rows[:, 2]), hmax)
        # Where a layer covers only part of the tile, the rest is the ellipsoid (height 0).
        hmin = np.where(covered, np.minimum(hmin, 0.0), 0.0)
        hmax = np.where(covered, np.maximum(hmax, 0.0), 0.0)
        return TileMetadata(err, hmin, hmax, has_finer, covered)

    def _virtual_errors(
        self, st: TileStore, level: int, x: np.ndarray, y: np.ndarray, ok: np.ndarray, rows
    ) -> np.ndarray:
        """(N, N_STRIDES) metres: stride errors of tiles (level, x, y) finer than layer
        ``st``'s data, where ``ok``; ``rows`` their ancestors' `_layer_table` rows.

        The `drawn_error` bound on each tile's part of its ancestor (plus the ancestor's
        stride-1 error) where measured (`_measured_virtual`), else the ancestor's whole-tile
        errors (stride s here is stride s / 2^f there, 0 below one ancestor cell)."""
        f = level - st.max_level
        old = np.zeros((len(x), N_STRIDES))
        if f < N_STRIDES:
            old[:, f:] = rows[:, 3 : 3 + N_STRIDES - f]
        new = self._measured_virtual(
            (st, -1),
            level,
            st.max_level,
            x,
            y,
            ok,
            rows[:, 3],
            functools.partial(self._layer_heights, st),
        )
        return np.where(np.isfinite(new), new, old)

    def _measured_virtual(
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
        version = self.version  # a table built while the layers change is not kept
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
                if self.version == version:
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

    # -- the border blend ----------------------------------------------------------------------
    def _blend_error(
        self,
        i: int,
        st: TileStore,
        level: int,
        x: np.ndarray,
        y: np.ndarray,
        blended: np.ndarray,
        e_upper: np.ndarray,
        e_lower: np.ndarray,
    ) -> np.ndarray:
        """(N, N_STRIDES) metres to add to layer ``i``'s stride errors where it blends.

        Why this bound: the composed surface is B = (1 - w) L + w U per node. Drawn at stride
        s it is the bilinear interpolation of node values; at a point p of a drawn cell whose
        corners have weights w_i = w(p) + d_i and barycentric weights l_i,
            interp(B) - B*(p) = (1 - w)(interp L - L*) + w (interp U - U*)
                                + sum l_i d_i (U_i - L_i),
        so |error| <= max(e_L, e_U) + max|d_i| * max|U_i - L_i|. `metadata` already takes the
        max over the layers (the first term); this is the second. max|d_i| is
        `weight_change_bound` of the drawn cell; max|U_i - L_i| over the tile's nodes is
        `_difference_bound` (a per-tile table, not the height ranges: the base's range over a
        20' ancestor spans the ocean floor too, and a bound of thousands of metres made the
        band refine to the finest level, 1.5 M triangles at a 174 km view).
        """
        n = len(x)
        mask = self._blend_mask(st)
        inband = blended & mask.touches_band(*tile_bounds_arrays(level, x, y))
        if not inband.any():
            return np.zeros((n, N_STRIDES))
        lm = st.max_level
        f = max(0, level - lm)
        if f == 0:
            total = self._blend_total(i, st, level, x, y, e_upper, e_lower)
        else:
            # Finer than the layer's data the band is the blend at its finest level, upsampled
            # (`_compose`): stride s here is stride s / 2^f there, and up to stride 2^f the
            # drawn surface is that level's stride-1 surface exactly.
            ax, ay = x >> f, y >> f
            e_up = np.nan_to_num(st.tile_stride_error(lm, ax, ay).astype(np.float64))
            e_low = self._metadata(lm, ax, ay, i).stride_error
            at_lm = self._blend_total(i, st, lm, ax, ay, e_up, e_low)
            total = np.repeat(at_lm[:, :1], N_STRIDES, axis=1)
            if f < N_STRIDES:
                total[:, f:] = at_lm[:, : N_STRIDES - f]
            # Measured on the tile where it can be: the composed surface here is the
            # composed ancestor's bilinear surface sampled (`_paste`), whose error is at most
            # at_lm's stride 1, so `drawn_error`'s bound holds with that as the base.
            measured = self._measured_virtual(
                (st, i),
                level,
                lm,
                x,
                y,
                inband,
                at_lm[:, 0],
                functools.partial(self._band_ancestor, i),
            )
            # There the composed surface is those nodes alone (the layer's own heights are
            # not drawn), so the measured bound replaces the layer's: the "extra" may be < 0.
            exact = np.isfinite(measured)
            extra = np.where(exact, measured - e_upper, np.maximum(total - e_upper, 0.0))
            return np.where(inband[:, None], extra, 0.0)
        extra = np.maximum(total - e_upper, 0.0)
        return np.where(inband[:, None], extra, 0.0)

    def _band_ancestor(self, i: int, key: tuple[int, int, int]) -> np.ndarray:
        """The first ``i + 1`` visible layers composed at a tile at layer ``i``'s finest
        level, as `_paste` upsamples it inside the layer's border band below that level."""
        return self._composed_padded(key, i + 1)[1:-1, 1:-1]

    def _blend_total(
        self,
        i: int,
        st: TileStore,
        level: int,
        x: np.ndarray,
        y: np.ndarray,
        e_upper: np.ndarray,
        e_lower: np.ndarray,
    ) -> np.ndarray:
        """(N, N_STRIDES) metres: a bound on the composed surface's stride errors (layer ``i``
        blended over those below) on tiles at ``level`` <= the layer's finest, given both
        surfaces' own stride errors there.

        Two bounds, the smaller taken: max(e_U, e_L) + `_blend_terms` (the interpolation
        algebra), and, where the band's tiles were measured (`_difference_table`), E(s) + the
        first bound at stride 1, with E(s) = max |interp_s(B) - B| over the tile's nodes: the
        drawn surface minus the stride-1 surface is bilinear on the stride-1 grid, so E is
        exact, and the stride-1 surface departs from the reference by the stride-1 bound.
        """
        e_here = e_upper[:, 0] + e_lower[:, 0]
        bound = np.maximum(e_upper, e_lower) + self._blend_terms(i, st, level, x, y, e_here)
        measured = self._self_interpolation(i, st, level, x, y)
        if measured is not None:
            bound = np.minimum(bound, measured + bound[:, :1])
        return bound

    def _blend_terms(
        self, i: int, st: TileStore, level: int, x: np.ndarray, y: np.ndarray, e_here: np.ndarray
    ) -> np.ndarray:
        """(N, N_STRIDES) metres: the blend's part of the stride errors of tiles at ``level``
        (<= the layer's finest), ``e_here`` a bound on both layers' stride-1 errors there.

        With d_i = w_i - w(p), Delta = U - L and Delta' its interpolation at p:
            sum l_i d_i Delta_i = Delta' (interp w - w)(p) + sum l_i d_i (Delta_i - Delta'),
        so it is at most D * W2 + dw * S, where D = max|Delta| over the tile's nodes, W2 =
        `interpolation_error` of w for the drawn cell (0 for cells inside one raster cell of
        w), dw = `weight_change_bound` and S the largest spread of Delta over a drawn cell's
        corners; and never more than dw * D. Where the band holds too many tiles for exact
        node statistics, only the dw * D bound is used (`_difference_bound`).

        The reference is the finest composed surface (the blended nodes at the layer's
        finest level, bilinear between), which departs from the blend of the full-resolution
        surfaces by at most dw(finest cell) * S(finest): every drawn surface but those very
        nodes adds that.
        """
        mask = self._blend_mask(st)
        tile_n = int(np.log2(st.tile_size - 1))
        strides = 2.0 ** np.arange(N_STRIDES)
        lm = st.max_level
        cells = strides * node_spacing(level, tile_n)
        dw = weight_change_bound(cells, mask.band)
        diff, spread = self._difference_bound(i, st, level, x, y, e_here)
        first = diff[:, None] * dw[None, :]
        if spread is None:
            terms = first
        else:
            w2 = np.array([interpolation_error(mask, c) for c in cells])
            terms = np.minimum(first, diff[:, None] * w2[None, :] + spread * dw[None, :])
        finest_cell = node_spacing(lm, tile_n)
        c_lm = self._exact_level(i, st, lm)
        if c_lm == lm:
            _, _, s_lm, _ = self._difference_table(i, st, lm)
            spread_lm = np.full(len(x), float(s_lm[..., 0].max(initial=0.0)))
        else:
            # Per tile: a cell's spread is at most twice the largest |U - L| (``diff``
            # bounds it over the tile, to full resolution).
            spread_lm = 2.0 * diff
        terms = terms + (weight_change_bound(finest_cell, mask.band) * spread_lm)[..., None]
        if level == lm:
            terms[:, 0] = 0.0  # stride 1 at the finest level draws the blended nodes themselves
        return terms

    def _difference_bound(
        self, i: int, st: TileStore, level: int, x: np.ndarray, y: np.ndarray, e_here: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """A bound on |U_i - L_i| over the nodes of each tile (level, x, y): (N,) metres, layer
        ``i``'s heights minus the composed layers' below it; and (N, N_STRIDES) the largest
        spread of U - L over a drawn cell's corners at each stride, or None where not exact.
        ``e_here``: (N,) a bound on both layers' stride-1 errors on these tiles.

        Exact (node statistics from `_difference_table`) at levels whose band holds at most
        `DIFF_TABLE_TILES` tiles. Finer than that, from the ancestor at the finest such level
        c: |U* - L*| <= its node max + both stride-1 errors at c (both surfaces are bilinear
        on the same node grid there, so their difference peaks at a node, and each departs
        from full resolution by at most its stride-1 error), and the nodes here depart from
        U*, L* by ``e_here``.
        """
        c = self._exact_level(i, st, level)
        grid, table, spread, _ = self._difference_table(i, st, c)
        k = level - c
        iy, ix, inside = grid.tile_slots(y >> k, x >> k)
        d = np.where(inside, table[iy, ix], 0.0)
        if k == 0:
            return d, np.where(inside[:, None], spread[iy, ix], 0.0)
        xa, ya = x >> k, y >> k
        e_up = np.nan_to_num(st.tile_stride_error(c, xa % grid.ncols, ya)[..., 0])
        e_low = self._metadata(c, xa, ya, i).stride_error[:, 0]
        return d + e_up + e_low + e_here, None

    def _self_interpolation(
        self, i: int, st: TileStore, level: int, x: np.ndarray, y: np.ndarray
    ) -> np.ndarray | None:
        """(N, N_STRIDES) E(s) of `_blend_total` where ``level`` is measured, else None."""
        if self._exact_level(i, st, level) != level:
            return None
        grid, _, _, measured = self._difference_table(i, st, level)
        iy, ix, inside = grid.tile_slots(y, x)
        # Outside the measured band tiles nothing is blended: no extra error there.
        return np.where(inside[:, None], measured[iy, ix], 0.0)

    def _exact_level(self, i: int, st: TileStore, level: int) -> int:
        """The finest level <= ``level`` whose border band holds at most `DIFF_TABLE_TILES`
        tiles of layer ``i`` (one-time work per level is bounded)."""
        for c in range(level, -1, -1):
            key = (st, c)
            with self._lock:
                n = self._band_counts.get(key)
            if n is None:
                mask = self._blend_mask(st)
                grid = st.level_grid(c)
                ys, xs = np.mgrid[grid.y0 : grid.y0 + grid.ny, grid.x0 : grid.x0 + grid.nx]
                n = int(mask.touches_band(*tile_bounds_arrays(c, xs.ravel(), ys.ravel())).sum())
                with self._lock:
                    self._band_counts[key] = n
            if n <= DIFF_TABLE_TILES:
                return c
        return 0

    def _difference_table(self, i: int, st: TileStore, level: int) -> tuple:
        """(grid, (ny, nx) table): max over each tile's nodes of |U - L| (layer ``i`` minus the
        composed layers below it) at ``level``, for the tiles in the layer's border band (0
        elsewhere: the blend term is zero there). Built once per level and stack of layers
        below (a bounded number of tiles, see `_exact_level`), never per frame."""
        below = tuple(ly.store for ly in self.visible_layers[:i])
        key = (st, below, level)
        with self._lock:
            hit = self._diffs.get(key)
            unread = self._diffs_unread.get(key)
        if hit is not None and (unread is None or time.monotonic() < unread[0]):
            return hit
        version = self.version
        grid = st.level_grid(level)
        ys, xs = np.mgrid[grid.y0 : grid.y0 + grid.ny, grid.x0 : grid.x0 + grid.nx]
        xs = xs % grid.ncols
        if hit is None:
            mask = self._blend_mask(st)
            todo = st.has_data(level, xs, ys)
            todo &= mask.touches_band(*tile_bounds_arrays(level, xs, ys))
            tiles = [(int(j), int(c)) for j, c in zip(*np.nonzero(todo), strict=True)]
            table = np.zeros(todo.shape)
            spread = np.zeros((*todo.shape, N_STRIDES))
            measured = np.zeros((*todo.shape, N_STRIDES))
        else:  # only the tiles that could not be read last time, into copies
            assert unread is not None
            tiles = unread[1]
            table, spread, measured = (a.copy() for a in hit[1:])
        missed: list[tuple[int, int]] = []
        for j, c in tiles:
            tile = (level, int(xs[j, c]), int(ys[j, c]))
            try:
                lower = self._compose(tile, i)
                composed = lower.copy()
                upper = self._paste(i, st, tile, composed)
            except StoreError:
                # A tile that cannot be read now (see DIFF_RETRY_S): bounded from the height
                # ranges below, measured again later.
                missed.append((j, c))
                continue
            if upper is None:
                table[j, c] = 0.0
                spread[j, c] = 0.0
                measured[j, c] = 0.0
                continue
            # Where either is missing the node is one layer's own: B_i = L_i + w_i * 0 with
            # the continuous w_i (U taken as L where U has no data, L as U where L has none),
            # so Delta is 0 there, and a drawn cell across a ragged data edge has its real
            # spread (ignoring those corners once under-counted the blend at Crater Lake's
            # edge: 102 m measured against 84 m recorded).
            delta = np.nan_to_num(upper.astype(np.float64) - lower, nan=0.0)
            table[j, c] = float(np.abs(delta).max())
            spread[j, c] = _cell_spreads(delta)
            measured[j, c] = _stride_interpolation_errors(composed)
        if missed:
            self._bound_unread(i, st, level, xs, ys, missed, table, spread, measured)
        hit = (grid, table, spread, measured)
        with self._lock:
            if self.version == version:  # the layers changed meanwhile: do not keep it
                self._diffs[key] = hit
                if missed:
                    self._diffs_unread[key] = (time.monotonic() + DIFF_RETRY_S, missed)
                else:
                    self._diffs_unread.pop(key, None)
        return hit

    def _bound_unread(
        self,
        i: int,
        st: TileStore,
        level: int,
        xs: np.ndarray,
        ys: np.ndarray,
        tiles: list[tuple[int, int]],
        table: np.ndarray,
        spread: np.ndarray,
        measured: np.ndarray,
    ) -> None:
        """Fill `_difference_table`'s rows of band tiles that could not be read with bounds
        from the manifests alone: |U - L| <= max(U_max - L_min, L_max - U_min) from layer
        ``i``'s and the composed lower layers' height ranges (`_metadata`), a drawn cell's
        spread of U - L <= twice that, and E(s) not measured (inf: `_blend_total` keeps its
        algebraic bound). Looser than the measured values, never smaller."""
        jj = np.array([t[0] for t in tiles])
        cc = np.array([t[1] for t in tiles])
        x, y = xs[jj, cc], ys[jj, cc]
        u_lo, u_hi = (np.nan_to_num(v.astype(np.float64)) for v in st.tile_hrange(level, x, y))
        below = self._metadata(level, x, y, i)
        d = np.maximum(u_hi - below.hmin, below.hmax - u_lo)
        d = np.maximum(d, 0.0)
        table[jj, cc] = d
        spread[jj, cc] = 2.0 * d[:, None]
        measured[jj, cc] = np.inf

    def blend_weight(self, i: int, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """Weight (0..1) of visible layer ``i`` over the layers below at points (degrees): 1
        deep inside its data, falling to 0 across its border band (the bottom layer: 1)."""
        lon = np.asarray(lon, dtype=np.float64)
        if i == 0:
            return np.ones(lon.shape)
        mask = self._blend_mask(self.visible_layers[i].store)
        return mask.sample(lon, np.asarray(lat, dtype=np.float64))

    def _blend_mask(self, st: TileStore) -> BlendMask:
        """The layer's blend weight raster (built once per store)."""
        with self._lock:
            hit = self._masks.get(st)
        if hit is None:
            hit = BlendMask(st)
            with self._lock:
                self._masks[st] = hit
        return hit

    def _blend_weight(self, st: TileStore, key: tuple[int, int, int]) -> np.ndarray | None:
        """(size, size) weight of a layer over those below at a tile's nodes; None where the
        whole tile is deeper inside the layer than its band (nothing to blend)."""
        mask = self._blend_mask(st)
        w_, s_, e_, n_ = (float(v) for v in tile_bounds_arrays(*key))
        if not mask.touches_band_one(w_, s_, e_, n_):
            return None
        return mask.sample_grid(w_, s_, e_, n_, self.tile_size).astype(np.float32)

    def _layer_table(self, st: TileStore, level: int):
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

    # -- heights -------------------------------------------------------------------------------
    def heights(self, key: tuple[int, int, int]) -> np.ndarray:
        """Composed (size, size) float32 heights of a tile (metres, row 0 at the north)."""
        key = (int(key[0]), int(key[1]), int(key[2]))
        with self._lock:
            hit = self._cache.get(key)
        if hit is not None:
            return hit
        version = self.version
        out = self._compose(key, len(self.visible_layers))
        if not np.isfinite(out).all():  # (nan_to_num's own checks cost more than a compose step)
            np.nan_to_num(out, copy=False, nan=0.0)
        with self._lock:
            if version != self.version:  # the layers changed meanwhile: do not cache
                return out
            self._cache[key] = out
            self._order.append(key)
            if len(self._order) > self.cache_tiles:
                self._cache.pop(self._order.pop(0), None)
        return out

    def _compose(self, key: tuple[int, int, int], upto: int) -> np.ndarray:
        """The first ``upto`` visible layers composed at a tile (NaN where none has data)."""
        size = self.tile_size
        layers = self.visible_layers[:upto]
        first, own = self._opaque_layer(layers, key, self._layer_heights, self._tile_blends)
        out = np.full((size, size), np.nan, dtype=np.float32)
        for i in range(first, len(layers)):
            self._paste(i, layers[i].store, key, out, own.get(i, _UNREAD))
        return out

    def _tile_blends(self, st: TileStore, key: tuple[int, int, int]) -> bool:
        """Whether `_paste` blends the layer into those below at this tile (`_blend_weight`
        is not None), without sampling the weights."""
        mask = self._blend_mask(st)
        w_, s_, e_, n_ = (float(v) for v in tile_bounds_arrays(*key))
        return mask.touches_band_one(w_, s_, e_, n_)

    def _opaque_layer(
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
            if j == 0 or not self.blend or not blends(st, key):
                return j, seen
        return 0, seen

    def _paste(
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
        h = self._layer_heights(st, key) if own is _UNREAD else own
        if h is None:
            return None
        assert isinstance(h, np.ndarray)
        has = ~np.isnan(h)
        # A layer over another one feathers into it near its data's edge; the bottom layer
        # has nothing to blend into.
        w = self._blend_weight(st, key) if i > 0 and self.blend else None
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
                anc = self._composed_padded((st.max_level, ax, ay), i + 1)[1:-1, 1:-1]
                h = upsample_subtile(anc, f, key[1] - (ax << f), key[2] - (ay << f))
                has = ~np.isnan(h)
            else:
                # Where nothing lies below (NaN) the layer keeps its own heights.
                mixed = np.where(np.isnan(out), h, out + w * (h - out))
                h = np.where(has, mixed, np.nan).astype(np.float32)
        np.copyto(out, h, where=has)
        return mine

    def heights_apron(self, key: tuple[int, int, int]) -> np.ndarray:
        """The tile's composed heights with one node beyond each edge: (size + 2, size + 2)
        float32 metres, row 0 north, for `build_tile_mesh`'s ``apron`` (normals at edge nodes
        then see the neighbours' triangles, exactly as if the tile had no edge).

        The interior is `heights` (the same array values); the ring holds the 8 same-level
        neighbours' nodes next to the edges, composed on the ring alone (`_compose_ring`)
        without composing the neighbours: equal to the neighbours' own `heights` there up to
        float rounding (the neighbours' separable products against a bilinear gather: under
        1 mm over the embedded layers' extent edges at their finest level - 1 to + 3, with and
        without blending, and at DEMs ending at +-180; tests/render/test_tile_build.py).
        Where a layer's data edge lies on this tile's edge finer than the layer's data, the
        ring nodes on that side are the neighbours' `heights` themselves
        (`_ring_from_neighbours`). Columns wrap across the antimeridian. Beyond the poles
        there is no neighbour: the ring row is extrapolated linearly from the two rows inside
        (its latitude is clamped to the pole by the mesh builder anyway). Outside any data the
        ring is the ellipsoid (height 0), which is what `heights` composes there too.
        """
        level, x, y = (int(key[0]), int(key[1]), int(key[2]))
        size = self.tile_size
        out = np.empty((size + 2, size + 2), dtype=np.float32)
        out[1:-1, 1:-1] = self.heights((level, x, y))
        rows, cols = _ring_index(size)
        ring = self._compose_ring((level, x, y), len(self.visible_layers))
        ring[np.isnan(ring)] = 0.0  # no data: the ellipsoid, as `heights` composes it
        out[rows, cols] = ring
        if y == 0:
            out[0] = 2.0 * out[1] - out[2]
        if y == (1 << level) - 1:
            out[-1] = 2.0 * out[-2] - out[-3]
        return out

    def _layer_heights(self, st: TileStore, key: tuple[int, int, int]) -> np.ndarray | None:
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

    # -- the apron ring ------------------------------------------------------------------------
    # `heights_apron` needs one node beyond each edge of a tile. Composing the 8 neighbours
    # for it cost twice the tile itself (a view's outer tiles have neighbours nobody else
    # asks for; issue #17: 0.9 of 2 ms a tile). The ring is composed instead on its own
    # 4 (size + 1) nodes, node by node as the neighbour composes them: each layer's ring
    # heights from the store's padded window (`TileStore.heights_padded`: the neighbours'
    # edge-adjacent nodes) or its finest ancestor's, interpolated; blend weights sampled at
    # the ring's points. The same values as the neighbours' up to rounding: a bilinear
    # gather instead of their separable matrix products (float64, then float32), NaN where
    # their `bilinear` has NaN. One case cannot be had from this tile's side: finer than a
    # layer's data, where the layer's data edge lies on this tile's edge, the neighbour
    # upsamples a different ancestor, and the store serves the shared edge nodes from the
    # ancestor outside the extent as NaN (N44W072's 45 N edge, a DEM ending at +-180). Those
    # ring nodes are copied from the neighbour's composition (`_ring_from_neighbours`).
    def _compose_ring(self, key: tuple[int, int, int], upto: int) -> np.ndarray:
        """(4 (size + 1),) float32: the first ``upto`` visible layers composed at the ring
        nodes of a tile (`_ring_index` order; NaN where none has data)."""
        visible = self.visible_layers
        layers = visible[:upto]
        first, own = self._opaque_layer(layers, key, self._layer_ring, self._ring_blends)
        out = np.full(4 * (self.tile_size + 1), np.nan, dtype=np.float32)
        for i in range(first, len(layers)):
            self._paste_ring(i, layers[i].store, key, out, own.get(i, _UNREAD))
        level, x, y = key
        for dy, dx in self._ring_from_neighbours(key, layers):
            # Where a layer's data edge lies on this tile's edge, finer than the layer's data,
            # the two sides upsample different ancestors that disagree on the shared edge
            # nodes (the one outside the extent serves NaN there, as `heights` always did):
            # the ring takes the neighbour's own composition (rare tiles: data edges only).
            nkey = (level, (x + dx) % (2 << level), y + dy)
            nb = self.heights(nkey) if upto == len(visible) else self._compose(nkey, upto)
            sel, src_r, src_c = _ring_segment(self.tile_size, dy, dx)
            out[sel] = nb[src_r, src_c]
        return out

    def _ring_from_neighbours(
        self, key: tuple[int, int, int], layers: list[TerrainLayer]
    ) -> list[tuple[int, int]]:
        """The neighbours (dy, dx) whose ring nodes must be read from their composition: for
        a layer finer than its data here (level > its max level), a neighbour whose finest
        ancestor differs from this tile's and has tile data where this one has none or the
        other way round (`TileStore.has_tile`; the store serves NaN on the shared edge from
        the ancestor outside the layer's extent). Empty for nearly every tile: a tile
        strictly inside its ancestor, or with every ancestor around on the same side of the
        layer's data edge."""
        level, x, y = key
        ncols, nrows = 2 << level, 1 << level
        need: set[tuple[int, int]] = set()
        for layer in layers:
            st = layer.store
            lm = st.max_level
            f = level - lm
            if f <= 0:
                continue
            # The side (-1, +1, or 0: none) on which the tile touches its ancestor's edge,
            # per axis (f >= 1: at most one side each); beyond a pole there is no neighbour
            # (`heights_apron` extrapolates that row).
            m = (1 << f) - 1
            sx = -1 if x & m == 0 else (1 if x & m == m else 0)
            sy = -1 if y & m == 0 else (1 if y & m == m else 0)
            if not 0 <= y + sy < nrows:
                sy = 0
            if not (sx or sy):
                continue  # every neighbour shares this tile's ancestor
            ax, ay = x >> f, y >> f
            mine = st.has_tile(lm, ax, ay)
            nax = ((x + sx) % ncols) >> f
            # Whether the ancestor across the column edge, the row edge, the corner differs.
            across_x = bool(sx) and st.has_tile(lm, nax, ay) != mine
            across_y = bool(sy) and st.has_tile(lm, ax, ay + sy) != mine
            corner = bool(sx and sy) and st.has_tile(lm, nax, ay + sy) != mine
            if across_x:  # the neighbours on that column side, but the corner's
                need.update(
                    (dy, sx) for dy in (-1, 0, 1) if (dy != sy or not sy) and 0 <= y + dy < nrows
                )
            if across_y:  # the neighbours on that row side, but the corner's
                need.update((sy, dx) for dx in (-1, 0, 1) if dx != sx or not sx)
            if corner:
                need.add((sy, sx))
        return sorted(need)

    def _ring_blends(self, st: TileStore, key: tuple[int, int, int]) -> bool:
        """Whether `_paste_ring` blends the layer at a tile's ring (`_blend_ring` not None)."""
        w_, s_, e_, n_ = (float(v) for v in tile_bounds_arrays(*key))
        d_lon = (e_ - w_) / (self.tile_size - 1)
        d_lat = (n_ - s_) / (self.tile_size - 1)
        mask = self._blend_mask(st)
        return mask.touches_band_one(w_ - d_lon, s_ - d_lat, e_ + d_lon, n_ + d_lat)

    def _paste_ring(
        self,
        i: int,
        st: TileStore,
        key: tuple[int, int, int],
        out: np.ndarray,
        own: np.ndarray | object | None = _UNREAD,
    ) -> None:
        """`_paste` on the ring nodes of a tile (``out``: the layers below there; ``own``:
        the layer's ring heights when already read)."""
        h = self._layer_ring(st, key) if own is _UNREAD else own
        if h is None:
            return
        assert isinstance(h, np.ndarray)
        has = ~np.isnan(h)
        if i > 0 and self.blend:
            w = self._blend_ring(st, key)
            if w is not None:
                f = key[0] - st.max_level
                if f > 0:
                    # The band finer than the layer's data: the blend at its finest level,
                    # upsampled (as `_paste`), from the padded composed ancestor.
                    ax, ay = key[1] >> f, key[2] >> f
                    anc = self._composed_padded((st.max_level, ax, ay), i + 1)
                    h = _upsample_ring(anc, f, key[1] - (ax << f), key[2] - (ay << f))
                    has = ~np.isnan(h)
                else:
                    mixed = np.where(np.isnan(out), h, out + w * (h - out))
                    h = np.where(has, mixed, np.nan).astype(np.float32)
        np.copyto(out, h, where=has)

    def _layer_ring(self, st: TileStore, key: tuple[int, int, int]) -> np.ndarray | None:
        """A layer's own heights at a tile's ring nodes (NaN = no data), None where neither
        the tile nor its neighbours have data of the layer."""
        level, x, y = key
        lm = st.max_level
        rows, cols = _ring_index(self.tile_size)
        if level <= lm:
            if not st.has_data_near(level, x, y):
                return None
            return st.heights_padded(key)[rows, cols]
        f = level - lm
        ax, ay = x >> f, y >> f
        if not st.has_data_near(lm, ax, ay):
            return None
        return _upsample_ring(st.heights_padded((lm, ax, ay)), f, x - (ax << f), y - (ay << f))

    def _blend_ring(self, st: TileStore, key: tuple[int, int, int]) -> np.ndarray | None:
        """(ring,) float32 weight of a layer over those below at a tile's ring nodes; None
        where the tile grown by one node is deeper inside the layer than its band."""
        mask = self._blend_mask(st)
        w_, s_, e_, n_ = (float(v) for v in tile_bounds_arrays(*key))
        size = self.tile_size
        d_lon = (e_ - w_) / (size - 1)
        d_lat = (n_ - s_) / (size - 1)
        grown = (w_ - d_lon, s_ - d_lat, e_ + d_lon, n_ + d_lat)
        if not mask.touches_band_one(*grown):
            return None
        rows, cols = _ring_index(size)
        t = np.arange(-1, size + 1, dtype=np.float64)
        lon = (w_ + d_lon * t)[cols]
        lat = (n_ - d_lat * t)[rows]
        return mask.sample(lon, lat).astype(np.float32)

    def _composed_padded(self, key: tuple[int, int, int], upto: int) -> np.ndarray:
        """(size + 2)^2 float32: the first ``upto`` layers composed at a tile and its ring
        (NaN where none has data). Cached with the composed tiles: a layer's border band
        finer than its data upsamples one such ancestor for up to 4^f tiles."""
        ckey = (int(key[0]), int(key[1]), int(key[2]), int(upto))
        with self._lock:
            hit = self._cache.get(ckey)
        if hit is not None:
            return hit
        version = self.version
        size = self.tile_size
        out = np.empty((size + 2, size + 2), dtype=np.float32)
        out[1:-1, 1:-1] = self._compose(key, upto)
        rows, cols = _ring_index(size)
        out[rows, cols] = self._compose_ring(key, upto)
        self._remember(ckey, out, version)
        return out

    def _remember(self, ckey: tuple, value: np.ndarray, version: int) -> None:
        """Cache ``value`` under ``ckey`` unless the layers changed since ``version``."""
        with self._lock:
            if version != self.version:  # the layers changed meanwhile: do not cache
                return
            self._cache[ckey] = value
            self._order.append(ckey)
            if len(self._order) > self.cache_tiles:
                self._cache.pop(self._order.pop(0), None)

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


def _ring_index(size: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the ring nodes of a (size + 2)^2 padded tile: the top row, the bottom
    row, then the left and right columns between them (4 (size + 1) nodes)."""
    hit = _RING.get(size)
    if hit is None:
        n = size + 2
        inner = np.arange(1, n - 1)
        rows = np.concatenate([np.zeros(n, np.int64), np.full(n, n - 1), inner, inner])
        cols = np.concatenate(
            [np.arange(n), np.arange(n), np.zeros(n - 2, np.int64), np.full(n - 2, n - 1)]
        )
        hit = _RING[size] = (rows, cols)
    return hit


_RING: dict[int, tuple[np.ndarray, np.ndarray]] = {}


@functools.lru_cache(maxsize=64)
def _ring_segment(size: int, dy: int, dx: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ring positions, rows, cols): the ring nodes (`_ring_index` order) that lie in the
    same-level neighbour (dy, dx) of a tile, and their (row, col) in that neighbour's
    (size, size) heights (neighbouring tiles share their edge nodes: the node beyond an
    edge is the neighbour's second row or column). Read-only (shared by the cache)."""
    rows, cols = _ring_index(size)
    ry = np.where(rows == 0, -1, np.where(rows == size + 1, 1, 0))
    cx = np.where(cols == 0, -1, np.where(cols == size + 1, 1, 0))
    sel = np.nonzero((ry == dy) & (cx == dx))[0]
    src = {-1: size - 2, 1: 1}
    src_r = np.full(sel.shape, src[dy]) if dy else rows[sel] - 1
    src_c = np.full(sel.shape, src[dx]) if dx else cols[sel] - 1
    for a in (sel, src_r, src_c):
        a.flags.writeable = False
    return sel, src_r, src_c


def _upsample_ring(anc: np.ndarray, f: int, dx: int, dy: int) -> np.ndarray:
    """(ring,) float32: the ring nodes of a descendant tile ``f`` levels below the padded
    ancestor ``anc`` ((size + 2)^2, `TileStore.heights_padded`), offset (dx, dy) tiles inside
    it, interpolated bilinearly. Ring nodes beyond the ancestor's edge lie within its first
    padded cell: the neighbouring ancestor's own bilinear surface there.

    Separable, as the tile's own upsampling: the two ring rows are interpolated down the
    ancestor's columns then along the row, the two ring columns the other way round (float64
    sums of the same two terms per axis). NaN as `bilinear` has it, which the neighbour's
    `upsample_subtile` uses when its ancestor has NaN: the result is NaN where any corner of
    the node's cell is NaN, a corner of weight 0 included (NaN * 0), the cell chosen as
    `bilinear` chooses it in the neighbour's ancestor (`_ring_axis`). Where that ancestor has
    no NaN the two agree up to float rounding (the neighbour's separable products)."""
    size = anc.shape[0] - 2
    r0, rf = _ring_axis(size, f, dy)
    c0, cf = _ring_axis(size, f, dx)
    g = anc.astype(np.float64)
    n = size + 2
    out = np.empty(4 * (size + 1))
    for j, r in enumerate((0, n - 1)):  # the top and bottom ring rows
        line = _lerp(g[r0[r]], g[r0[r] + 1], rf[r])  # along the ancestor's columns
        out[j * n : (j + 1) * n] = _lerp(line[c0], line[c0 + 1], cf)
    for j, c in enumerate((0, n - 1)):  # the left and right ring columns, between them
        line = _lerp(g[:, c0[c]], g[:, c0[c] + 1], cf[c])
        out[2 * n + j * (n - 2) : 2 * n + (j + 1) * (n - 2)] = _lerp(
            line[r0[1:-1]], line[r0[1:-1] + 1], rf[1:-1]
        )
    return out.astype(np.float32)


@functools.lru_cache(maxsize=1024)
def _ring_axis(size: int, f: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    """(first node, fraction), each (size + 2,), of the padded nodes -1..size of a descendant
    ``f`` levels below, at tile offset ``d``, along one axis of its padded ancestor (grid
    positions exact: integers over a power of two). Read-only (shared by the cache).

    The cell is the one `bilinear` takes in the ancestor that holds the node (this tile's,
    or for a node beyond its edge, in (size, size + 1) or (0, 1), the neighbouring one's
    first cell): the floor, except on the ancestor's last node (padded ``size``), which
    belongs to its last cell with fraction 1, as `bilinear` clamps it. That choice decides
    which weight-0 corner makes a node NaN (`_upsample_ring`)."""
    cells = size - 1
    scale = 2**f
    pos = (d * cells + np.arange(-1, size + 1, dtype=np.float64) + scale) / scale
    i0 = np.floor(pos).astype(np.int64)
    i0[pos == size] = size - 1  # the ancestor's last node: its last cell, fraction 1
    frac = pos - i0
    i0.flags.writeable = False
    frac.flags.writeable = False
    return i0, frac


def _lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """a (1 - t) + b t: exactly a where t = 0 and b where t = 1 when both are finite, NaN
    where either is NaN, its weight 0 included (`bilinear`'s rule)."""
    return a * (1.0 - t) + b * t


def _stride_interpolation_errors(h: np.ndarray) -> np.ndarray:
    """(N_STRIDES,) max |bilinear of every s-th node - the nodes| of a (size, size) tile, s =
    1, 2, 4, ... 64 (size - 1 a multiple of 64)."""
    size = h.shape[0]
    out = np.zeros(N_STRIDES)
    nodes = np.arange(size, dtype=np.float64)
    g = np.nan_to_num(h.astype(np.float64), nan=0.0)  # as drawn: no data is the ellipsoid
    for k in range(1, N_STRIDES):
        s = 1 << k
        if s >= size:
            out[k:] = out[k - 1]
            break
        m = linear_weights(nodes / s, g[::s, ::s].shape[0])
        out[k] = float(np.abs(m @ g[::s, ::s] @ m.T - g).max())
    return out


def _cell_spreads(delta: np.ndarray) -> np.ndarray:
    """(N_STRIDES,) the largest max - min of ``delta`` over the four corners of a cell drawn
    every 1, 2, 4, ... 64 nodes (NaN corners ignored)."""
    out = np.zeros(N_STRIDES)
    for k in range(N_STRIDES):
        g = delta[:: 1 << k, :: 1 << k]
        if g.shape[0] < 2 or g.shape[1] < 2:
            break
        quad = np.stack([g[:-1, :-1], g[:-1, 1:], g[1:, :-1], g[1:, 1:]])
        hi = np.where(np.isnan(quad), -np.inf, quad).max(axis=0)
        lo = np.where(np.isnan(quad), np.inf, quad).min(axis=0)
        both = np.isfinite(hi) & np.isfinite(lo)
        out[k] = float((hi - lo)[both].max(initial=0.0))
    return out
