"""Two LOD providers written against the plugin API alone (`globeview.plugins.api`).

- `FixedLevelProvider` (``fixed-level``): every visible tile at one quadtree level, at full
  resolution. The simplest provider that is still useful to compare against: no refinement
  by error, only culling. Visibility is decided level by level from the two level-0 tiles
  down, so a tile hidden by the frustum or the horizon never has its children tested (the
  work is bounded by the visible tiles, not by the 2^(2L+1) tiles of the level).
- `CappedProvider` (``capped-sse``): wraps the default provider, chunked-sse, through
  `PluginContext.lod_provider` and caps how deep it refines: tiles finer than ``max_level``
  are replaced by their ancestor at that level. It shows delegation: the host runs
  chunked-sse isolated, so a bug there fails chunked-sse, not this plugin.

Under a displacement (a tool's ``view.displace``, e.g. the terrain collapse) fixed-level's
culling tests the displaced bounding points. No crack can open along the collapse's fold
lines: every tile is drawn at the same level and at stride 1 (already the finest index
buffer), so neighbours share every edge vertex and the displaced mesh stays closed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from globeview.plugins.api import (
    IndexVariant,
    LodProvider,
    RenderSet,
    Setting,
    ViewState,
    bounding_distance,
    frustum_visible,
    horizon_visible,
    level_shape,
    tile_bounding_points,
    tile_bounds_arrays,
)

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


def cap_render_set(rs: RenderSet, max_level: int) -> tuple[RenderSet, int]:
    """``rs`` with every tile deeper than ``max_level`` replaced by its ancestor at
    ``max_level`` (each ancestor once), and how many tiles were replaced.

    A RenderSet is a cut of the quadtree (no tile together with one of its ancestors), so
    the ancestors overlap nothing that stays. They are drawn at full resolution with skirts
    (stride 1: the finest, so never coarser than what they replace) and the pole fans of
    their row; their ``error_px`` is the worst of the tiles they replace times 2 per level
    climbed (a level coarser roughly doubles the geometric error). The input is not changed
    (it may be the delegate's cached set).
    """
    keys = rs.keys
    deep = keys[:, 0] > max_level
    n_deep = int(np.count_nonzero(deep))
    if n_deep == 0:
        return rs, 0
    shift = keys[deep, 0] - max_level
    anc = np.stack(
        [np.full(n_deep, max_level), keys[deep, 1] >> shift, keys[deep, 2] >> shift], axis=1
    )
    uniq, group = np.unique(anc, axis=0, return_inverse=True)
    group = group.reshape(-1)

    keep = ~deep
    variants = list(rs.variants)
    nrows = 1 << max_level
    poles = np.where(
        nrows == 1,
        3,
        np.where(uniq[:, 2] == 0, 1, np.where(uniq[:, 2] == nrows - 1, 2, 0)),
    )
    names = (None, "north", "south", "both")
    new_ids = np.empty(len(uniq), dtype=np.int64)
    for code in np.unique(poles):
        variant = IndexVariant(stride=1, skirts=True, pole=names[int(code)])
        if variant not in variants:
            variants.append(variant)
        new_ids[poles == code] = variants.index(variant)

    error_px = None
    if rs.error_px is not None:
        worst = np.zeros(len(uniq))
        np.maximum.at(worst, group, np.asarray(rs.error_px, np.float64)[deep] * 2.0**shift)
        error_px = np.concatenate([np.asarray(rs.error_px, np.float64)[keep], worst])
    # Tiles the delegate triangulated itself keep their lists, renumbered to their new rows.
    new_row = np.cumsum(keep) - 1
    custom = {int(new_row[r]): idx for r, idx in rs.custom_indices.items() if keep[int(r)]}
    capped = RenderSet(
        keys=np.concatenate([keys[keep], uniq]),
        variant_ids=np.concatenate([rs.variant_ids[keep], new_ids]),
        variants=variants,
        custom_indices=custom,
        error_px=error_px,
        stats=dict(rs.stats),
    )
    return capped, n_deep


class CappedProvider(LodProvider):
    """chunked-sse, refining no deeper than ``max_level`` (delegation through the API)."""

    name = "capped-sse"
    label = "Chunked, capped level"
    settings = (
        Setting(
            "max_level",
            "int",
            8,
            min=0,
            max=22,
            label="Deepest level",
            help="Quadtree level beyond which tiles are not refined (level 8: ~700 m tiles).",
        ),
    )

    def __init__(self, context=None) -> None:
        super().__init__(context)
        # Looked up once; each select asks the host again, so a later failure is noticed.
        self._inner = context.lod_provider("chunked-sse") if context is not None else None

    def select(self, view: ViewState, terrain: Any) -> RenderSet:
        if self._inner is None:  # a bare object (no host): nothing to delegate to
            return RenderSet.empty()
        rs = self._inner.select(view, terrain)  # ProviderUnavailable fails this frame
        capped, replaced = cap_render_set(rs, int(self.values["max_level"]))
        capped.stats["tiles_capped"] = float(replaced)
        return capped

    def reset(self) -> None:
        if self._inner is not None:
            self._inner.reset()
