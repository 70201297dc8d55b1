"""Shading normals of tiles finer than their data (issue #29, item 6).

Below the finest level a layer holds, a tile's heights are its data-level ancestor's bilinear
surface sampled at the tile's nodes (`TerrainStack.heights`, `upsample_subtile`). That surface
is smooth inside each data cell and creased along the data's node lines (its slope across a
line jumps from one cell's to the next's). Normals averaged from the tile's own triangles
(`tile_mesh._normals_of`) draw each crease as a step of shade one or two of the tile's cells
wide: a lattice of lines at the data's sample spacing over the whole view (7 px apart in the
White Mountains at 9 km, 16 px at 4 km), and a seam wherever tiles of two levels meet, each
drawing the creases over its own cells.

The data hold nothing finer than their spacing, so such a tile is shaded with the normal field
of its data level instead: the ancestor's vertex normals (with its apron, as any tile's),
interpolated to the tile's nodes with Catmull-Rom cubics along each axis (exact for
quadratics). They pass through the ancestor's node normals, so every tile edge agrees: with a
tile at the data level (which the sampler interpolates linearly between the same nodes) at
each shared node, with a neighbour under another ancestor everywhere (both interpolate the
same edge nodes, which the aprons make equal); and they are C1 inside the ancestor: no crease
is left for the eye to find. The texture's own bilinear filtering adds kinks only at the
tile's node spacing, 2^-f of the data's (a few pixels where the LOD draws such tiles).

Precision: the 8-bit normal texture (tile_pool.py) is not what drew the lattice. With half
floats instead, the lattice measure (tests/render/test_render_lattice.py) at 9 km was the
same to 5 %; only a faint ripple at the tile's own node spacing (3.5 px there) halved.

Frames: normals are unit ECEF vectors; grids are row-major with row 0 at the north edge.
"""

from __future__ import annotations

import functools
import threading

import numpy as np

from globeview.render.tile_mesh import apron_normals
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.quadtree import TileKey, tile_bounds

Key = tuple[int, int, int]


def data_level(terrain: TerrainStack, key: Key) -> int:
    """The level whose nodes carry the data under tile ``key`` (level, x, y): the finest level,
    down to the tile's own, that a visible layer holds at or next to the tile (a layer's data
    edge may lie in the tile's ring of neighbour nodes). The tile's own level where no layer
    has data there (the ellipsoid: nothing to interpolate)."""
    level, x, y = key
    best = -1
    for layer in terrain.visible_layers:
        st = layer.store
        la = min(level, st.max_level)
        f = level - la
        if la > best and st.has_data_near(la, x >> f, y >> f):
            best = la
    return level if best < 0 else best


@functools.lru_cache(maxsize=256)
def catmull_rom_taps(size: int, f: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    """The Catmull-Rom cubic of `catmull_rom_weights` as its four taps: ``first`` (size,)
    int64, the apron index of each node's first tap (its taps are first .. first + 3), and
    ``w`` (size, 4) float64 their weights. Read-only (shared by the cache)."""
    cells = size - 1
    pos = (d * cells + np.arange(size, dtype=np.float64)) / 2**f  # ancestor node units
    i = np.minimum(np.floor(pos).astype(np.int64), cells - 1)
    t = pos - i
    t2, t3 = t * t, t * t * t
    w = np.empty((size, 4))
    # Apron index of ancestor node j is j + 1, so nodes i - 1 .. i + 2 are columns i .. i + 3.
    w[:, 0] = 0.5 * (-t3 + 2.0 * t2 - t)
    w[:, 1] = 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0)
    w[:, 2] = 0.5 * (-3.0 * t3 + 4.0 * t2 + t)
    w[:, 3] = 0.5 * (t3 - t2)
    i.flags.writeable = False
    w.flags.writeable = False
    return i, w


@functools.lru_cache(maxsize=256)
def catmull_rom_weights(size: int, f: int, d: int) -> np.ndarray:
    """(size, size + 2) weights taking the node values of an ancestor ``f`` levels up, on its
    apron grid (index 0 is the ring node before its node 0), to the nodes of its descendant at
    tile offset ``d`` (0 .. 2^f - 1) along one axis: the Catmull-Rom cubic through the ancestor
    nodes i - 1 .. i + 2 at the fraction t of cell i. Read-only (shared by the cache).

    At t = 0 the weights are (0, 1, 0, 0): the descendant's nodes on an ancestor node take its
    value exactly (the last one is taken from cell size - 2 at t = 1, which keeps the four
    nodes inside the apron)."""
    first, taps = catmull_rom_taps(size, f, d)
    w = np.zeros((size, size + 2))
    rows = np.arange(size)
    for k in range(4):
        w[rows, first + k] = taps[:, k]
    w.flags.writeable = False
    return w


