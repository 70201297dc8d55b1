"""The apron ring of a composed tile: one node beyond each edge, for the mesh's normals
(`TerrainStack.heights_apron`), and padded composed ancestors (the tile and its ring), which
a layer's border band finer than its data upsamples.

Composing the 8 neighbours for the ring cost twice the tile itself (a view's outer tiles
have neighbours nobody else asks for; issue #17: 0.9 of 2 ms a tile). The ring is composed
instead on its own 4 (size + 1) nodes, node by node as the neighbour composes them: each
layer's ring heights from the store's padded window (`TileStore.heights_padded`: the
neighbours' edge-adjacent nodes) or its finest ancestor's, interpolated; blend weights
sampled at the ring's points. The same values as the neighbours' up to rounding: a bilinear
gather instead of their separable matrix products (float64, then float32), NaN where their
`bilinear` has NaN. One case cannot be had from this tile's side: finer than a layer's data,
where the layer's data edge lies on this tile's edge, the neighbour upsamples a different
ancestor, and the store serves the shared edge nodes from the ancestor outside the extent as
NaN (N44W072's 45 N edge, a DEM ending at +-180). Those ring nodes are copied from the
neighbour's composition (`RingComposer._ring_from_neighbours`).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

from globeview.terrain.compose.heights import _UNREAD
from globeview.terrain.quadtree import tile_bounds_arrays
from globeview.terrain.store.tile_store import TileStore

if TYPE_CHECKING:  # type hints only: the stack imports its parts, never the other way round
    from globeview.terrain.compose.stack import TerrainLayer, TerrainStack

__all__ = ["RingComposer"]


class RingComposer:
    """`TerrainStack.heights_apron` and the padded composed tiles (no cache of its own:
    padded tiles are kept with the composed tiles, `TileComposer`)."""

    def __init__(self, stack: TerrainStack) -> None:
        self._stack = stack

    def heights_apron(self, key: tuple[int, int, int]) -> np.ndarray:
        """The tile's composed heights with one node beyond each edge: (size + 2, size + 2)
        float32 metres, row 0 north, for `build_tile_mesh`'s ``apron`` (normals at edge nodes
        then see the neighbours' triangles, exactly as if the tile had no edge).

        The interior is `heights` (the same array values); the ring holds the 8 same-level
        neighbours' nodes next to the edges, composed on the ring alone (`compose_ring`)
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
        size = self._stack.tile_size
        out = np.empty((size + 2, size + 2), dtype=np.float32)
        out[1:-1, 1:-1] = self._stack._tiles.heights((level, x, y))
        rows, cols = _ring_index(size)
        ring = self.compose_ring((level, x, y), len(self._stack.visible_layers))
        ring[np.isnan(ring)] = 0.0  # no data: the ellipsoid, as `heights` composes it
        out[rows, cols] = ring
        if y == 0:
            out[0] = 2.0 * out[1] - out[2]
        if y == (1 << level) - 1:
            out[-1] = 2.0 * out[-2] - out[-3]
        return out

    def compose_ring(self, key: tuple[int, int, int], upto: int) -> np.ndarray:
        """(4 (size + 1),) float32: the first ``upto`` visible layers composed at the ring
        nodes of a tile (`_ring_index` order; NaN where none has data)."""
        visible = self._stack.visible_layers
        layers = visible[:upto]
        first, own = self._stack._tiles.opaque_layer(layers, key, self.layer_ring, self.ring_blends)
        out = np.full(4 * (self._stack.tile_size + 1), np.nan, dtype=np.float32)
        for i in range(first, len(layers)):
            self._paste_ring(i, layers[i].store, key, out, own.get(i, _UNREAD))
        level, x, y = key
        for dy, dx in self._ring_from_neighbours(key, layers):
            # Where a layer's data edge lies on this tile's edge, finer than the layer's data,
            # the two sides upsample different ancestors that disagree on the shared edge
            # nodes (the one outside the extent serves NaN there, as `heights` always did):
            # the ring takes the neighbour's own composition (rare tiles: data edges only).
            nkey = (level, (x + dx) % (2 << level), y + dy)
            nb = (
                self._stack._tiles.heights(nkey)
                if upto == len(visible)
                else self._stack._tiles.compose(nkey, upto)
            )
            sel, src_r, src_c = _ring_segment(self._stack.tile_size, dy, dx)
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

    def ring_blends(self, st: TileStore, key: tuple[int, int, int]) -> bool:
        """Whether `_paste_ring` blends the layer at a tile's ring (`_blend_ring` not None)."""
        w_, s_, e_, n_ = (float(v) for v in tile_bounds_arrays(*key))
        d_lon = (e_ - w_) / (self._stack.tile_size - 1)
        d_lat = (n_ - s_) / (self._stack.tile_size - 1)
        mask = self._stack.blend_mask(st)
        return mask.touches_band_one(w_ - d_lon, s_ - d_lat, e_ + d_lon, n_ + d_lat)

    def _paste_ring(
        self,
        i: int,
        st: TileStore,
        key: tuple[int, int, int],
        out: np.ndarray,
        own: np.ndarray | object | None = _UNREAD,
    ) -> None:
        """`paste` on the ring nodes of a tile (``out``: the layers below there; ``own``:
        the layer's ring heights when already read)."""
        h = self.layer_ring(st, key) if own is _UNREAD else own
        if h is None:
            return
        assert isinstance(h, np.ndarray)
        has = ~np.isnan(h)
        if i > 0 and self._stack.blend:
            w = self._blend_ring(st, key)
            if w is not None:
                f = key[0] - st.max_level
                if f > 0:
                    # The band finer than the layer's data: the blend at its finest level,
                    # upsampled (as `paste`), from the padded composed ancestor.
                    ax, ay = key[1] >> f, key[2] >> f
                    anc = self.composed_padded((st.max_level, ax, ay), i + 1)
                    h = _upsample_ring(anc, f, key[1] - (ax << f), key[2] - (ay << f))
                    has = ~np.isnan(h)
                else:
                    mixed = np.where(np.isnan(out), h, out + w * (h - out))
                    h = np.where(has, mixed, np.nan).astype(np.float32)
        np.copyto(out, h, where=has)

    def layer_ring(self, st: TileStore, key: tuple[int, int, int]) -> np.ndarray | None:
        """A layer's own heights at a tile's ring nodes (NaN = no data), None where neither
        the tile nor its neighbours have data of the layer."""
        level, x, y = key
        lm = st.max_level
        rows, cols = _ring_index(self._stack.tile_size)
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
        mask = self._stack.blend_mask(st)
        w_, s_, e_, n_ = (float(v) for v in tile_bounds_arrays(*key))
        size = self._stack.tile_size
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

    def composed_padded(self, key: tuple[int, int, int], upto: int) -> np.ndarray:
        """(size + 2)^2 float32: the first ``upto`` layers composed at a tile and its ring
        (NaN where none has data). Cached with the composed tiles: a layer's border band
        finer than its data upsamples one such ancestor for up to 4^f tiles."""
        ckey = (int(key[0]), int(key[1]), int(key[2]), int(upto))
        hit = self._stack._tiles.cached(ckey)
        if hit is not None:
            return hit
        version = self._stack.version
        size = self._stack.tile_size
        out = np.empty((size + 2, size + 2), dtype=np.float32)
        out[1:-1, 1:-1] = self._stack._tiles.compose(key, upto)
        rows, cols = _ring_index(size)
        out[rows, cols] = self.compose_ring(key, upto)
        self._stack._tiles.remember(ckey, out, version)
        return out


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
