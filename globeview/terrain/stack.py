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
        self._masks: dict[int, BlendMask] = {}
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
        strides = 2.0 ** np.arange(N_STRIDES)
        for i, layer in enumerate(self.visible_layers):
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
            if i > 0:
                e = e + self._blend_error(st, level, x, y, ok & covered, rows, hmin, hmax, strides)
            covered |= ok
            err = np.where(ok[:, None], np.maximum(err, e), err)
            hmin = np.where(ok, np.minimum(hmin, rows[:, 1]), hmin)
            hmax = np.where(ok, np.maximum(hmax, rows[:, 2]), hmax)
        # Where a layer covers only part of the tile, the rest is the ellipsoid (height 0).
        hmin = np.where(covered, np.minimum(hmin, 0.0), 0.0)
        hmax = np.where(covered, np.maximum(hmax, 0.0), 0.0)
        return TileMetadata(err, hmin, hmax, has_finer, covered)

    def _blend_error(self, st, level, x, y, both, rows, lo_below, hi_below, strides) -> np.ndarray:
        """(N, N_STRIDES) metres to add to a blended layer's stride errors in its border band.

        Why this bound: the composed surface there is B = (1 - w) L + w U per node. Drawn at
        stride s it is the linear interpolation of node values; at a point p of a drawn cell
        with w_i = w(p) + d_i at its corners,
            interp(B) - B*(p) = (1 - w)(interp L - L*) + w (interp U - U*) + sum l_i d_i (U_i - L_i)
        so |error| <= max(e_L, e_U) + max|d_i| * max|U - L|. The first term is the max over
        the layers that `metadata` already takes; this adds the second. w = smoothstep(d/band)
        has slope <= 1.5 / band and d (degrees, min over the sides) moves at most one cell
        side c = stride * node spacing between a point and a corner, so max|d_i| <=
        min(1, 1.5 c / band); max|U - L| <= the spread of the two tiles' height ranges.
        """
        from globeview.terrain.quadtree import node_spacing, tile_bounds_arrays

        n = len(x)
        extra = np.zeros((n, N_STRIDES))
        mask = self._blend_mask(st)
        band = mask.band
        inband = both & mask.touches_band(*tile_bounds_arrays(level, x, y))
        if not inband.any():
            return extra
        jump = np.maximum(np.abs(rows[:, 2] - lo_below), np.abs(hi_below - rows[:, 1]))
        # Below the layer's finest level the band is upsampled from that level (`_compose`):
        # stride s there is stride s / 2^f at the finest level, and exact below one cell.
        f = max(0, level - st.max_level)
        lv = level - f
        cell = strides * node_spacing(lv, int(np.log2(st.tile_size - 1)))
        # A drawn cell's corner is at most one cell side away along each axis (BlendMask).
        dw = np.minimum(1.0, 3.0 * cell / band)
        if lv == st.max_level:
            dw[0] = 0.0  # stride 1 at the finest level draws the finest blended nodes
        if f:
            dw = np.concatenate([np.zeros(min(f, N_STRIDES)), dw[: max(0, N_STRIDES - f)]])
        return np.where(inband[:, None], jump[:, None] * dw[None, :], 0.0)

    def _blend_mask(self, st: TileStore) -> BlendMask:
        """The layer's blend weight raster (built once per store, under the lock)."""
        with self._lock:
            hit = self._masks.get(id(st))
        if hit is None:
            hit = BlendMask(st)
            with self._lock:
                self._masks[id(st)] = hit
        return hit

    def _blend_weight(self, st: TileStore, key: tuple[int, int, int]) -> np.ndarray | None:
        """(size, size) weight of a layer over those below at a tile's nodes; None where the
        whole tile is deeper inside the layer than its band (nothing to blend)."""
        from globeview.terrain.quadtree import tile_bounds_arrays

        mask = self._blend_mask(st)
        tb = tile_bounds_arrays(*key)
        if not mask.touches_band(*(np.atleast_1d(v) for v in tb))[0]:
            return None
        w_, s_, e_, n_ = (float(v) for v in tb)
        size = self.tile_size
        lon, lat = np.meshgrid(np.linspace(w_, e_, size), np.linspace(n_, s_, size))
        return mask.sample(lon.ravel(), lat.ravel()).reshape(size, size).astype(np.float32)

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
        out = self._compose(key, len(self.visible_layers))
        np.nan_to_num(out, copy=False, nan=0.0)
        with self._lock:
            self._cache[key] = out
            self._order.append(key)
            if len(self._order) > self.cache_tiles:
                self._cache.pop(self._order.pop(0), None)
        return out

    def _compose(self, key: tuple[int, int, int], upto: int) -> np.ndarray:
        """The first ``upto`` visible layers composed at a tile (NaN where none has data)."""
        size = self.tile_size
        out = np.full((size, size), np.nan, dtype=np.float32)
        for i, layer in enumerate(self.visible_layers[:upto]):
            st = layer.store
            h = self._layer_heights(st, key)
            if h is None:
                continue
            has = ~np.isnan(h)
            # A layer over another one feathers into it near its footprint's edge (no cliff
            # at layer borders, issue #16); the bottom layer has nothing to blend into.
            w = self._blend_weight(st, key) if i > 0 else None
            if w is not None:
                f = key[0] - st.max_level
                if f > 0:
                    # Finer than the layer's data: its band is the blend at the layer's finest
                    # level, upsampled (so the band, like the layer, adds no detail below its
                    # finest level and its LOD errors stop there; finer data of a layer below
                    # is given up inside the band only).
                    ax, ay = key[1] >> f, key[2] >> f
                    anc = self._compose((st.max_level, ax, ay), i + 1)
                    mixed = upsample_subtile(anc, f, key[1] - (ax << f), key[2] - (ay << f))
                else:
                    lower = out
                    # Where nothing lies below (NaN) the layer keeps its own heights.
                    mixed = np.where(np.isnan(lower), h, lower + w * (h - lower))
                h = np.where(has, mixed, np.nan).astype(np.float32)
            np.copyto(out, h, where=has)
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


