"""Per-block bends (issue #27 item 4, design C5): the projected error of each 8 x 8-cell
block of tiles drawn under a displacement (a tool's, e.g. the collapse), so that blocks
away from a fold keep coarse strides and only those the fold crosses go fine.

Each block is measured as the traversal measures a tile under a displacement
(`lod.traversal`): its bounding lattice (`culling.tile_bounding_points` over the block's
bounds and min / max heights), moved where it is drawn; its distance from the eye (the
bounding sphere of the moved lattice, as `culling.bounding_distance`, widened by the
lattice's margin and the bend); and the bend of the displacement over it
(`culling.displacement_bend_m`, per lattice span), which a stride s of the block's 8 cells
spans `candidates.bend_fractions` (9) times.
"""

from __future__ import annotations

import numpy as np

from globeview.lod.block_indices import BLOCK_CELLS, BLOCKS
from globeview.lod.candidates import bend_fractions
from globeview.lod.culling import displacement_bend_m, tile_bounding_points
from globeview.lod.view_state import ViewState
from globeview.terrain.quadtree import tile_bounds_arrays

#: Stride indices (into `bend_fractions`) of the block strides 2, 4, 8.
_BLOCK_STRIDE_IDX = np.array([1, 2, 3])


def block_bounds(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(west, south, east, north) degrees, each (N, 64), of the blocks of tiles ``keys``
    (N, 3) (level, x, y), blocks row-major from the north-west one."""
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    n = len(keys)
    west, south, east, north = (np.empty(n) for _ in range(4))
    for level in np.unique(keys[:, 0]):
        rows = keys[:, 0] == level
        w, s, e, nn = tile_bounds_arrays(int(level), keys[rows, 1], keys[rows, 2])
        west[rows], south[rows], east[rows], north[rows] = w, s, e, nn
    t = np.arange(BLOCKS + 1) / BLOCKS
    lon = west[:, None] + (east - west)[:, None] * t  # (N, 9) block edges, west to east
    lat = north[:, None] + (south - north)[:, None] * t  # north to south
    bw = np.broadcast_to(lon[:, None, :-1], (n, BLOCKS, BLOCKS)).reshape(n, -1)
    be = np.broadcast_to(lon[:, None, 1:], (n, BLOCKS, BLOCKS)).reshape(n, -1)
    bn = np.broadcast_to(lat[:, :-1, None], (n, BLOCKS, BLOCKS)).reshape(n, -1)
    bs = np.broadcast_to(lat[:, 1:, None], (n, BLOCKS, BLOCKS)).reshape(n, -1)
    return bw, bs, be, bn


def displaced_block_terms(
    keys: np.ndarray, hmin: np.ndarray, hmax: np.ndarray, view: ViewState
) -> tuple[np.ndarray, np.ndarray]:
    """Under ``view.displace``: (pixels per metre (M, 64), bend (m) at the block strides 2, 4,
    8 (M, 64, 3)) of the blocks of tiles ``keys`` (M, 3), with their min / max node heights
    ``hmin``, ``hmax`` (M, 64) (m, true relief). The pixels per metre use a lower bound of the
    eye's distance to the block as drawn (moved, and bent by up to the stride-8 bend).

    What does not depend on the eye (each block's moved bounding ball and its bends) is kept
    per tile while the tool's ``view.displacement_key`` and the exaggeration stay the same
    (a still collapse: only the distances are computed again each frame)."""
    m = len(keys)
    centre, reach, bend_s = _CACHE.balls(np.asarray(keys), hmin, hmax, view)
    d = np.sqrt(np.einsum("mbj,mbj->mb", centre - view.eye, centre - view.eye)) - reach
    px_per_m: np.ndarray = view.sse_factor / np.maximum(d, 1.0)
    return px_per_m.reshape(m, -1), bend_s


def _balls(
    keys: np.ndarray, hmin: np.ndarray, hmax: np.ndarray, view: ViewState
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre (M, 64, 3) m ECEF, reach (M, 64) m, bend (M, 64, 3) m at strides 2, 4, 8):
    a ball holding each block of tiles ``keys`` as drawn under ``view.displace`` (its moved
    bounding lattice's, `culling.bounding_distance`'s, widened by the lattice's margin and the
    stride-8 bend), and the block's bends."""
    m = len(keys)
    w, s, e, n = (b.ravel() for b in block_bounds(keys))
    lo = np.asarray(hmin, dtype=np.float64).ravel()
    hi = np.asarray(hmax, dtype=np.float64).ravel()
    pts, margin = tile_bounding_points(w, s, e, n, lo, hi, float(view.exaggeration))
    assert view.displace is not None
    moved = np.asarray(view.displace(pts.reshape(-1, 3)), dtype=np.float64).reshape(pts.shape)
    bend = displacement_bend_m(view, pts, moved)  # (M * 64,) per lattice span
    bend_s = bend[:, None] * bend_fractions(BLOCK_CELLS + 1)[_BLOCK_STRIDE_IDX][None, :]
    centre = moved.mean(axis=1)
    radius = np.sqrt(np.einsum("bkj,bkj->bk", moved - centre[:, None], moved - centre[:, None]))
    reach = radius.max(axis=1) + margin + bend_s[:, -1]
    return centre.reshape(m, -1, 3), reach.reshape(m, -1), bend_s.reshape(m, -1, 3)


class _BallCache:
    """`_balls` per tile, for one displacement (the tool's key) and exaggeration."""

    def __init__(self) -> None:
        self.key: object = None
        self.rows: dict[tuple[int, int, int, bytes], tuple[np.ndarray, ...]] = {}

    def balls(
        self, keys: np.ndarray, hmin: np.ndarray, hmax: np.ndarray, view: ViewState
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`_balls` of ``keys``, computed only for tiles not seen under this displacement
        (uncached without a tool key: nothing then says two displacements are the same)."""
        if view.displacement_key is None:
            return _balls(keys, hmin, hmax, view)
        key = (view.displacement_key, float(view.exaggeration), view.displacement_bend)
        if key != self.key or len(self.rows) > _CACHE_TILES:
            self.key, self.rows = key, {}
        heights = np.stack([hmin, hmax], axis=1).astype(np.float32)
        ids = [(int(k[0]), int(k[1]), int(k[2]), h.tobytes()) for k, h in zip(keys, heights)]
        new = [i for i, t in enumerate(ids) if t not in self.rows]
        if new:
            got = _balls(keys[new], hmin[new], hmax[new], view)
            for j, i in enumerate(new):
                self.rows[ids[i]] = tuple(a[j] for a in got)
        rows = [self.rows[t] for t in ids]
        return (
            np.stack([r[0] for r in rows]),
            np.stack([r[1] for r in rows]),
            np.stack([r[2] for r in rows]),
        )


#: Tiles `_BallCache` keeps before starting again (a few hundred KB).
_CACHE_TILES = 4096
_CACHE = _BallCache()
