"""`TerrainStack`: the visible DEM layers composed into one terrain.

Each DEM layer is its own tile store (a global base, regional detail on top). The stack
answers, for any tile key of the ellipsoidal quadtree, what the composed surface is:

- **heights**: each visible layer's heights pasted in order (later layers win where they have
  data). A layer asked for a tile finer than its finest level answers with its finest
  ancestor tile upsampled bilinearly — exactly the surface it stands for, so that part adds
  no geometric error. Where no layer has data the surface is the ellipsoid (height 0).
- **metadata**, vectorised over arrays of keys for the LOD providers: geometric error per
  index stride (the max over the layers covering the key), height range, and whether any layer
  has finer data below the key.

Heights are metres above the ellipsoid; keys are (level, x, y) with y = 0 at the north pole
(see quadtree.py).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from globeview.errors import StoreError
from globeview.terrain.store import TileStore

#: Number of index strides with recorded errors: 1, 2, 4, ..., 64.
N_STRIDES = 7


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

    def __post_init__(self) -> None:
        self.version = 0
        self._lock = threading.Lock()
        self._cache: dict[tuple[int, int, int], np.ndarray] = {}
        self._order: list[tuple[int, int, int]] = []
        self._tables: dict[tuple[int, int], tuple] = {}
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
        self.layers = [ly for ly in self.layers if ly.name != name]
        self._changed()

    def set_visible(self, name: str, visible: bool) -> None:
        for ly in self.layers:
            if ly.name == name:
                ly.visible = visible
        self._changed()

    def move(self, name: str, index: int) -> None:
        """Move a layer to a new position (0 = bottom)."""
        layer = next(ly for ly in self.layers if ly.name == name)
        self.layers.remove(layer)
        self.layers.insert(index, layer)
        self._changed()

    def _changed(self) -> None:
        self.version += 1
        with self._lock:
            self._cache.clear()
            self._order.clear()

    def _check_sizes(self, layers: list[TerrainLayer] | None = None) -> None:
        sizes = {ly.store.tile_size for ly in (self.layers if layers is None else layers)}
        if len(sizes) > 1:
            raise StoreError(
                f"DEM layers use different tile sizes {sorted(sizes)}; re-ingest with one --tile-n"
            )

    @property
    def visible_layers(self) -> list[TerrainLayer]:
        return [ly for ly in self.layers if ly.visible]

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
        x = np.asarray(x, dtype=np.int64)
        y = np.asarray(y, dtype=np.int64)
        n = len(x)
        err = np.zeros((n, N_STRIDES), dtype=np.float64)
        hmin = np.full(n, np.inf)
        hmax = np.full(n, -np.inf)
        has_finer = np.zeros(n, dtype=bool)
        covered = np.zeros(n, dtype=bool)
        for layer in self.visible_layers:
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
                # Finer than the layer's data: its finest ancestor, upsampled. The height
                # error of stride s here is that of stride s / 2^f on the ancestor, and zero
                # below one ancestor cell.
                e = np.zeros((n, N_STRIDES))
                if f < N_STRIDES:
                    e[:, f:] = rows[:, 3 : 3 + N_STRIDES - f]
            covered |= ok
            err = np.where(ok[:, None], np.maximum(err, e), err)
            hmin = np.where(ok, np.minimum(hmin, rows[:, 1]), hmin)
            hmax = np.where(ok, np.maximum(hmax, rows[:, 2]), hmax)
        # Where a layer covers only part of the tile, the rest is the ellipsoid (height 0).
        hmin = np.where(covered, np.minimum(hmin, 0.0), 0.0)
        hmax = np.where(covered, np.maximum(hmax, 0.0), 0.0)
        return TileMetadata(err, hmin, hmax, has_finer, covered)

    def _layer_table(self, st: TileStore, level: int):
        """A layer's per-tile facts at a level as one dense (ny, nx, 3 + N_STRIDES) table:
        [has data, hmin, hmax, stride errors...] (built once, then looked up per frame)."""
        key = (id(st), level)
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
        size = self.tile_size
        out = np.full((size, size), np.nan, dtype=np.float32)
        for layer in self.visible_layers:
            h = self._layer_heights(layer.store, key)
            if h is not None:
                np.copyto(out, h, where=~np.isnan(h))
        np.nan_to_num(out, copy=False, nan=0.0)
        with self._lock:
            self._cache[key] = out
            self._order.append(key)
            if len(self._order) > self.cache_tiles:
                self._cache.pop(self._order.pop(0), None)
        return out

    def heights_apron(self, key: tuple[int, int, int]) -> np.ndarray:
        """The tile's composed heights with one node beyond each edge: (size + 2, size + 2)
        float32 metres, row 0 north, for `build_tile_mesh`'s ``apron`` (normals at edge nodes
        then see the neighbours' triangles, exactly as if the tile had no edge).

        The ring comes from the 8 same-level neighbours, composed by `heights` (so through its
        tile cache: neighbours drawn in the same view are usually already there); columns wrap
        across the antimeridian. Beyond the poles there is no neighbour: the ring row is
        extrapolated linearly from the two rows inside (its latitude is clamped to the pole by
        the mesh builder anyway). Outside any data the neighbours are the ellipsoid (height 0),
        which is what `heights` composes there too.
        """
        level, x, y = (int(key[0]), int(key[1]), int(key[2]))
        ncols, nrows = 2 << level, 1 << level
        size = self.tile_size
        out = np.empty((size + 2, size + 2), dtype=np.float32)
        # Neighbouring tiles share their edge nodes, so the node beyond our edge is the
        # neighbour's second row/column (index 1 or -2), not its first.
        dst = {-1: slice(0, 1), 0: slice(1, size + 1), 1: slice(size + 1, size + 2)}
        src = {-1: slice(size - 2, size - 1), 0: slice(0, size), 1: slice(1, 2)}
        for dy in (-1, 0, 1):
            ny = y + dy
            if not 0 <= ny < nrows:
                continue
            for dx in (-1, 0, 1):
                h = self.heights((level, (x + dx) % ncols, ny))
                out[dst[dy], dst[dx]] = h[src[dy], src[dx]]
        if y == 0:
            out[0] = 2.0 * out[1] - out[2]
        if y == nrows - 1:
            out[-1] = 2.0 * out[-2] - out[-3]
        return out

    def _layer_heights(self, st: TileStore, key: tuple[int, int, int]) -> np.ndarray | None:
        level, x, y = key
        lm = st.max_level
        if level <= lm:
            if not st.has_data(level, np.array([x]), np.array([y]))[0]:
                return None
            return st.heights(key)
        f = level - lm
        ax, ay = x >> f, y >> f
        if not st.has_data(lm, np.array([ax]), np.array([ay]))[0]:
            return None
        anc = st.heights((lm, ax, ay))
        return upsample_subtile(anc, f, x - (ax << f), y - (ay << f))

    def height_at(self, lon: float, lat: float, level: int | None = None) -> float:
        """Composed height (m) at a point, bilinear in the tile at ``level`` (default: the
        finest level any visible layer has, capped at 12)."""
        from globeview.terrain.quadtree import TileKey, key_for_lonlat, tile_bounds

        level = min(self.max_level, 12) if level is None else level
        kx, ky = key_for_lonlat(level, np.array([lon]), np.array([lat]))
        key = (level, int(np.asarray(kx).reshape(-1)[0]), int(np.asarray(ky).reshape(-1)[0]))
        h = self.heights(key)
        w, s, e, n = tile_bounds(TileKey(*key))
        size = h.shape[0]
        c = (lon - w) / (e - w) * (size - 1)
        r = (n - lat) / (n - s) * (size - 1)
        return float(bilinear(h, np.array([r]), np.array([c]))[0])


def bilinear(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a 2-D grid at fractional (row, col) node positions."""
    nr, nc = grid.shape
    r = np.clip(rows, 0.0, nr - 1.0)
    c = np.clip(cols, 0.0, nc - 1.0)
    r0 = np.minimum(np.floor(r).astype(np.int64), nr - 2)
    c0 = np.minimum(np.floor(c).astype(np.int64), nc - 2)
    fr = r - r0
    fc = c - c0
    g = grid.astype(np.float64)
    top = g[r0, c0] * (1 - fc) + g[r0, c0 + 1] * fc
    bot = g[r0 + 1, c0] * (1 - fc) + g[r0 + 1, c0 + 1] * fc
    return top * (1 - fr) + bot * fr


def upsample_subtile(anc: np.ndarray, f: int, dx: int, dy: int) -> np.ndarray:
    """The nodes of a descendant tile ``f`` levels below ``anc``, offset (dx, dy) tiles inside
    it, interpolated bilinearly from the ancestor's grid (exactly its bilinear surface)."""
    size = anc.shape[0]
    cells = size - 1
    scale = 2**f
    t = np.arange(size, dtype=np.float64)
    cols = (dx * cells + t) / scale
    rows = (dy * cells + t) / scale
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    return bilinear(anc, rr.reshape(-1), cc.reshape(-1)).reshape(size, size).astype(np.float32)
