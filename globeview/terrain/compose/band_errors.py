"""What the border blend adds to the stride errors of the tiles in a layer's border band.

A layer over others is composed as B = (1 - w) L + w U (`blend`); drawn at a stride, the
composed surface departs from the reference by at most the layers' own errors plus a term of
the weight's change over a drawn cell times |U - L| (`BandErrors.blend_error` derives it).
|U - L| and its spread over drawn cells are measured exactly on the band's tiles at levels
where the band holds at most `DIFF_TABLE_TILES` tiles (`_difference_table`, once per level
and stack of layers below), bounded from the ancestor there finer than that.
"""

from __future__ import annotations

import functools
import threading
import time
from typing import TYPE_CHECKING

import numpy as np

from globeview.errors import StoreError
from globeview.terrain.compose.band_tables import (
    load_tables,
    save_tables,
    store_digest,
    tables_key,
)
from globeview.terrain.compose.blend import interpolation_error, weight_change_bound
from globeview.terrain.compose.metadata import N_STRIDES
from globeview.terrain.interpolate import linear_weights
from globeview.terrain.quadtree import node_spacing, tile_bounds_arrays
from globeview.terrain.store.tile_store import TileStore

if TYPE_CHECKING:  # type hints only: the stack imports its parts, never the other way round
    from globeview.terrain.compose.stack import TerrainStack

__all__ = ["DIFF_RETRY_S", "DIFF_TABLE_TILES", "BandErrors"]

#: Most tiles of a layer's border band whose |upper - lower| is measured exactly at one level
#: (one-time work, ~1 ms a tile); finer levels bound it from the finest level within this.
DIFF_TABLE_TILES = 1024
#: Seconds before the band tiles a `_difference_table` could not read (a remote store's tile
#: that failed, or one not fetched yet on a thread that may not wait for the network: the
#: window's UI thread) are tried again; until then they are bounded by their height ranges.
DIFF_RETRY_S = 2.0


