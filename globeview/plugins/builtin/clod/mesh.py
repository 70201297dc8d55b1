"""Per-tile quadtree CLOD mesh (Wang thesis §4.3-4.4, after Lindstrom et al. and Ulrich),
vectorised level by level over all blocks of all tiles at once.

Block hierarchy of a tile of ``size = 2^L + 1`` nodes (``n = size - 1`` cells per side):
block level j (0 = the whole tile) has 2^j x 2^j blocks of 2h x 2h cells, ``h = n / 2^(j+1)``
(the half size). Each block has 9 nodes: a centre, four edge midpoints and four corners
(thesis fig. 4.2). Every grid node except the four tile corners is exactly one block's centre
or one level's edge midpoint, so one (size, size) array holds every vertex's error.

Frames and units: all geometry is in the tile's ENU frame (origin = the tile's centre on the
ellipsoid at height 0, axes east/north/up), metres; heights carry the vertical exaggeration.

Per frame (`clod_frame`):

1. *Update* (top-down): a block is refined (its centre enabled) when its parent is and the
   box test (thesis eq. 4.2) ``E_max / (d - s) >= tau'`` holds, d = distance from the eye to
   the block's centre node, s = radius of the block's bounding sphere, and the sphere is not
   outside the frustum (thesis §5.2, planes in the tile's ENU frame). The edge midpoints of
   refined blocks are enabled by the vertex test (eq. 4.1) ``E_v / d_v >= tau'``.
2. *Dependencies* (bottom-up, one pass): an enabled edge midpoint enables the block(s) on both
   sides of its edge; an enabled block enables its parent and its four corners (the thesis'
   variant: a centre depends on all four corners). The result is the restricted quadtree:
   every enabled vertex's dependencies are enabled, so the fans below have no T-junction.
3. *Across tiles*: a tile-edge vertex is shared with the same-level tile beside it. After each
   dependency pass the two tiles' edge masks are OR-ed and the pass repeats until nothing
   changes (a monotone fixpoint), so a shared edge vertex ends up enabled identically on both
   sides: the union of what each side's data asks for. Tiles of different levels meet behind
   the skirts.
4. *Render*: each refined block emits a triangle fan around its centre over its enabled
   border vertices, skipping the quadrants that are refined themselves and the disabled edge
   midpoints (thesis fig. 4.4), as a triangle list; skirts follow the enabled edge vertices.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from globeview.plugins.api import (
    WGS84,
    enu_basis,
    lonlat_to_ecef,
    node_lonlat,
    tile_bounds_arrays,
)


# -- per-tile precomputation (first use of a tile, cached by the provider) ------------------
@dataclass
class TileClod:
    """A tile's CLOD data, fixed for one (tile, exaggeration).

    origin: (3,) ECEF of the ENU origin (m); basis: (3, 3) rows E, N, U in ECEF.
    pos: (size, size, 3) float64 node positions in the ENU frame (m, heights x exaggeration;
        displaced when built with a displacement: where they are drawn).
    err: (size, size) vertex error E_v (m): 3-D distance between the node and the midpoint of
        the two nodes it interpolates at its level (the diagonal for block centres: the larger
        of the two diagonals); 0 at the tile corners.
    emax: per block level j, (2^j, 2^j) max vertex error in the block and all its sub-blocks.
    radius: per block level j, (2^j, 2^j) radius (m) of a sphere around the block's centre
        node holding all of its nodes.
    """

    origin: np.ndarray
    basis: np.ndarray
    pos: np.ndarray
    err: np.ndarray
    emax: list[np.ndarray]
    radius: list[np.ndarray]


def n_block_levels(size: int) -> int:
    """L for a tile of size = 2^L + 1 nodes: block levels 0..L-1."""
    n = size - 1
    levels = n.bit_length() - 1
    if n < 2 or (1 << levels) != n:
        raise ValueError(f"tile size {size} is not 2^L + 1")
    return levels


def _norm(v: np.ndarray) -> np.ndarray:
    """np.linalg.norm(v, axis=-1) of 3-vectors: the same operations in the same order
    (x² + y², then + z²), so the same floats, ~4x faster (numpy's reduce over a 3-long axis
    pays a loop per vector)."""
    w = v * v
    return np.sqrt(w[..., 0] + w[..., 1] + w[..., 2])


def tile_clod(
    key: tuple[int, int, int],
    heights: np.ndarray,
    exaggeration: float,
    displace: Callable[[np.ndarray], np.ndarray] | None = None,
) -> TileClod:
    """Precompute a tile's vertex errors, block error maxima and block radii (vectorised):
    `tile_clods` of one tile."""
    return tile_clods([key], [heights], exaggeration, displace)[0]


def tile_clods(
    keys: list[tuple[int, int, int]],
    heights: list[np.ndarray],
    exaggeration: float,
    displace: Callable[[np.ndarray], np.ndarray] | None = None,
) -> list[TileClod]:
    """`TileClod` of several tiles (their ``heights``, (size, size) each): the node positions
    per tile, the errors, maxima and radii of all of them in one pass of array operations
    (the same per-element operations as for one tile, so the same floats).

    ``displace`` (a ViewState's CPU displacement, (M, 3) -> (M, 3) ECEF) moves the nodes where
    the vertex shader draws them before anything is measured: the vertex errors then include
    how far the displacement bends the surface away from straight edges (the collapse's fold
    lines), and radii and distances are those of the drawn geometry, so blocks a fold crosses
    refine like rough terrain (no gap opens along the fold)."""
    frames = [
        _tile_positions(k, h, exaggeration, displace) for k, h in zip(keys, heights, strict=True)
    ]
    pos = np.stack([p for _, _, p in frames])  # (B, size, size, 3)
    b_n, size = pos.shape[0], pos.shape[1]
    n = size - 1

    err = np.zeros((b_n, size, size))
    n_levels = n_block_levels(size)
    for j in range(n_levels):
        hh = n >> (j + 1)
        s2 = 2 * hh
        # Horizontal edge midpoints (rows 0, 2h, ..; cols h, 3h, ..) between (r, c -+ h).
        c = pos[:, ::s2, hh::s2]
        err[:, ::s2, hh::s2] = _norm(
            c - 0.5 * (pos[:, ::s2, 0 : n - hh + 1 : s2] + pos[:, ::s2, s2::s2])
        )
        # Vertical edge midpoints between (r -+ h, c).
        c = pos[:, hh::s2, ::s2]
        err[:, hh::s2, ::s2] = _norm(
            c - 0.5 * (pos[:, 0 : n - hh + 1 : s2, ::s2] + pos[:, s2::s2, ::s2])
        )
        # Block centres: against both diagonals (the one through the parent's centre is the
        # one the parent's fan uses; the max of the two is conservative and symmetric).
        c = pos[:, hh::s2, hh::s2]
        nw = pos[:, 0 : n - hh + 1 : s2, 0 : n - hh + 1 : s2]
        se = pos[:, s2::s2, s2::s2]
        ne = pos[:, 0 : n - hh + 1 : s2, s2::s2]
        sw = pos[:, s2::s2, 0 : n - hh + 1 : s2]
        err[:, hh::s2, hh::s2] = np.maximum(_norm(c - 0.5 * (nw + se)), _norm(c - 0.5 * (ne + sw)))

    emax: list[np.ndarray] = [np.empty(0)] * n_levels
    radius: list[np.ndarray] = [np.empty(0)] * n_levels
    for j in range(n_levels - 1, -1, -1):
        hh = n >> (j + 1)
        s2 = 2 * hh
        nb = 1 << j
        own = np.maximum.reduce(
            [
                err[:, hh::s2, hh::s2],  # centre
                err[:, 0:n:s2, hh::s2],  # north midpoint
                err[:, s2::s2, hh::s2],  # south midpoint
                err[:, hh::s2, 0:n:s2],  # west midpoint
                err[:, hh::s2, s2::s2],  # east midpoint
            ]
        )
        centre = pos[:, hh::s2, hh::s2]
        corners = [
            pos[:, 0:n:s2, 0:n:s2],
            pos[:, 0:n:s2, s2::s2],
            pos[:, s2::s2, 0:n:s2],
            pos[:, s2::s2, s2::s2],
        ]
        r = np.maximum.reduce([_norm(q - centre) for q in corners])
        if j == n_levels - 1:
            # 3 x 3 nodes: the midpoints too.
            mids = [
                pos[:, 0:n:s2, hh::s2],
                pos[:, s2::s2, hh::s2],
                pos[:, hh::s2, 0:n:s2],
                pos[:, hh::s2, s2::s2],
            ]
            r = np.maximum(r, np.maximum.reduce([_norm(q - centre) for q in mids]))
        else:
            ch = emax[j + 1].reshape(b_n, nb, 2, nb, 2)
            own = np.maximum(own, ch.max(axis=(2, 4)))
            # Children's spheres, moved to this centre (triangle inequality).
            cc = pos[:, hh // 2 :: hh, hh // 2 :: hh].reshape(b_n, nb, 2, nb, 2, 3)
            off = _norm(cc - centre[:, :, None, :, None, :])
            r = np.maximum(r, (radius[j + 1].reshape(b_n, nb, 2, nb, 2) + off).max(axis=(2, 4)))
        emax[j] = own
        radius[j] = r
    return [
        TileClod(o, bs, pos[i], err[i], [e[i] for e in emax], [q[i] for q in radius])
        for i, (o, bs, _) in enumerate(frames)
    ]


def _grid_ecef(lon_deg: np.ndarray, lat_deg: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(rows, cols, 3) ECEF (m) of a grid's nodes: ``lonlat_to_ecef`` of
    ``np.meshgrid(lon_deg, lat_deg)`` and heights ``h`` (rows, cols), with the same operations
    per node (so the same floats), but the trigonometry once per row (latitude) and column
    (longitude) instead of per node."""
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    sin_lat, cos_lat = np.sin(lat)[:, None], np.cos(lat)[:, None]
    n = WGS84.a / np.sqrt(1.0 - WGS84.e2 * sin_lat * sin_lat)  # prime-vertical radius
    rho = (n + h) * cos_lat
    out = np.empty((*h.shape, 3))
    out[..., 0] = rho * np.cos(lon)[None, :]
    out[..., 1] = rho * np.sin(lon)[None, :]
    out[..., 2] = (n * (1.0 - WGS84.e2) + h) * sin_lat
    return out


def _tile_positions(
    key: tuple[int, int, int],
    heights: np.ndarray,
    exaggeration: float,
    displace: Callable[[np.ndarray], np.ndarray] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tile's ENU frame (origin (3,) ECEF, basis (3, 3) rows E, N, U) and its nodes in it
    (size, size, 3), metres, heights x exaggeration, displaced where ``displace`` is given."""
    level, x, y = key
    size = heights.shape[0]
    w, s, e, nn = (float(v) for v in tile_bounds_arrays(level, x, y))
    lon, lat = node_lonlat((w, s, e, nn), size)
    mid_lon, mid_lat = 0.5 * (w + e), 0.5 * (s + nn)
    origin = np.asarray(lonlat_to_ecef(mid_lon, mid_lat, 0.0), dtype=np.float64).reshape(3)
    basis = enu_basis(mid_lon, mid_lat)
    h = heights.astype(np.float64) * exaggeration
    ecef = _grid_ecef(lon, lat, h)
    if displace is not None:
        ecef = np.asarray(displace(ecef.reshape(-1, 3)), dtype=np.float64).reshape(ecef.shape)
    return origin, basis, (ecef - origin) @ basis.T


# -- per-frame selection ----------------------------------------------------------------------
@dataclass
class ClodFrame:
    """The enabled state of a batch of T tiles for one view.

    on: per block level j, (T, 2^j, 2^j) bool: block refined (its centre enabled).
    enabled: (T, size, size) bool: enabled vertices.
    error_px: (T,) the largest error (pixels) the meshes leave: disabled midpoints of refined
        blocks (E_v K / d) and unrefined sub-blocks (E_max K / (d - s)).
    exchange_passes: dependency passes run until shared tile edges agreed.
    blocks: per block level j, the sorted flat codes ``(t * 2^j + bi) * 2^j + bj`` of the
        refined blocks (``np.flatnonzero(on[j])``, kept so nothing rescans ``on``).
    """

    on: list[np.ndarray]
    enabled: np.ndarray
    error_px: np.ndarray
    exchange_passes: int
    blocks: list[np.ndarray] | None = None

    def refined(self, j: int) -> np.ndarray:
        """Flat codes of the refined blocks of level j (see ``blocks``)."""
        return self.blocks[j] if self.blocks is not None else np.flatnonzero(self.on[j])


class ClodArrays(Protocol):
    """Packed per-tile CLOD data indexed by slot (`tile_data.ClodTiles`): ``pos`` (S, size,
    size, 3), ``err`` (S, size, size), ``emax[j]`` and ``radius[j]`` (S, 2^j, 2^j), as in
    `TileClod`; all C-contiguous."""

    pos: np.ndarray
    err: np.ndarray
    emax: list[np.ndarray]
    radius: list[np.ndarray]


def clod_frame(
    keys: np.ndarray,
    data: ClodArrays,
    slots: np.ndarray,
    eye_local: np.ndarray,
    planes_local: np.ndarray,
    tau_ratio: float,
    k_px: float,
    cull: bool = True,
) -> ClodFrame:
    """Enable vertices of T tiles for one view.

    Only the refined blocks and enabled vertices are visited (a few thousand in a frame of
    hundreds of tiles, of their 4 225 nodes each), by flat indices: the tiles' data is read
    where it is packed (``data`` at ``slots``, nothing stacked per frame), and the dependency
    closure follows what changed (`_close`).

    Args:
        keys: (T, 3) int (level, x, y) of the tiles (used to find same-level neighbours).
        data: the packed CLOD data of the tiles (`ClodArrays`); ``slots`` (T,) their slots.
        eye_local: (T, 3) the eye in each tile's ENU frame (m).
        planes_local: (T, 6, 4) frustum planes in each tile's ENU frame (n . p + d >= 0 in).
        tau_ratio: the thesis' threshold tau' (error / distance), = tau_px / k_px.
        k_px: view.sse_factor (pixels per metre of error at 1 m), for error_px.
        cull: prune blocks outside the frustum (thesis §5.2).
    """
    slots = np.asarray(slots, dtype=np.int64)
    t_n = len(slots)
    size = data.pos.shape[1] if t_n else 3
    n, s2n = size - 1, size * size
    n_levels = n_block_levels(size)
    error_px = np.zeros(t_n)
    enabled = np.zeros((t_n, size, size), dtype=bool)
    on = [np.zeros((t_n, 1 << j, 1 << j), dtype=bool) for j in range(n_levels)]
    if t_n == 0:
        return ClodFrame(on, enabled, error_px, 0, [np.empty(0, np.int64)] * n_levels)
    pos_f, err_f = data.pos.reshape(-1, 3), data.err.reshape(-1)
    en_f = enabled.reshape(-1)
    slot_base = slots * s2n  # flat index of each tile's node (0, 0) in the packed data
    tile_base = np.arange(t_n) * s2n  # ... and in ``enabled``

    # 1. Update, top-down over the refined blocks only (the thesis' recursion, one level of
    # all tiles at a time). The errors left on screen are gathered as (tile, px) pairs and
    # reduced once at the end.
    on[0][:] = True
    blocks = [np.arange(t_n)]  # level 0: one block per tile
    err_t: list[np.ndarray] = []
    err_v: list[np.ndarray] = []
    mids: list[np.ndarray] = []
    for j in range(n_levels):
        hh = n >> (j + 1)
        nb = 1 << j
        # (Divisions by powers of two as shifts and masks: numpy's integer // and % are slow.)
        t, bi, bj = blocks[j] >> (2 * j), (blocks[j] >> j) & (nb - 1), blocks[j] & (nb - 1)
        local = ((2 * bi + 1) * hh) * size + (2 * bj + 1) * hh  # block centres
        # Vertex test on the four edge midpoints (north, south, west, east) of every
        # refined block, all at once.
        t4 = np.concatenate([t, t, t, t])
        l4 = np.concatenate([local - hh * size, local + hh * size, local - hh, local + hh])
        at = slot_base.take(t4) + l4
        d = _norm(pos_f.take(at, axis=0) - eye_local.take(t4, axis=0))
        e = err_f.take(at)
        ok = e >= tau_ratio * d
        mids.append(tile_base.take(t4[ok]) + l4[ok])
        off = ~ok
        err_t.append(t4[off])
        err_v.append(e[off] * k_px / np.maximum(d[off], 1.0))
        if j == n_levels - 1:
            break
        # Box test on the four children.
        nc = 2 * nb
        ct = np.repeat(t, 4)
        ci = (2 * bi[:, None] + np.array([0, 0, 1, 1])).reshape(-1)
        cj = (2 * bj[:, None] + np.array([0, 1, 0, 1])).reshape(-1)
        cs = slots.take(ct)
        ch = hh // 2
        centre = pos_f.take(cs * s2n + ((2 * ci + 1) * ch) * size + (2 * cj + 1) * ch, axis=0)
        bcode = (cs * nc + ci) * nc + cj  # the child in the packed per-block arrays
        s = data.radius[j + 1].reshape(-1).take(bcode)
        em = data.emax[j + 1].reshape(-1).take(bcode)
        room = _norm(centre - eye_local.take(ct, axis=0)) - s
        refine = (em > 0.0) & (em >= tau_ratio * np.maximum(room, 0.0))
        visible = np.ones(len(ct), dtype=bool)
        if cull:
            # The planes' signed distances, sum over k in order as einsum("mpk,mk->mp")
            # adds them (the same floats), without einsum's setup per call.
            pl = planes_local.take(ct, axis=0)
            c3 = centre[:, None, :]
            dist = pl[:, :, 0] * c3[..., 0] + pl[:, :, 1] * c3[..., 1]
            dist = dist + pl[:, :, 2] * c3[..., 2] + pl[:, :, 3]
            visible = (dist >= -s[:, None]).all(axis=1)
            refine &= visible
        blocks.append(np.sort(((ct * nc + ci) * nc + cj)[refine]))
        on[j + 1].reshape(-1)[blocks[j + 1]] = True
        left = ~refine & visible  # what is left coarse on screen
        err_t.append(ct[left])
        err_v.append(em[left] * k_px / np.maximum(room[left], 1.0))
    np.maximum.at(error_px, np.concatenate(err_t), np.concatenate(err_v))
    nodes = np.concatenate(mids)
    en_f[nodes] = True
    blocks += [np.empty(0, np.int64)] * (n_levels - len(blocks))

    # 2./3. Dependencies, then agreement on shared tile edges, until a fixpoint. The first
    # closure starts from everything the update enabled (its blocks and midpoints); each
    # later one only from the edge vertices the exchange added (the rest is closed already).
    enabled[:, 0::n, 0::n] = True  # tile corners
    lev = _node_levels(size).reshape(-1)
    pairs_ew, pairs_ns = _same_level_neighbours(keys)
    added: list[list[np.ndarray]] = [[] for _ in range(n_levels)]
    todo = blocks
    passes = 0
    while True:
        passes += 1
        _close(on, en_f, lev, size, nodes, todo, added)
        new = []
        for a, b, ea, eb, step in (
            # the east column of a, the west column of b; one edge node to the next: a row
            (pairs_ew[0], pairs_ew[1], n, 0, size),
            # the south row of a, the north row of b; one edge node to the next: a column
            (pairs_ns[0], pairs_ns[1], n * size, 0, 1),
        ):
            if len(a) == 0:
                continue
            if step == size:  # (P, size) each: the shared edge as each side has it
                va, vb = enabled[a, :, n], enabled[b, :, 0]
            else:
                va, vb = enabled[a, n, :], enabled[b, 0, :]
            differ = np.flatnonzero(va != vb)  # where one side has a vertex the other lacks
            if len(differ) == 0:
                continue
            p, k = np.divmod(differ, size)
            a_has = va.reshape(-1).take(differ)
            tiles = np.where(a_has, b.take(p), a.take(p))  # the side that lacks it
            new.append(tile_base.take(tiles) + np.where(a_has, eb, ea) + k * step)
        if not new:
            break
        nodes = np.concatenate(new)
        en_f[nodes] = True  # (at the pass cap too, as the union it is)
        if passes > 4 * n_levels + 4:
            break
        todo = [np.empty(0, np.int64)] * n_levels
    for j in range(n_levels):
        if added[j]:
            blocks[j] = np.sort(np.concatenate([blocks[j], *added[j]]))
    return ClodFrame(on, enabled, error_px, passes, blocks)


@functools.lru_cache(maxsize=8)
def _node_levels(size: int) -> np.ndarray:
    """(size, size) int: the block level j whose centre or edge midpoint each node is
    (for node (r, c), hh = n >> (j + 1) is the largest power of two dividing both r and c);
    -1 at the tile corners."""
    n = size - 1
    n_levels = n_block_levels(size)
    k = np.arange(size)
    tz = np.full(size, n_levels, dtype=np.int64)  # trailing zeros; n_levels for 0 and n
    for b in range(n_levels - 1, -1, -1):
        tz[(k % (1 << b) == 0) & (tz == n_levels)] = b
    tz[0] = tz[n] = n_levels
    m = np.minimum(tz[:, None], tz[None, :])
    out = np.where(m >= n_levels, -1, n_levels - 1 - m)
    out.setflags(write=False)  # cached: shared by every frame
    return out


def _close(
    on: list[np.ndarray],
    en_f: np.ndarray,
    lev: np.ndarray,
    size: int,
    nodes: np.ndarray,
    blocks: list[np.ndarray],
    added: list[list[np.ndarray]],
) -> None:
    """Make the enabled set closed under the vertex dependencies (in place), given what was
    added since it last was: newly enabled ``nodes`` (flat indices into ``en_f``, the
    (T, size, size) enabled array flattened) and, per block level, refined ``blocks`` (flat
    codes into ``on[j]``) whose own consequences are still to apply. The blocks it refines
    are appended to ``added`` (per level).

    The rules (thesis §4.4, the restricted quadtree): an enabled block centre means its block
    is refined; an enabled edge midpoint needs the blocks on both sides of its edge; a refined
    block needs its parent, its centre and its four corners. Every consequence is at the same
    or a coarser level, so one sweep finest level first resolves every chain (a level-j
    block's corners are vertices of coarser levels, handled after it). Only what changed is
    visited; the result is the smallest closed set holding the old one and the additions,
    which is what a sweep over every node of every tile gives."""
    n_levels = len(on)
    n, s2n = size - 1, size * size
    pend: list[list[np.ndarray]] = [[] for _ in range(n_levels)]
    _bucket(pend, lev, s2n, nodes)
    parents: np.ndarray | None = None  # flat codes at this level of new blocks' parents
    for j in range(n_levels - 1, -1, -1):
        hh = n >> (j + 1)
        s2 = 2 * hh
        sh = s2.bit_length() - 1  # x // s2 = x >> sh, x % s2 = x & (s2 - 1) (powers of two)
        nb = 1 << j
        on_f = on[j].reshape(-1)
        cand = [] if parents is None else [parents]
        if pend[j]:
            g = np.concatenate(pend[j])
            t, loc = np.divmod(g, s2n)
            r, c = np.divmod(loc, size)
            bt = t << (2 * j)
            rm, cm = r & (s2 - 1), c & (s2 - 1)
            centre = (rm == hh) & (cm == hh)
            cand.append((bt + (((r - hh) >> sh) << j) + ((c - hh) >> sh))[centre])
            hmid = rm == 0  # on a horizontal edge: the blocks above and below
            vmid = cm == 0  # on a vertical edge: the blocks left and right
            # (Only the block beyond the midpoint's edge can fall outside the tile.)
            below, right = r >> sh, c >> sh
            above, left = below - 1, right - 1
            bj_h, bi_v = (c - hh) >> sh, (r - hh) >> sh
            for sel, bi, bj in (
                (hmid & (above >= 0), above, bj_h),
                (hmid & (below < nb), below, bj_h),
                (vmid & (left >= 0), bi_v, left),
                (vmid & (right < nb), bi_v, right),
            ):
                cand.append((bt + (bi << j) + bj)[sel])
        new = np.empty(0, np.int64)
        if cand:
            cc = np.concatenate(cand)
            cc = cc[~on_f[cc]]
            if len(cc):
                new = np.unique(cc)
                on_f[new] = True
                added[j].append(new)
        # The new blocks and those given: their centres and corners, and their parents.
        if len(blocks[j]):
            new = np.concatenate([new, blocks[j]])
        if len(new) == 0:
            parents = None
            continue
        t, bi, bj = new >> (2 * j), (new >> j) & (nb - 1), new & (nb - 1)
        nw = t * s2n + (2 * bi * hh) * size + 2 * bj * hh  # north-west corner
        en_f[nw + hh * size + hh] = True  # centre
        k = np.concatenate([nw, nw + s2, nw + s2 * size, nw + s2 * size + s2])
        k = k[~en_f[k]]
        if len(k):
            en_f[k] = True
            _bucket(pend, lev, s2n, k)
        parents = (((t << (j - 1)) + (bi >> 1)) << (j - 1)) + (bj >> 1) if j > 0 else None


def _bucket(pend: list[list[np.ndarray]], lev: np.ndarray, s2n: int, g: np.ndarray) -> None:
    """Append flat node indices ``g`` to ``pend`` by their block level (`_node_levels`;
    tile corners, level -1, have no dependencies and are dropped)."""
    if len(g) == 0:
        return
    lv = lev.take(g % s2n)
    for j in np.unique(lv).tolist():
        if j >= 0:
            pend[j].append(g[lv == j])


def _same_level_neighbours(keys: np.ndarray) -> tuple[tuple, tuple]:
    """Row pairs of tiles that share an edge at the same level: (west, east) and (north,
    south) index arrays. Longitude wraps; rows do not (the poles)."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    if len(keys) == 0:
        e = np.empty(0, np.int64)
        return (e, e), (e, e)
    level, x, y = keys.T
    code = (level << 58) | (y << 29) | x
    order = np.argsort(code)
    sorted_code = code[order]

    def find(codes: np.ndarray) -> np.ndarray:
        i = np.clip(np.searchsorted(sorted_code, codes), 0, len(codes) - 1)
        hit = sorted_code[i] == codes
        return np.where(hit, order[i], -1)

    ncols = np.left_shift(2, level)  # level_shape(level)[0] = 2^(level + 1), per tile
    nrows = ncols // 2
    east = find((level << 58) | (y << 29) | ((x + 1) % ncols))
    south = find((level << 58) | (np.minimum(y + 1, nrows - 1) << 29) | x)
    south = np.where(y + 1 < nrows, south, -1)
    rows = np.arange(len(keys))
    ew = (rows[east >= 0], east[east >= 0])
    ns = (rows[south >= 0], south[south >= 0])
    # A tile is its own east neighbour only at level 0 with one column, which cannot happen.
    return ew, ns


# -- triangulation ----------------------------------------------------------------------------
def triangulate(
    frame: ClodFrame, size: int, keys: np.ndarray
) -> tuple[list[np.ndarray], np.ndarray]:
    """Triangle lists over the tile vertex layout (tile_mesh.py) for each tile of a frame.

    Per block level, every refined block's fan is written as 12 candidate triangles (three
    per border edge: two halves when the edge midpoint is enabled, else the whole edge), kept
    where they apply, in one masked selection over all blocks of the level.

    Returns (indices per tile as uint32 triangle lists, (T,) triangle counts)."""
    n = size - 1
    s2n = size * size
    t_n = frame.enabled.shape[0]
    en_f = frame.enabled.reshape(-1)
    parts_t: list[np.ndarray] = []
    parts_tri: list[np.ndarray] = []
    n_levels = len(frame.on)
    for j in range(n_levels):
        hh = n >> (j + 1)
        nb = 1 << j
        code = frame.refined(j)
        if len(code) == 0:
            continue
        t, rest = np.divmod(code, nb * nb)
        bi, bj = np.divmod(rest, nb)
        nw = (2 * bi * hh) * size + 2 * bj * hh  # node indices within the tile
        s2, down = 2 * hh, 2 * hh * size
        centre = nw + hh * size + hh
        ne, se, sw = nw + s2, nw + down + s2, nw + down
        mn, me, ms, mw = nw + hh, nw + hh * size + s2, nw + down + hh, nw + hh * size
        if j + 1 < n_levels:
            nc = 2 * nb
            q = frame.on[j + 1].reshape(-1)
            c00 = (t * nc + 2 * bi) * nc + 2 * bj
            q_nw, q_ne, q_sw, q_se = q[c00], q[c00 + 1], q[c00 + nc], q[c00 + nc + 1]
        else:
            q_nw = q_ne = q_sw = q_se = np.zeros(len(t), dtype=bool)
        tb = t * s2n
        # Walk the border clockwise (as seen from above): each edge u -> m -> v, with the
        # quadrants of its two halves. Triangles are written (centre, v, u): counter-clockwise
        # from above, the winding of grid_indices. Candidate k = 3 * edge + case, in the order
        # (first half, second half, whole edge).
        tri_b, tri_a, keep = [], [], []
        for u, m, v, qa, qb in (
            (nw, mn, ne, q_nw, q_ne),
            (ne, me, se, q_ne, q_se),
            (se, ms, sw, q_se, q_sw),
            (sw, mw, nw, q_sw, q_nw),
        ):
            m_on = en_f[tb + m]
            tri_b += [m, v, v]
            tri_a += [u, m, u]
            keep += [m_on & ~qa, m_on & ~qb, ~m_on]
        tri = np.empty((12, len(t), 3), dtype=np.int64)
        tri[:, :, 0] = centre
        tri[:, :, 1] = tri_b
        tri[:, :, 2] = tri_a
        at = np.flatnonzero(np.stack(keep))  # (candidate k, block) in row-major order
        parts_t.append(t.take(at % len(t)))
        parts_tri.append(tri.reshape(-1, 3).take(at, axis=0))

    # Skirts along the enabled edge vertices of non-pole edges (north, south, west, east).
    level, _, y = np.asarray(keys, dtype=np.int64).reshape(-1, 3).T
    nrows = np.left_shift(1, level)
    k = np.arange(size)
    edge_nodes = np.stack([k, n * size + k, k * size, k * size + n])  # (4, size)
    edge_on = frame.enabled.reshape(t_n, -1)[:, edge_nodes]  # (T, 4, size)
    edge_on[:, 0][y == 0] = False  # a pole row is one point: no skirt there
    edge_on[:, 1][y == nrows - 1] = False
    tt, ee, kk = np.nonzero(edge_on)
    same = (tt[:-1] == tt[1:]) & (ee[:-1] == ee[1:])
    i0 = np.nonzero(same)[0]
    t_s, e_s, k0, k1 = tt[i0], ee[i0], kk[i0], kk[i0 + 1]
    top0, top1 = edge_nodes[e_s, k0], edge_nodes[e_s, k1]
    bot0, bot1 = s2n + e_s * size + k0, s2n + e_s * size + k1
    parts_t += [t_s, t_s]
    parts_tri += [np.stack([top0, bot0, top1], 1), np.stack([top1, bot0, bot1], 1)]

    all_t = np.concatenate(parts_t)
    all_tri = np.concatenate(parts_tri).astype(np.uint32)
    # Stable, so each tile keeps its triangles' order; tile rows fit int16 (MAX_TILES is
    # 16 384), for which numpy's stable sort is a radix sort.
    order = np.argsort(all_t.astype(np.int16) if t_n < 2**15 else all_t, kind="stable")
    counts = np.bincount(all_t, minlength=t_n)
    flat = all_tri[order].reshape(-1)
    ends = np.cumsum(counts * 3).tolist()
    # Slices of one array (np.split's per-piece overhead is ~20x a plain slice).
    chunks = [flat[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]
    return chunks, counts
