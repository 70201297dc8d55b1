"""`chunked-sse`: the default LOD provider, chunked screen-space-error selection (TREND §4.2 /
Cesium style), vectorised. This is the renderer's original selection moved, unchanged, behind
the plugin interface (`LodProvider`).

The quadtree is walked level by level with numpy over all candidate tiles at once:

1. cull candidates against the frustum and the ellipsoid horizon (culling.py);
2. project each tile's geometric error to pixels, ``e * K / d`` with K = viewport height /
   (2 tan(fovy/2)) and d a lower bound of the distance to the tile;
3. refine (replace by its four children) when that exceeds tau and finer data exists, or
   when the tile's texels would be magnified beyond ``texel_px`` pixels and finer data exists;
4. draw the others with the coarsest index stride whose error still projects below tau
   (TREND's per-block resolution pyramid, applied to the whole tile).

The error of a tile drawn with stride s is its height error (from the tile store) times the
vertical exaggeration plus the chord sag of the curved ellipsoid between vertices s nodes
apart: flat triangles cut under a curved globe, and at globe scale that dominates.

Cracks between tiles drawn at different levels or strides are hidden by skirts.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from globeview.plugins.api import LodProvider, Setting
from globeview.render.culling import (
    LATTICE,
    bounding_distance,
    chord_sag,
    displacement_chord_error_m,
    frustum_visible,
    horizon_visible,
    tile_bounding_points,
)
from globeview.render.render_set import RenderSet
from globeview.render.tile_indices import IndexVariant
from globeview.render.view_state import ViewState
from globeview.terrain.quadtree import tile_bounds_arrays
from globeview.terrain.stack import N_STRIDES, TerrainStack

#: Deepest level the walk goes to even where the data stops (curvature alone).
MAX_LEVEL = 22


@dataclass
class ChunkedSettings:
    """Settings of the chunked selection.

    tau_px: screen-space error threshold (pixels); None uses the ViewState's.
    texel_px: refine while a texel of the tile's height/normal textures covers more pixels.
    max_tiles: stop refining beyond this many drawn tiles (a safety budget).
    """

    tau_px: float | None = None
    texel_px: float = 1.5
    max_tiles: int = 600


def stride_errors_m(
    level: int, height_err: np.ndarray, exaggeration: float, size: int
) -> np.ndarray:
    """(N, N_STRIDES) total geometric error (m) of drawing tiles at each stride: the height
    error scaled by the exaggeration plus the chord sag of the stride's vertex spacing."""
    node_deg = 180.0 / 2**level / (size - 1)
    strides = 2 ** np.arange(N_STRIDES)
    sag = chord_sag(node_deg * strides)
    valid = strides <= size - 1
    total = height_err * exaggeration + sag[None, :]
    total[:, ~valid] = np.inf
    return total


