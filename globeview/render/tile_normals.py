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
def catmull_rom_weights(size: int, f: int, d: int) -> np.ndarray:
    """(size, size + 2) weights taking the node values of an ancestor ``f`` levels up, on its
    apron grid (index 0 is the ring node before its node 0), to the nodes of its descendant at
    tile offset ``d`` (0 .. 2^f - 1) along one axis: the Catmull-Rom cubic through the ancestor
    nodes i - 1 .. i + 2 at the fraction t of cell i. Read-only (shared by the cache).

    At t = 0 the weights are (0, 1, 0, 0): the descendant's nodes on an ancestor node take its
    value exactly (the last one is taken from cell size - 2 at t = 1, which keeps the four
    nodes inside the apron)."""
    cells = size - 1
    pos = (d * cells + np.arange(size, dtype=np.float64)) / 2**f  # ancestor node units
    i = np.minimum(np.floor(pos).astype(np.int64), cells - 1)
    t = pos - i
    t2, t3 = t * t, t * t * t
    w = np.zeros((size, size + 2))
    rows = np.arange(size)
    # Apron index of ancestor node j is j + 1, so nodes i - 1 .. i + 2 are columns i .. i + 3.
    w[rows, i] = 0.5 * (-t3 + 2.0 * t2 - t)
    w[rows, i + 1] = 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0)
    w[rows, i + 2] = 0.5 * (-3.0 * t3 + 4.0 * t2 + t)
    w[rows, i + 3] = 0.5 * (t3 - t2)
    w.flags.writeable = False
    return w


@functools.lru_cache(maxsize=256)
def catmull_rom_window(size: int, f: int, d: int) -> tuple[slice, np.ndarray]:
    """`catmull_rom_weights` without its zero columns: (the apron rows a descendant's nodes
    read, as a slice; the (size, window) weights on them, contiguous, read-only). A
    descendant f levels down reads ~size / 2^f + 4 of the size + 2 ancestor nodes."""
    w = catmull_rom_weights(size, f, d)
    used = np.nonzero(np.any(w != 0.0, axis=0))[0]
    lo, hi = int(used[0]), int(used[-1]) + 1
    sub = np.ascontiguousarray(w[:, lo:hi])
    sub.flags.writeable = False
    return slice(lo, hi), sub


def upsample_normals(ancestor: np.ndarray, f: int, dx: int, dy: int) -> np.ndarray:
    """(size, size, 3) float32 unit normals of the descendant ``f`` levels below, at tile offset
    (dx, dy) inside it, of an ancestor's apron normals ``ancestor`` ((size + 2, size + 2, 3),
    unit ECEF vectors): Catmull-Rom along each axis (`catmull_rom_weights`), renormalised.

    Only the ancestor nodes the descendant reads enter the products (`catmull_rom_window`:
    2.4x fewer operations a level down, 5x two levels down); the terms left out are zeros,
    so the result is the full products' within float32 rounding
    (tests/render/test_tile_normals.py)."""
    size = ancestor.shape[0] - 2
    rows, wr = catmull_rom_window(size, f, dy)
    cols, wc = catmull_rom_window(size, f, dx)
    # Separable: per component, rows then columns (two small matrix products).
    out = np.moveaxis(wr @ np.moveaxis(ancestor[rows, cols], -1, 0) @ wc.T, 0, -1)
    out /= np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-30)
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
        """`normals` of each of ``keys`` (a builder's batch)."""
        out: list[np.ndarray | None] = [None] * len(keys)
        for i, (level, x, y) in enumerate(keys):
            d = data_level(self.terrain, (level, x, y))
            if d >= level:
                continue
            f = level - d
            anc = self._ancestor((d, x >> f, y >> f))
            out[i] = upsample_normals(anc, f, x - ((x >> f) << f), y - ((y >> f) << f))
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