#: Width of a layer's border band as a fraction of its footprint's shorter side. The blend
#: must depend on position only (tiles of every level then agree on the surface), so the band
#: is a property of the layer, not of a tile or level. A tenth of the footprint leaves the
#: central 80 % of each axis untouched and spreads the step between, e.g., 30 m data and the
#: 20' base over ~100 of the regional data's own nodes.
BLEND_FRACTION = 0.05

#: The coverage mask is read at the coarsest level with at least this many nodes across the
#: footprint's shorter side (its edge is then exact to ~1 % of the footprint).
MASK_NODES = 160


def blend_band(bounds: tuple) -> float:
    """Border band width (degrees) of a layer with footprint (west, south, east, north)."""
    west, south, east, north = bounds
    span_lon = (east - west) % 360.0 or 360.0
    return BLEND_FRACTION * min(span_lon, north - south)


class BlendMask:
    """A layer's blend weight w(lon, lat) in [0, 1] over the layers below, on a fixed raster.

    w = smoothstep(clip(2 c - 1, 0, 1)), c = the fraction of the layer's data coverage in a
    square of half-side ``band`` around the point (an integral-image box mean of the layer's
    nodata mask, read once at one level). On a straight data edge c = 1/2, so w = 0 there and
    reaches 1 one band inside; it follows nodata holes and rotated footprints (projected
    sources leave nodata wedges inside their lon/lat box) as well as the box edge. Sampled
    bilinearly at any node, it depends on position only.

    Lipschitz bound (for the error bound in `TerrainStack._blend_error`): moving delta
    degrees along one axis changes c by <= delta / (2 band), 2c - 1 by <= delta / band, and
    smoothstep's slope is <= 1.5, so |dw| <= 1.5 (|dlon| + |dlat|) / band (bilinear sampling of
    the raster keeps that bound).
    """

    def __init__(self, st: TileStore) -> None:
        from globeview.terrain.quadtree import tile_bounds_arrays

        self.band = blend_band(st.bounds)
        short = self.band / BLEND_FRACTION
        tile_n = int(np.log2(st.tile_size - 1))
        lv = st.max_level
        for cand in range(st.max_level + 1):
            if short / ((180.0 / 2**cand) / 2**tile_n) >= MASK_NODES:
                lv = cand
                break
        grid = st.level_grid(lv)
        cells = st.tile_size - 1
        data = np.zeros((grid.ny * cells + 1, grid.nx * cells + 1), dtype=bool)
        for j in range(grid.ny):
            for i in range(grid.nx):
                x, y = (grid.x0 + i) % grid.ncols, grid.y0 + j
                if st.has_data(lv, np.array([x]), np.array([y]))[0]:
                    h = st.heights((lv, x, y))
                    sl = (
                        slice(j * cells, j * cells + cells + 1),
                        slice(i * cells, i * cells + cells + 1),
                    )
                    data[sl] |= ~np.isnan(h)
        self.step = (180.0 / 2**lv) / cells
        w0, _, _, n0 = (float(v) for v in tile_bounds_arrays(lv, grid.x0, grid.y0))
        r = max(1, round(self.band / self.step))
        # Pad by the box radius (no data beyond the raster) and box-mean with an integral image.
        pad = np.pad(data.astype(np.float64), r + 1)
        ii = pad.cumsum(0).cumsum(1)
        k = 2 * r + 1
        box = ii[k:, k:] - ii[:-k, k:] - ii[k:, :-k] + ii[:-k, :-k]
        c = box / (k * k)
        t = np.clip(2.0 * c - 1.0, 0.0, 1.0)
        # Output (i, j) is the box centred on data node (i, j); one extra row and column of
        # padding at the far ends.
        self.w = (t * t * (3.0 - 2.0 * t)).astype(np.float32)
        self.west, self.north = w0, n0
        # Integral image of "w < 1" cells: does a lon/lat box meet the band (metadata)?
        part = np.pad((self.w < 1.0).astype(np.int64), ((1, 0), (1, 0)))
        self._partial = part.cumsum(0).cumsum(1)

    def sample(self, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        """w at points (degrees; outside the raster: 0)."""
        ny, nx = self.w.shape
        cols = (lon - self.west) / self.step
        rows = (self.north - lat) / self.step
        inside = (cols >= 0) & (cols <= nx - 1) & (rows >= 0) & (rows <= ny - 1)
        return np.where(inside, bilinear(self.w, rows, cols), 0.0)

    def touches_band(self, tw, ts, te, tn) -> np.ndarray:
        """Whether tiles (bounds arrays, degrees) may hold nodes with 0 < w < 1... or w = 0
        next to data: conservatively, any raster cell with w < 1 within one cell of them."""
        ny, nx = self.w.shape
        c0 = np.clip(np.floor((tw - self.west) / self.step).astype(np.int64) - 1, 0, nx)
        c1 = np.clip(np.ceil((te - self.west) / self.step).astype(np.int64) + 2, 0, nx)
        r0 = np.clip(np.floor((self.north - tn) / self.step).astype(np.int64) - 1, 0, ny)
        r1 = np.clip(np.ceil((self.north - ts) / self.step).astype(np.int64) + 2, 0, ny)
        p = self._partial
        n = p[r1, c1] - p[r0, c1] - p[r1, c0] + p[r0, c0]
        # Outside the raster w = 0: such tiles have no data of this layer, harmless either way.
        return n > 0