def upsample_normals(ancestor: np.ndarray, f: int, dx: int, dy: int) -> np.ndarray:
    """(size, size, 3) float32 unit normals of the descendant ``f`` levels below, at tile offset
    (dx, dy) inside it, of an ancestor's apron normals ``ancestor`` ((size + 2, size + 2, 3),
    unit ECEF vectors): Catmull-Rom along each axis (`catmull_rom_weights`), renormalised."""
    return upsample_normals_batch(ancestor[None], np.array([[f, dx, dy]]))[0]


def upsample_normals_batch(ancestors: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """`upsample_normals` of B tiles at once: ``ancestors`` (B, size + 2, size + 2, 3) apron
    normals, ``offsets`` (B, 3) each tile's (f, dx, dy); returns (B, size, size, 3) float32.

    The cubic has four taps a node, so rows then columns are four weighted gathers each
    (float64, taps in order), not products with the (size, size + 2) weight matrices: a
    sixteenth of the arithmetic, no BLAS threads, one pass over the batch. The sums are the
    matrix products' less their zero terms, in another order: equal to them within float32
    rounding (tests/render/test_tile_normals.py)."""
    b = len(ancestors)
    size = ancestors.shape[1] - 2
    taps = [
        (catmull_rom_taps(size, int(f), int(dy)), catmull_rom_taps(size, int(f), int(dx)))
        for f, dx, dy in np.asarray(offsets).reshape(b, 3).tolist()
    ]
    first_r = np.stack([t[0][0] for t in taps])  # (B, size)
    w_r = np.stack([t[0][1] for t in taps])  # (B, size, 4)
    first_c = np.stack([t[1][0] for t in taps])
    w_c = np.stack([t[1][1] for t in taps])
    tile = np.arange(b)[:, None]
    rows = w_r[:, :, 0, None, None] * ancestors[tile, first_r]  # (B, size, size + 2, 3)
    for k in range(1, 4):
        rows += w_r[:, :, k, None, None] * ancestors[tile, first_r + k]
    out = w_c[:, None, :, 0, None] * np.take_along_axis(rows, first_c[:, None, :, None], axis=2)
    for k in range(1, 4):
        picked = np.take_along_axis(rows, (first_c + k)[:, None, :, None], axis=2)
        out += w_c[:, None, :, k, None] * picked
    ox, oy, oz = out[..., 0], out[..., 1], out[..., 2]
    norm = np.sqrt(ox * ox + oy * oy + oz * oz)
    out /= np.maximum(norm, 1e-30)[..., None]
    return out.astype(np.float32)


class DataLevelNormals:
    """Normals of tiles finer than their data, from their data-level ancestors (module
    docstring), with the ancestors' apron normals cached: the 4^f descendants of one ancestor
    that a view draws side by side compute them once. Thread-safe (the tile loader builds on
    a worker thread); the cache is emptied when the terrain's version changes.

    Args:
        terrain: the composed layers the tiles are built from.
        capacity: ancestors kept (each (size + 2)^2 x 3 float64, ~110 kB at size 65).
    """

    def __init__(self, terrain: TerrainStack, capacity: int = 64) -> None:
        self.terrain = terrain
        self.capacity = capacity
        self._cache: dict[Key, np.ndarray] = {}
        self._version = terrain.version
        self._lock = threading.Lock()

    def normals(self, key: Key) -> np.ndarray | None:
        """(size, size, 3) float32 unit ECEF normals of tile ``key`` interpolated from its data
        level, or None where the tile is at or above its data level (its own heights carry the
        data: `build_tile_mesh` computes its normals from them)."""
        return self.normals_many([key])[0]

    def normals_many(self, keys: list[Key]) -> list[np.ndarray | None]:
        """`normals` of each of ``keys``, the interpolations in one pass over the batch
        (`upsample_normals_batch`)."""
        out: list[np.ndarray | None] = [None] * len(keys)
        rows, ancestors, offsets = [], [], []
        for i, (level, x, y) in enumerate(keys):
            d = data_level(self.terrain, (level, x, y))
            if d >= level:
                continue
            f = level - d
            rows.append(i)
            ancestors.append(self._ancestor((d, x >> f, y >> f)))
            offsets.append((f, x - ((x >> f) << f), y - ((y >> f) << f)))
        if rows:
            up = upsample_normals_batch(np.stack(ancestors), np.array(offsets))
            for j, i in enumerate(rows):
                out[i] = up[j]
        return out

    def _ancestor(self, key: Key) -> np.ndarray:
        version = self.terrain.version
        with self._lock:
            if version != self._version:
                self._cache, self._version = {}, version
            hit = self._cache.get(key)
        if hit is not None:
            return hit
        # Computed outside the lock: two threads may both compute one ancestor (the same
        # numbers), which is cheaper than making every build wait for another's.
        bounds = tile_bounds(TileKey(*key))
        normals = apron_normals(bounds, self.terrain.heights_apron(key)).astype(np.float64)
        with self._lock:
            if self._version == version:
                if len(self._cache) >= self.capacity:
                    self._cache.pop(next(iter(self._cache)))  # the oldest entry
                self._cache[key] = normals
        return normals
