"""Per-block strides inside a tile (issue #27 item 3, design §5.2): each 8 x 8-cell block of
a tile drawn at the coarsest stride whose projected error stays within tau.

A tile's block facts ((`N_FACTS`, 64) float32, bounds rounded outward: a column per block,
blocks row-major from the north-west one) are what the renderer knows of a loaded tile:

- ``ERR``: the block's height error (m, true relief) at strides 2, 4, 8: the tile's level
  error (its stride-1 error from the store) plus the running max over strides of the block's
  max |bilinear of every s-th node - node| over its 9 x 9 nodes (`block_height_stats`, the
  definition of the store's per-tile stride deltas, `terrain/ingest/tile_errors.stride_deltas`,
  on the 8-cell block instead of the 64-cell tile);
- ``H``: the min and max height (m) of its nodes;
- ``GEO``: its centre on the ellipsoid (ECEF m), the geodetic up there, the radius (m) of a
  ball about that centre holding the block's ellipsoid surface, and the angle (radians) the
  up vector turns over the block (`block_geometry`).

The projected error of a block at stride s is ``(e (ERR[s]) + chord_sag(s)) * K / d``, as
the tile's (`tile_cache.stride_errors_m`, e the exaggeration), with d a lower bound of the
eye's distance to the block: the distance to the ball about the block's centre at its mid
height holding its surface between its min and max heights. A block never draws finer than
its tile's stride (that one already meets tau for the whole tile), so blocks only coarsen.
"""

from __future__ import annotations

import numpy as np

from globeview.geodesy import WGS84
from globeview.lod.block_indices import BLOCK_CELLS, BLOCKS, N_BLOCK_STRIDES
from globeview.lod.culling import chord_sag
from globeview.lod.view_state import ViewState
from globeview.terrain.quadtree import tile_bounds_arrays

#: Rows of a tile's block facts (`N_FACTS`, 64): fact-major, so that each fact of many
#: tiles is one contiguous (N, 64) array in the per-frame choice.
ERR = slice(0, 3)  # height error (m) at strides 2, 4, 8, level error included
H = slice(3, 5)  # min, max node height (m)
CENTRE = slice(5, 8)  # ECEF (m) of the block's centre on the ellipsoid
UP = slice(8, 11)  # geodetic unit normal there
RADIUS, TURN = 11, 12  # m; radians
N_FACTS = 13
N_BLOCKS = BLOCKS * BLOCKS
#: Metres added to a block's reach for its facts' float32 rounding (ECEF coordinates of
#: ~6.4e6 m round by up to 0.25 m each; differences of them by twice that per axis).
FLOAT32_SLACK_M = 4.0
#: Stride index from which a tile is drawn whole (stride 8 = one block, nothing to gain).
WHOLE_FROM = N_BLOCK_STRIDES - 1