def select_tiles(
    view: ViewState, terrain: TerrainStack, settings: ChunkedSettings | None = None
) -> RenderSet:
    """Choose the tiles (and each one's index stride) for a view."""
    settings = settings or ChunkedSettings()
    t0 = time.perf_counter()
    tau = settings.tau_px if settings.tau_px is not None else view.tau_px
    size = terrain.tile_size
    k_px = view.sse_factor
    exag = view.exaggeration

    x = np.array([0, 1], dtype=np.int64)
    y = np.array([0, 0], dtype=np.int64)
    out_keys, out_stride, out_err = [], [], []
    culled_f = culled_h = 0
    drawn = 0
    for level in range(MAX_LEVEL + 1):
        if len(x) == 0:
            break
        w, s, e, n = tile_bounds_arrays(level, x, y)
        meta = terrain.metadata(level, x, y)
        pts, margin = tile_bounding_points(w, s, e, n, meta.hmin, meta.hmax, exag)
        pts_true = pts
        if view.displace is not None:
            pts = np.asarray(view.displace(pts.reshape(-1, 3)), dtype=np.float64).reshape(pts.shape)
        vis_f = frustum_visible(view, pts, margin)
        vis_h = horizon_visible(view, w, s, e, n, meta.hmax, exag)
        culled_f += int(np.count_nonzero(~vis_f))
        culled_h += int(np.count_nonzero(vis_f & ~vis_h))
        keep = vis_f & vis_h
        x, y = x[keep], y[keep]
        if len(x) == 0:
            break
        err = stride_errors_m(level, meta.stride_error[keep], exag, size)
        if view.displace is not None:
            # A displacement that bends the surface (the collapse's fold lines) bends it away
            # from straight triangle edges: count that as geometric error, shrinking with the
            # stride, so tiles across a fold refine and no gap opens between them.
            bend = displacement_chord_error_m(view.displace, pts_true[keep])
            frac = np.minimum(1.0, 2.0 ** np.arange(N_STRIDES) * (LATTICE - 1) / (size - 1))
            err = err + bend[:, None] * frac[None, :]
        dist = bounding_distance(view, pts[keep], margin[keep])
        px_per_m = k_px / dist
        sse = err * px_per_m[:, None]
        tile_m = math.radians(180.0 / 2**level) * 6.371e6
        texel = tile_m / (size - 1) * px_per_m
        finer = meta.has_finer[keep]
        refine = ((sse[:, 0] > tau) & (finer | (level < MAX_LEVEL))) | (
            (texel > settings.texel_px) & finer
        )
        if level == MAX_LEVEL:
            refine[:] = False
        # Budget: if refining everything would exceed the tile budget, refine the worst first.
        n_ref = int(np.count_nonzero(refine))
        room = settings.max_tiles - drawn - int(np.count_nonzero(~refine))
        if n_ref * 4 > room and n_ref > 0:
            allowed = max(room // 4, 0)
            order = np.argsort(-sse[:, 0])
            ref_idx = order[refine[order]][:allowed]
            refine[:] = False
            refine[ref_idx] = True
        acc = ~refine
        if acc.any():
            # Coarsest stride whose error projects within tau (stride 1 if none does).
            ok = sse[acc] <= tau
            idx = np.where(ok.any(axis=1), N_STRIDES - 1 - np.argmax(ok[:, ::-1], axis=1), 0)
            out_keys.append(np.stack([np.full(int(acc.sum()), level), x[acc], y[acc]], axis=1))
            out_stride.append(idx)
            out_err.append(sse[acc][np.arange(len(idx)), idx])
            drawn += int(acc.sum())
        rx, ry = x[refine], y[refine]
        x = np.concatenate([2 * rx, 2 * rx + 1, 2 * rx, 2 * rx + 1])
        y = np.concatenate([2 * ry, 2 * ry, 2 * ry + 1, 2 * ry + 1])

    if not out_keys:
        rs = RenderSet.empty()
    else:
        keys = np.concatenate(out_keys)
        stride_idx = np.concatenate(out_stride)
        pole = (keys[:, 2] == 0).astype(np.int64) + 2 * (keys[:, 2] == (1 << keys[:, 0]) - 1)
        combo = stride_idx * 4 + pole
        uniq, ids = np.unique(combo, return_inverse=True)
        poles = (None, "north", "south", "both")
        variants = [IndexVariant(stride=int(2 ** (c // 4)), pole=poles[c % 4]) for c in uniq]
        rs = RenderSet(keys, ids, variants, error_px=np.concatenate(out_err))
    rs.stats.update(
        {
            "tiles_culled_frustum": culled_f,
            "tiles_culled_horizon": culled_h,
            "lod_ms": (time.perf_counter() - t0) * 1e3,
        }
    )
    return rs


class ChunkedSseProvider(LodProvider):
    """The built-in default LOD provider (see the module docstring)."""

    name = "chunked-sse"
    label = "Chunked (screen-space error)"
    settings = (
        Setting(
            "texel_px",
            "float",
            1.5,
            min=0.5,
            max=8.0,
            label="texel size (pixels)",
            help="refine while a texel of the tile textures covers more pixels",
        ),
        Setting("max_tiles", "int", 600, min=16, max=2000, label="tile budget"),
    )

    def __init__(self, context=None) -> None:
        super().__init__(context)
        self._cache_key: tuple | None = None
        self._cache: RenderSet | None = None

    def reset(self) -> None:
        self._cache_key = self._cache = None

    def select(self, view: ViewState, terrain: TerrainStack) -> RenderSet:
        if terrain is None or not terrain.layers:
            return RenderSet.empty()
        # A repaint with an unchanged view (window expose, overlay redraw) reuses the last
        # selection; any camera move, setting or layer change recomputes it.
        key = (
            view.eye.tobytes(),
            view.rotation.tobytes(),
            view.viewport,
            view.fovy_deg,
            view.tau_px,
            view.exaggeration,
            view.displace is None,
            id(terrain),
            terrain.version,
            tuple(sorted(self.values.items())),
        )
        if key == self._cache_key and self._cache is not None and view.displace is None:
            rs = self._cache
            rs.stats["lod_ms"] = 0.0
            rs.stats["lod_cached"] = 1.0
            return rs
        v = self.values
        rs = select_tiles(
            view,
            terrain,
            # tau comes with the view (ViewState.tau_px): one threshold for every provider.
            ChunkedSettings(texel_px=v["texel_px"], max_tiles=v["max_tiles"]),
        )
        self._cache_key, self._cache = key, rs
        return rs
