"""`FixedLevelProvider`: every visible tile at one quadtree level, at full resolution.

The simplest LOD provider that is still useful to compare against: no refinement by error,
only culling. Visibility is decided level by level from the two level-0 tiles down, so a tile
hidden by the frustum or the horizon never has its children tested (the work is bounded by
the visible tiles, not by the 2^(2L+1) tiles of the level).

Under a displacement (a tool's ``view.displace``, e.g. the terrain collapse) culling tests the
displaced bounding points. No crack can open along the collapse's fold lines: every tile is
drawn at the same level and at stride 1 (already the finest index buffer), so neighbours share
every edge vertex and the displaced mesh stays closed; a long edge across a fold is drawn as a
chord (the fold looks coarse at a coarse level), but both sides draw the same chord.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from globeview.plugins.api import LodProvider, Setting
from globeview.render.culling import (
    bounding_distance,
    frustum_visible,
    horizon_visible,
    tile_bounding_points,
)
from globeview.render.render_set import RenderSet
from globeview.render.tile_indices import IndexVariant
from globeview.render.view_state import ViewState
from globeview.terrain.quadtree import level_shape, tile_bounds_arrays

#: Height range (m) assumed for tiles when no terrain is open or it has no data there:
#: deep-ocean floor to above Everest, so culling stays conservative.
FALLBACK_HMIN = -11000.0
FALLBACK_HMAX = 9000.0

_VARIANTS = [
    IndexVariant(stride=1, skirts=True, pole=None),
    IndexVariant(stride=1, skirts=True, pole="north"),
    IndexVariant(stride=1, skirts=True, pole="south"),
]


class FixedLevelProvider(LodProvider):
    """Draws all tiles of quadtree level ``level`` that pass frustum and horizon culling."""

    name = "fixed-level"
    label = "Fixed level"
    settings = (
        Setting("level", "int", 3, min=0, max=12, label="Level", help="Quadtree level drawn."),
        Setting(
            "max_tiles",
            "int",
            20000,
            min=1,
            max=1_000_000,
            label="Tile budget",
            help="Most tiles drawn per frame; the nearest are kept.",
        ),
    )

    def _height_range(
        self, terrain: Any, level: int, x: np.ndarray, y: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(hmin, hmax) in metres of each tile: from the terrain's metadata where it has
        data, else the conservative fallback range."""
        hmin = np.full(len(x), FALLBACK_HMIN)
        hmax = np.full(len(x), FALLBACK_HMAX)
        if terrain is not None and len(x):
            meta = terrain.metadata(level, x, y)
            hmin = np.where(meta.covered, meta.hmin, hmin)
            hmax = np.where(meta.covered, meta.hmax, hmax)
        return hmin, hmax

    def _visible(
        self, view: ViewState, terrain: Any, level: int, x: np.ndarray, y: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Masks (frustum-visible, horizon-visible) and the bounding points and margins."""
        w, s, e, n = tile_bounds_arrays(level, x, y)
        hmin, hmax = self._height_range(terrain, level, x, y)
        pts, margin = tile_bounding_points(w, s, e, n, hmin, hmax, view.exaggeration, view.displace)
        in_frustum = frustum_visible(view, pts, margin)
        above_horizon = horizon_visible(view, w, s, e, n, hmax, view.exaggeration)
        return in_frustum, above_horizon, pts, margin

    def select(self, view: ViewState, terrain: Any) -> RenderSet:
        """The visible tiles of the configured level, nearest first, within the budget.

        Tiles in the first (last) row of the level touch the north (south) pole and use the
        pole-fan variant; level 0's single row touches both and uses the north fan (its south
        edge draws as degenerate triangles, which show nothing).
        """
        target = int(self.values["level"])
        budget = int(self.values["max_tiles"])
        x = np.arange(level_shape(0)[0], dtype=np.int64)
        y = np.zeros_like(x)
        culled_frustum = culled_horizon = 0
        for level in range(target + 1):
            in_frustum, above_horizon, pts, margin = self._visible(view, terrain, level, x, y)
            culled_frustum += int(np.count_nonzero(~in_frustum))
            culled_horizon += int(np.count_nonzero(in_frustum & ~above_horizon))
            keep = in_frustum & above_horizon
            x, y, pts, margin = x[keep], y[keep], pts[keep], margin[keep]
            if level < target:
                # The four children of each survivor: (2x + dx, 2y + dy).
                x = (2 * x[:, None] + np.array([0, 1, 0, 1])).reshape(-1)
                y = (2 * y[:, None] + np.array([0, 0, 1, 1])).reshape(-1)

        dist = bounding_distance(view, pts, margin)
        n_visible = len(dist)
        order = np.argsort(dist, kind="stable")[:budget]
        x, y, dist = x[order], y[order], dist[order]
        nrows = level_shape(target)[1]
        variant_ids = np.where(y == 0, 1, np.where(y == nrows - 1, 2, 0))

        error_px = None
        if terrain is not None and len(x):
            err_m = terrain.metadata(target, x, y).stride_error[:, 0]
            error_px = err_m * view.exaggeration * view.sse_factor / dist
        keys = np.stack([np.full_like(x, target), x, y], axis=1)
        return RenderSet(
            keys=keys,
            variant_ids=variant_ids,
            variants=list(_VARIANTS),
            error_px=error_px,
            stats={
                "tiles_culled_frustum": float(culled_frustum),
                "tiles_culled_horizon": float(culled_horizon),
                "tiles_over_budget": float(max(n_visible - budget, 0)),
            },
        )