class BandErrors:
    """The border blend's part of the stack's stride errors (`blend_error`), with its
    per-level difference tables."""

    def __init__(self, stack: TerrainStack) -> None:
        self._stack = stack
        self._lock = threading.Lock()
        self._diffs: dict[tuple, tuple] = {}
        # _diffs entries with unread band tiles: key -> (time.monotonic() to retry, tiles).
        self._diffs_unread: dict[tuple, tuple[float, list[tuple[int, int]]]] = {}
        self._band_counts: dict[tuple[TileStore, int], int] = {}  # band tiles per level
        # sha256 of each store's manifest (`band_tables.store_digest`), None for remote ones.
        self._digests: dict[TileStore, str | None] = {}

    def clear(self) -> None:
        """The layers changed: |upper - lower| bounds depend on which layers lie below."""
        with self._lock:
            self._diffs.clear()
            self._diffs_unread.clear()
            self._band_counts.clear()
            self._digests.clear()  # holds the stores: forget removed ones

    def blend_error(
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
        mask = self._stack.blend_mask(st)
        inband = blended & mask.touches_band(*tile_bounds_arrays(level, x, y))
        if not inband.any():
            return np.zeros((n, N_STRIDES))
        lm = st.max_level
        f = max(0, level - lm)
        if f == 0:
            total = self._blend_total(i, st, level, x, y, e_upper, e_lower)
        else:
            # Finer than the layer's data the band is the blend at its finest level, upsampled
            # (`compose`): stride s here is stride s / 2^f there, and up to stride 2^f the
            # drawn surface is that level's stride-1 surface exactly.
            ax, ay = x >> f, y >> f
            e_up = np.nan_to_num(st.tile_stride_error(lm, ax, ay).astype(np.float64))
            e_low = self._stack._meta.of_layers(lm, ax, ay, i).stride_error
            at_lm = self._blend_total(i, st, lm, ax, ay, e_up, e_low)
            total = np.repeat(at_lm[:, :1], N_STRIDES, axis=1)
            if f < N_STRIDES:
                total[:, f:] = at_lm[:, : N_STRIDES - f]
            # Measured on the tile where it can be: the composed surface here is the
            # composed ancestor's bilinear surface sampled (`paste`), whose error is at most
            # at_lm's stride 1, so `drawn_error`'s bound holds with that as the base.
            measured = self._stack._meta.measured_virtual(
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
        level, as `paste` upsamples it inside the layer's border band below that level."""
        return self._stack._ring.composed_padded(key, i + 1)[1:-1, 1:-1]

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
        mask = self._stack.blend_mask(st)
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
        e_low = self._stack._meta.of_layers(c, xa, ya, i).stride_error[:, 0]
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
        tiles of layer ``i`` (one-time work per level is bounded). The count is of the tiles
        `_difference_table` measures, those with data: since store format 7 a level grid spans
        whole chunks, and counting its empty tiles too made the Whites' level 12 band 1924
        tiles (196 with data), so the band was bounded from level 11 (2x the triangles)."""
        for c in range(level, -1, -1):
            key = (st, c)
            with self._lock:
                n = self._band_counts.get(key)
            if n is None:
                n = int(self._band_tiles(st, c).sum())
                with self._lock:
                    self._band_counts[key] = n
            if n <= DIFF_TABLE_TILES:
                return c
        return 0

    def _band_tiles(self, st: TileStore, level: int) -> np.ndarray:
        """(ny, nx) bool over ``st``'s level grid: the tiles with data that touch its border
        band (those `_difference_table` measures)."""
        grid = st.level_grid(level)
        ys, xs = np.mgrid[grid.y0 : grid.y0 + grid.ny, grid.x0 : grid.x0 + grid.nx]
        xs = xs % grid.ncols
        todo = st.has_data(level, xs, ys)
        todo &= self._stack.blend_mask(st).touches_band(*tile_bounds_arrays(level, xs, ys))
        return np.asarray(todo, dtype=bool)

    def _difference_table(self, i: int, st: TileStore, level: int) -> tuple:
        """(grid, (ny, nx) table): max over each tile's nodes of |U - L| (layer ``i`` minus the
        composed layers below it) at ``level``, for the tiles in the layer's border band (0
        elsewhere: the blend term is zero there). Built once per level and stack of layers
        below (a bounded number of tiles, see `_exact_level`), never per frame."""
        below = tuple(ly.store for ly in self._stack.visible_layers[:i])
        key = (st, below, level)
        with self._lock:
            hit = self._diffs.get(key)
            unread = self._diffs_unread.get(key)
        if hit is not None and (unread is None or time.monotonic() < unread[0]):
            return hit
        version = self._stack.version
        grid = st.level_grid(level)
        ys, xs = np.mgrid[grid.y0 : grid.y0 + grid.ny, grid.x0 : grid.x0 + grid.nx]
        xs = xs % grid.ncols
        disk_key = self._disk_key(st, below, level) if hit is None else None
        if disk_key is not None:
            kept = load_tables(disk_key, xs.shape)
            if kept is not None:  # measured in an earlier session: the same numbers
                return self._keep(key, version, (grid, *kept), [])
        if hit is None:
            todo = self._band_tiles(st, level)
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
                lower = self._stack._tiles.compose(tile, i)
                composed = lower.copy()
                upper = self._stack._tiles.paste(i, st, tile, composed)
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
        elif disk_key is not None:
            save_tables(disk_key, (table, spread, measured))
        return self._keep(key, version, (grid, table, spread, measured), missed)

    def _keep(self, key: tuple, version: int, hit: tuple, missed: list[tuple[int, int]]) -> tuple:
        """Remember a difference table (unless the layers changed since ``version``), with
        the band tiles it could not read for a retry; returns it."""
        with self._lock:
            if self._stack.version == version:  # the layers changed meanwhile: do not keep it
                self._diffs[key] = hit
                if missed:
                    self._diffs_unread[key] = (time.monotonic() + DIFF_RETRY_S, missed)
                else:
                    self._diffs_unread.pop(key, None)
        return hit

    def _disk_key(self, st: TileStore, below: tuple[TileStore, ...], level: int) -> str | None:
        """The key of this table in the user's cache (`band_tables`), None where a store is
        remote or its manifest unreadable (then the table is measured every session)."""
        digests = []
        for store in (st, *below):
            with self._lock:
                digest = self._digests.get(store, "")
            if digest == "":
                digest = store_digest(store)
                with self._lock:
                    self._digests[store] = digest
            if digest is None:
                return None
            digests.append(digest)
        try:
            return tables_key(digests[0], digests[1:], level, self._stack.blend)
        except OSError:  # the package's source unreadable (`code_digest`): measure instead
            return None

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
        ``i``'s and the composed lower layers' height ranges (`of_layers`), a drawn cell's
        spread of U - L <= twice that, and E(s) not measured (inf: `_blend_total` keeps its
        algebraic bound). Looser than the measured values, never smaller."""
        jj = np.array([t[0] for t in tiles])
        cc = np.array([t[1] for t in tiles])
        x, y = xs[jj, cc], ys[jj, cc]
        u_lo, u_hi = (np.nan_to_num(v.astype(np.float64)) for v in st.tile_hrange(level, x, y))
        below = self._stack._meta.of_layers(level, x, y, i)
        d = np.maximum(u_hi - below.hmin, below.hmax - u_lo)
        d = np.maximum(d, 0.0)
        table[jj, cc] = d
        spread[jj, cc] = 2.0 * d[:, None]
        measured[jj, cc] = np.inf


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
