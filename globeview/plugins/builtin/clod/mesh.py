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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from globeview.plugins.api import (
    enu_basis,
    level_shape,
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


def tile_clod(
    key: tuple[int, int, int],
    heights: np.ndarray,
    exaggeration: float,
    displace: Callable[[np.ndarray], np.ndarray] | None = None,
) -> TileClod:
    """Precompute a tile's vertex errors, block error maxima and block radii (vectorised).

    ``displace`` (a ViewState's CPU displacement, (M, 3) -> (M, 3) ECEF) moves the nodes where
    the vertex shader draws them before anything is measured: the vertex errors then include
    how far the displacement bends the surface away from straight edges (the collapse's fold
    lines), and radii and distances are those of the drawn geometry, so blocks a fold crosses
    refine like rough terrain (no gap opens along the fold)."""
    level, x, y = key
    size = heights.shape[0]
    n = size - 1
    w, s, e, nn = (float(v) for v in tile_bounds_arrays(level, x, y))
    lon, lat = node_lonlat((w, s, e, nn), size)
    lon_g, lat_g = np.meshgrid(lon, lat)
    mid_lon, mid_lat = 0.5 * (w + e), 0.5 * (s + nn)
    origin = np.asarray(lonlat_to_ecef(mid_lon, mid_lat, 0.0), dtype=np.float64).reshape(3)
    basis = enu_basis(mid_lon, mid_lat)
    h = heights.astype(np.float64) * exaggeration
    ecef = np.asarray(lonlat_to_ecef(lon_g, lat_g, h), dtype=np.float64)
    if displace is not None:
        ecef = np.asarray(displace(ecef.reshape(-1, 3)), dtype=np.float64).reshape(ecef.shape)
    pos = (ecef - origin) @ basis.T  # (size, size, 3) in ENU

    err = np.zeros((size, size))
    n_levels = n_block_levels(size)
    for j in range(n_levels):
        hh = n >> (j + 1)
        s2 = 2 * hh
        # Horizontal edge midpoints (rows 0, 2h, ..; cols h, 3h, ..) between (r, c -+ h).
        c = pos[::s2, hh::s2]
        err[::s2, hh::s2] = np.linalg.norm(
            c - 0.5 * (pos[::s2, 0 : n - hh + 1 : s2] + pos[::s2, s2::s2]), axis=-1
        )
        # Vertical edge midpoints between (r -+ h, c).
        c = pos[hh::s2, ::s2]
        err[hh::s2, ::s2] = np.linalg.norm(
            c - 0.5 * (pos[0 : n - hh + 1 : s2, ::s2] + pos[s2::s2, ::s2]), axis=-1
        )
        # Block centres: against both diagonals (the one through the parent's centre is the
        # one the parent's fan uses; the max of the two is conservative and symmetric).
        c = pos[hh::s2, hh::s2]
        nw = pos[0 : n - hh + 1 : s2, 0 : n - hh + 1 : s2]
        se = pos[s2::s2, s2::s2]
        ne = pos[0 : n - hh + 1 : s2, s2::s2]
        sw = pos[s2::s2, 0 : n - hh + 1 : s2]
        err[hh::s2, hh::s2] = np.maximum(
            np.linalg.norm(c - 0.5 * (nw + se), axis=-1),
            np.linalg.norm(c - 0.5 * (ne + sw), axis=-1),
        )

    emax: list[np.ndarray] = [np.empty(0)] * n_levels
    radius: list[np.ndarray] = [np.empty(0)] * n_levels
    for j in range(n_levels - 1, -1, -1):
        hh = n >> (j + 1)
        s2 = 2 * hh
        nb = 1 << j
        own = np.maximum.reduce(
            [
                err[hh::s2, hh::s2],  # centre
                err[0:n:s2, hh::s2],  # north midpoint
                err[s2::s2, hh::s2],  # south midpoint
                err[hh::s2, 0:n:s2],  # west midpoint
                err[hh::s2, s2::s2],  # east midpoint
            ]
        )
        centre = pos[hh::s2, hh::s2]
        corners = [
            pos[0:n:s2, 0:n:s2],
            pos[0:n:s2, s2::s2],
            pos[s2::s2, 0:n:s2],
            pos[s2::s2, s2::s2],
        ]
        r = np.maximum.reduce([np.linalg.norm(q - centre, axis=-1) for q in corners])
        if j == n_levels - 1:
            # 3 x 3 nodes: the midpoints too.
            mids = [
                pos[0:n:s2, hh::s2],
                pos[s2::s2, hh::s2],
                pos[hh::s2, 0:n:s2],
                pos[hh::s2, s2::s2],
            ]
            r = np.maximum(
                r, np.maximum.reduce([np.linalg.norm(q - centre, axis=-1) for q in mids])
            )
        else:
            ch = emax[j + 1].reshape(nb, 2, nb, 2)
            own = np.maximum(own, ch.max(axis=(1, 3)))
            # Children's spheres, moved to this centre (triangle inequality).
            cc = pos[hh // 2 :: hh, hh // 2 :: hh].reshape(nb, 2, nb, 2, 3)
            off = np.linalg.norm(cc - centre[:, None, :, None, :], axis=-1)
            r = np.maximum(r, (radius[j + 1].reshape(nb, 2, nb, 2) + off).max(axis=(1, 3)))
        emax[j] = own
        radius[j] = r
    return TileClod(origin, basis, pos, err, emax, radius)


# -- per-frame selection ----------------------------------------------------------------------
@dataclass
class ClodFrame:
    """The enabled state of a batch of T tiles for one view.

    on: per block level j, (T, 2^j, 2^j) bool: block refined (its centre enabled).
    enabled: (T, size, size) bool: enabled vertices.
    error_px: (T,) the largest error (pixels) the meshes leave: disabled midpoints of refined
        blocks (E_v K / d) and unrefined sub-blocks (E_max K / (d - s)).
    exchange_passes: dependency passes run until shared tile edges agreed.
    """

    on: list[np.ndarray]
    enabled: np.ndarray
    error_px: np.ndarray
    exchange_passes: int


def clod_frame(
    keys: np.ndarray,
    tiles: list[TileClod],
    eye_local: np.ndarray,
    planes_local: np.ndarray,
    tau_ratio: float,
    k_px: float,
    cull: bool = True,
) -> ClodFrame:
    """Enable vertices of T tiles for one view.

    Args:
        keys: (T, 3) int (level, x, y) of the tiles (used to find same-level neighbours).
        tiles: their `TileClod` data (same order).
        eye_local: (T, 3) the eye in each tile's ENU frame (m).
        planes_local: (T, 6, 4) frustum planes in each tile's ENU frame (n . p + d >= 0 in).
        tau_ratio: the thesis' threshold tau' (error / distance), = tau_px / k_px.
        k_px: view.sse_factor (pixels per metre of error at 1 m), for error_px.
        cull: prune blocks outside the frustum (thesis §5.2).
    """
    t_n = len(tiles)
    size = tiles[0].pos.shape[0] if t_n else 3
    n = size - 1
    n_levels = n_block_levels(size)
    pos = np.stack([t.pos for t in tiles]) if t_n else np.zeros((0, size, size, 3))
    err = np.stack([t.err for t in tiles]) if t_n else np.zeros((0, size, size))
    emax = [np.stack([t.emax[j] for t in tiles]) for j in range(n_levels)] if t_n else []
    rad = [np.stack([t.radius[j] for t in tiles]) for j in range(n_levels)] if t_n else []
    error_px = np.zeros(t_n)
    enabled = np.zeros((t_n, size, size), dtype=bool)
    on = [np.zeros((t_n, 1 << j, 1 << j), dtype=bool) for j in range(n_levels)]
    if t_n == 0:
        return ClodFrame(on, enabled, error_px, 0)

    # 1. Update, top-down over the refined blocks only (the thesis' recursion, one level of
    # all tiles at a time).
    on[0][:] = True
    for j in range(n_levels):
        hh = n >> (j + 1)
        t, bi, bj = np.nonzero(on[j])
        rc, cc = (2 * bi + 1) * hh, (2 * bj + 1) * hh
        # Vertex test on the four edge midpoints of every refined block.
        for dr, dc in ((-hh, 0), (hh, 0), (0, -hh), (0, hh)):
            r, c = rc + dr, cc + dc
            d = np.linalg.norm(pos[t, r, c] - eye_local[t], axis=-1)
            e = err[t, r, c]
            ok = e >= tau_ratio * d
            enabled[t[ok], r[ok], c[ok]] = True
            np.maximum.at(error_px, t[~ok], e[~ok] * k_px / np.maximum(d[~ok], 1.0))
        if j == n_levels - 1:
            break
        # Box test on the four children.
        ct = np.repeat(t, 4)
        ci = (2 * bi[:, None] + np.array([0, 0, 1, 1])).reshape(-1)
        cj = (2 * bj[:, None] + np.array([0, 1, 0, 1])).reshape(-1)
        ch = hh // 2
        centre = pos[ct, (2 * ci + 1) * ch, (2 * cj + 1) * ch]
        s = rad[j + 1][ct, ci, cj]
        em = emax[j + 1][ct, ci, cj]
        room = np.linalg.norm(centre - eye_local[ct], axis=-1) - s
        refine = (em > 0.0) & (em >= tau_ratio * np.maximum(room, 0.0))
        visible = np.ones(len(ct), dtype=bool)
        if cull:
            pl = planes_local[ct]
            dist = np.einsum("mpk,mk->mp", pl[:, :, :3], centre) + pl[:, :, 3]
            visible = np.all(dist >= -s[:, None], axis=1)
            refine &= visible
        on[j + 1][ct[refine], ci[refine], cj[refine]] = True
        left = ~refine & visible  # what is left coarse on screen
        np.maximum.at(error_px, ct[left], em[left] * k_px / np.maximum(room[left], 1.0))

    # 2./3. Dependencies, then agreement on shared tile edges, until a fixpoint.
    enabled[:, 0::n, 0::n] = True  # tile corners
    pairs_ew, pairs_ns = _same_level_neighbours(keys)
    passes = 0
    while True:
        passes += 1
        _close_dependencies(on, enabled, n)
        changed = False
        for a, b, ea, eb in (
            (pairs_ew[0], pairs_ew[1], (slice(None), n), (slice(None), 0)),
            (pairs_ns[0], pairs_ns[1], (n, slice(None)), (0, slice(None))),
        ):
            if len(a) == 0:
                continue
            va = enabled[(a, *ea)]
            vb = enabled[(b, *eb)]
            union = va | vb
            if np.any(union != va) or np.any(union != vb):
                changed = True
                enabled[(a, *ea)] = union
                enabled[(b, *eb)] = union
        if not changed or passes > 4 * n_levels + 4:
            break
    return ClodFrame(on, enabled, error_px, passes)


def _close_dependencies(on: list[np.ndarray], enabled: np.ndarray, n: int) -> None:
    """One bottom-up pass making the enabled set closed under the vertex dependencies (in
    place). Processing block levels finest first resolves every chain: a level-j block's
    corners are vertices of coarser levels, handled after it."""
    t_n = enabled.shape[0]
    for j in range(len(on) - 1, -1, -1):
        hh = n >> (j + 1)
        s2 = 2 * hh
        nb = 1 << j
        blk = on[j]
        # An enabled centre (a finer block's corner) means its block is refined.
        blk |= enabled[:, hh::s2, hh::s2]
        # An enabled edge midpoint needs the blocks on both sides of its edge.
        hm = enabled[:, 0::s2, hh::s2]  # (T, nb + 1, nb)
        blk |= hm[:, :-1, :] | hm[:, 1:, :]
        vm = enabled[:, hh::s2, 0::s2]  # (T, nb, nb + 1)
        blk |= vm[:, :, :-1] | vm[:, :, 1:]
        # A refined child needs its parent.
        if j + 1 < len(on):
            blk |= on[j + 1].reshape(t_n, nb, 2, nb, 2).any(axis=(2, 4))
        enabled[:, hh::s2, hh::s2] |= blk
        # A refined block needs its four corners.
        corners = enabled[:, 0::s2, 0::s2]  # a view: (T, nb + 1, nb + 1)
        corners[:, :-1, :-1] |= blk
        corners[:, :-1, 1:] |= blk
        corners[:, 1:, :-1] |= blk
        corners[:, 1:, 1:] |= blk


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

    ncols = np.array([level_shape(int(lv))[0] for lv in level])
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

    Returns (indices per tile as uint32 triangle lists, (T,) triangle counts)."""
    n = size - 1
    t_n = frame.enabled.shape[0]
    en = frame.enabled
    parts_t: list[np.ndarray] = []
    parts_tri: list[np.ndarray] = []
    n_levels = len(frame.on)
    for j in range(n_levels):
        hh = n >> (j + 1)
        t, bi, bj = np.nonzero(frame.on[j])
        if len(t) == 0:
            continue
        r0, c0 = 2 * bi * hh, 2 * bj * hh

        def node(dr: int, dc: int, r0=r0, c0=c0) -> np.ndarray:
            return (r0 + dr) * size + (c0 + dc)

        centre = node(hh, hh)
        nw, ne, se, sw = node(0, 0), node(0, 2 * hh), node(2 * hh, 2 * hh), node(2 * hh, 0)
        mn, me, ms, mw = node(0, hh), node(hh, 2 * hh), node(2 * hh, hh), node(hh, 0)
        if j + 1 < n_levels:
            q = frame.on[j + 1]
            q_nw, q_ne = q[t, 2 * bi, 2 * bj], q[t, 2 * bi, 2 * bj + 1]
            q_sw, q_se = q[t, 2 * bi + 1, 2 * bj], q[t, 2 * bi + 1, 2 * bj + 1]
        else:
            q_nw = q_ne = q_sw = q_se = np.zeros(len(t), dtype=bool)
        flat = en.reshape(t_n, -1)
        # Walk the border clockwise (as seen from above): each edge u -> m -> v, with the
        # quadrants of its two halves. Triangles are written (centre, v, u): counter-clockwise
        # from above, the winding of grid_indices.
        for u, m, v, qa, qb in (
            (nw, mn, ne, q_nw, q_ne),
            (ne, me, se, q_ne, q_se),
            (se, ms, sw, q_se, q_sw),
            (sw, mw, nw, q_sw, q_nw),
        ):
            m_on = flat[t, m]
            for sel, a, b in ((m_on & ~qa, u, m), (m_on & ~qb, m, v), (~m_on, u, v)):
                parts_t.append(t[sel])
                parts_tri.append(np.stack([centre[sel], b[sel], a[sel]], axis=1))

    # Skirts along the enabled edge vertices of non-pole edges (north, south, west, east).
    level, _, y = np.asarray(keys, dtype=np.int64).reshape(-1, 3).T
    nrows = np.left_shift(1, level)
    k = np.arange(size)
    edge_nodes = np.stack([k, n * size + k, k * size, k * size + n])  # (4, size)
    edge_on = en.reshape(t_n, -1)[:, edge_nodes]  # (T, 4, size)
    edge_on[:, 0][y == 0] = False  # a pole row is one point: no skirt there
    edge_on[:, 1][y == nrows - 1] = False
    tt, ee, kk = np.nonzero(edge_on)
    same = (tt[:-1] == tt[1:]) & (ee[:-1] == ee[1:])
    i0 = np.nonzero(same)[0]
    t_s, e_s, k0, k1 = tt[i0], ee[i0], kk[i0], kk[i0 + 1]
    top0, top1 = edge_nodes[e_s, k0], edge_nodes[e_s, k1]
    bot0, bot1 = size * size + e_s * size + k0, size * size + e_s * size + k1
    parts_t += [t_s, t_s]
    parts_tri += [np.stack([top0, bot0, top1], 1), np.stack([top1, bot0, bot1], 1)]

    all_t = np.concatenate(parts_t)
    all_tri = np.concatenate(parts_tri).astype(np.uint32)
    order = np.argsort(all_t, kind="stable")
    counts = np.bincount(all_t, minlength=t_n)
    chunks = np.split(all_tri[order].reshape(-1), np.cumsum(counts * 3)[:-1])
    return chunks, counts