def block_height_stats(heights: np.ndarray, level_err: np.ndarray) -> np.ndarray:
    """(B, 64, 5) float64 per block of B tiles' heights (B, 65, 65) (m, row 0 north): its
    height error at strides 2, 4, 8 (m: ``level_err`` (B,) plus the running max of the
    block's max |bilinear of every s-th node - node| over its closed 9 x 9 nodes), then its
    min and max node height. NaN heights count as 0 difference (as the store's maxima)."""
    h = np.asarray(heights, dtype=np.float64)
    b, size = h.shape[0], h.shape[1]
    if size != BLOCKS * BLOCK_CELLS + 1:
        raise ValueError(f"block stats need tiles of {BLOCKS * BLOCK_CELLS + 1} nodes")
    out = np.empty((b, N_BLOCKS, 5))
    running = np.zeros((b, BLOCKS, BLOCKS))
    idx = np.arange(size)
    for k, s in enumerate((2, 4, 8)):
        i0 = np.minimum((idx // s) * s, size - 1 - s)
        f = (idx - i0) / s
        rows = h[:, i0, :] * (1.0 - f)[None, :, None] + h[:, i0 + s, :] * f[None, :, None]
        bil = rows[:, :, i0] * (1.0 - f)[None, None, :] + rows[:, :, i0 + s] * f[None, None, :]
        d = np.nan_to_num(np.abs(bil - h), nan=0.0)
        running = np.maximum(running, _closed_block_max(d))
        out[:, :, k] = running.reshape(b, -1)
    out[:, :, ERR] += np.asarray(level_err, dtype=np.float64).reshape(b, 1, 1)
    out[:, :, 3] = -_closed_block_max(np.nan_to_num(-h, nan=np.inf)).reshape(b, -1)
    out[:, :, 4] = _closed_block_max(np.nan_to_num(h, nan=-np.inf)).reshape(b, -1)
    return out


def _closed_block_max(d: np.ndarray) -> np.ndarray:
    """(B, 8, 8) max of (B, 65, 65) node values over each block's closed 9 x 9 nodes."""
    b = d.shape[0]
    c = BLOCK_CELLS
    inner = d[:, :-1, :-1].reshape(b, BLOCKS, c, BLOCKS, c).max(axis=(2, 4))
    below = d[:, c::c, :-1].reshape(b, BLOCKS, BLOCKS, c).max(axis=3)  # row 8(bi+1)
    right = d[:, :-1, c::c].reshape(b, BLOCKS, c, BLOCKS).max(axis=2)  # col 8(bj+1)
    corner = d[:, c::c, c::c]
    out: np.ndarray = np.maximum(np.maximum(inner, below), np.maximum(right, corner))
    return out


def block_geometry(keys: np.ndarray) -> np.ndarray:
    """(N, 64, 8) float64 per block of tiles ``keys`` (N, 3): ECEF centre on the ellipsoid,
    geodetic up there, the radius (m) of a ball about the centre that holds the block's
    ellipsoid surface (the farthest of its corners and edge midpoints, 5 % more, plus the
    chord sag over the block), and the angle (radians) the up vector turns within it."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    n = len(keys)
    out = np.empty((n, N_BLOCKS, 8))
    west, south, east, north = (np.empty(n) for _ in range(4))
    for level in np.unique(keys[:, 0]):
        rows = keys[:, 0] == level
        w, s, e, nn = tile_bounds_arrays(int(level), keys[rows, 1], keys[rows, 2])
        west[rows], south[rows], east[rows], north[rows] = w, s, e, nn
    t = np.arange(2 * BLOCKS + 1) / (2 * BLOCKS)  # block edges and middles
    lon = west[:, None] + (east - west)[:, None] * t  # (N, 17)
    lat = north[:, None] + (south - north)[:, None] * t
    lon_r, lat_r = np.radians(lon), np.radians(lat)
    # ECEF on the ellipsoid at every (lat, lon) of the 17 x 17 lattice.
    sin_lat, cos_lat = np.sin(lat_r), np.cos(lat_r)
    nu = WGS84.a / np.sqrt(1.0 - WGS84.e2 * sin_lat**2)
    x = (nu * cos_lat)[:, :, None] * np.cos(lon_r)[:, None, :]
    y = (nu * cos_lat)[:, :, None] * np.sin(lon_r)[:, None, :]
    z = np.broadcast_to((nu * (1.0 - WGS84.e2) * sin_lat)[:, :, None], x.shape)
    pts = np.stack([x, y, z], axis=-1)  # (N, 17, 17, 3)
    centre = pts[:, 1::2, 1::2]  # (N, 8, 8, 3)
    up = np.stack(
        [
            cos_lat[:, 1::2, None] * np.cos(lon_r)[:, None, 1::2],
            cos_lat[:, 1::2, None] * np.sin(lon_r)[:, None, 1::2],
            np.broadcast_to(sin_lat[:, 1::2, None], (n, BLOCKS, BLOCKS)),
        ],
        axis=-1,
    )
    radius = np.zeros((n, BLOCKS, BLOCKS))
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            ring = pts[:, 1 + di :: 2, 1 + dj :: 2][:, :BLOCKS, :BLOCKS]
            radius = np.maximum(radius, np.linalg.norm(ring - centre, axis=-1))
    span_lat = np.radians(np.abs(north - south)) / BLOCKS
    span_lon = np.radians(np.abs(east - west)) / BLOCKS
    sag = chord_sag(np.degrees(np.hypot(span_lat, span_lon)))
    turn = 0.5 * (span_lat + span_lon)
    out[:, :, 0:3] = centre.reshape(n, N_BLOCKS, 3)
    out[:, :, 3:6] = up.reshape(n, N_BLOCKS, 3)
    out[:, :, 6] = (1.05 * radius).reshape(n, N_BLOCKS) + sag[:, None]
    out[:, :, 7] = turn[:, None]
    return out


def block_facts(keys: np.ndarray, stats: np.ndarray) -> np.ndarray:
    """(N, `N_FACTS`, 64) facts of tiles ``keys`` from their `block_height_stats` (N, 64, 5)."""
    both = np.concatenate([np.asarray(stats, np.float64), block_geometry(keys)], axis=2)
    return as_facts32(both.transpose(0, 2, 1))


def as_facts32(facts: np.ndarray) -> np.ndarray:
    """Block facts (..., `N_FACTS`, 64) float64 as float32 with the errors and radii rounded
    up (bounds stay bounds) and the min height down."""
    out = np.asarray(facts, dtype=np.float32).copy()
    up = np.float32(np.inf)
    for rows in (ERR, slice(4, 5), slice(RADIUS, TURN + 1)):
        out[..., rows, :] = np.nextafter(out[..., rows, :], up)
    out[..., 3, :] = np.nextafter(out[..., 3, :], -up)
    return out


def choose_block_strides(
    facts: np.ndarray,
    slots: np.ndarray,
    level: np.ndarray,
    stride_idx: np.ndarray,
    view: ViewState,
    tau_px: float,
    size: int,
) -> np.ndarray:
    """(N, 8, 8) int8 stride index (0..3) of each block of N tiles, or -1 for a tile drawn
    by its index variant (its stride index is `WHOLE_FROM` or more, its slot is -1 or its
    facts are NaN, or no block goes coarser than the tile).

    Args:
        facts: (S, `N_FACTS`, 64) float32 block facts by slot (NaN: unknown; `as_facts32`).
        slots: (N,) each tile's row of ``facts`` (-1: none).
        level: (N,) the tiles' quadtree levels.
        stride_idx: (N,) the stride index each tile is drawn at (its error within tau).
        view: the frame's view (eye, exaggeration, ``sse_factor``).
        tau_px: the screen-space error threshold (pixels).
        size: nodes per tile side (65).
    Vectorised over the tiles: a few dozen numpy calls whatever N.
    """
    n = len(stride_idx)
    out = np.full((n, BLOCKS, BLOCKS), -1, dtype=np.int8)
    tile_idx = np.asarray(stride_idx, dtype=np.int64)
    slots = np.asarray(slots, dtype=np.int64)
    rows = np.flatnonzero(tile_idx < WHOLE_FROM)
    rows = rows[slots[rows] >= 0]
    rows = rows[np.isfinite(facts[slots[rows], 0, 0])]
    if not len(rows) or view.displace is not None:
        return out
    # Fact-major rows (M, N_FACTS, 64): every fact below is a contiguous (M, 64) array.
    f = facts[slots[rows]]
    e = np.float32(view.exaggeration)
    mid = (f[:, 3] + f[:, 4]) * (np.float32(0.5) * e)
    half = (f[:, 4] - f[:, 3]) * (np.float32(0.5) * e)
    eye = np.asarray(view.eye, dtype=np.float32)
    d2 = np.zeros_like(mid)
    for k in range(3):
        diff = f[:, 5 + k] + mid * f[:, 8 + k] - eye[k]
        d2 += diff * diff
    # float32 ECEF (ulp 0.5 m at the Earth's radius): `FLOAT32_SLACK_M` more reach.
    reach = f[:, RADIUS] + half + np.abs(mid) * f[:, TURN] + np.float32(FLOAT32_SLACK_M)
    px_per_m = view.sse_factor / np.maximum(np.sqrt(d2) - reach, 1.0)  # (M, 64)
    node_deg = 180.0 / np.exp2(np.asarray(level, dtype=np.float64)[rows]) / (size - 1)
    # Errors grow with the stride (running max, sag): the coarsest within tau is a count.
    ok = np.zeros(mid.shape, dtype=np.int64)
    for k, s in enumerate((2.0, 4.0, 8.0)):
        sag = chord_sag(node_deg * s)[:, None].astype(np.float32)  # (M, 1)
        ok += (f[:, k] * e + sag) * px_per_m <= tau_px
    chosen = np.maximum(ok, tile_idx[rows, None])
    coarser = (chosen > tile_idx[rows, None]).any(axis=1)
    out[rows[coarser]] = chosen[coarser].reshape(-1, BLOCKS, BLOCKS).astype(np.int8)
    return out
