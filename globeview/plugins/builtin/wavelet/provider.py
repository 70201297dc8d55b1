"""`wavelet`: M-band wavelet LOD after Zhang et al., "Effective techniques for interactive
rendering of global terrain surfaces", §V, vectorised over quadtree tiles.

Zhang partition the visible terrain into tiles by distance, pick for each tile a wavelet
approximation (coarse to fine) and triangulate it hierarchically "until the height error is
smaller than the given height error", with two errors: a *static* error (roughness: rough
areas keep more detail, flat ones are merged) and a *dynamic* error (distance: far regions get
fewer triangles). Here:

- **Tiles and wavelet levels.** The tile store's pyramid *is* a dyadic wavelet approximation:
  quadtree level L of a tile is the approximation a_j with j = (finest level - L), and each
  tile stores the geometric error (metres, max |height - full resolution|) of that
  approximation drawn at index strides 1..64 (`TerrainStack.metadata(...).stride_error`).
- **Level choice** (walk from the root, all candidates at once): a tile is split into its
  children when finer data exists and both
  - its *static* error, the stored error of its approximation (stride 1), exceeds the
    roughness floor ``static_m`` (below it the tile is flat: further wavelet levels add
    nothing visible at any distance), and
  - its *dynamic* error, that error x exaggeration projected to pixels, ``e K / d`` with
    K = viewport height / (2 tan(fovy/2)) and d a lower bound of the eye-tile distance,
    exceeds tau;
  or when the chord sag of the curved globe between its nodes projects beyond tau (geometry
  the flat approximation cannot show, independent of the data); or when, rough with finer
  data, no stride coarser than 1 meets tau (the tile would need its full grid: its children
  draw it with no more triangles, far fewer where the level approximates poorly, and the
  count then never grows with tau).
- **M-band.** With M bands per step a wavelet level divides the resolution by M. The store
  holds dyadic levels only, so: M = 2 may stop at every level; M = 4 = 2^2 only at every
  second level (a split jumps two quadtree levels: 16 children); M = 3 has no dyadic
  counterpart, so a tile may stop only at the dyadic level nearest to, and at least as fine
  as, an exact 3-band level: levels ceil(k log2 3) = 0, 2, 4, 5, 7, 8, 10, ... This keeps the
  3-band *resolution ladder* (each step at least x3 finer), not the 3-band *filter*: the
  filtered heights are the store's dyadic approximations. (`globeview.terrain.ingest.mband` can
  compute true 3-band approximations of a tile, but only per tile from its heights — a
  Python loop per tile per frame, which ``select`` must not do.)
- **Triangulation** ("until the height error is below the given error"): the accepted tile is
  drawn with the coarsest index stride whose error (height error x exaggeration + chord sag)
  projects within tau; flat tiles (static error below the floor) take the coarsest stride
  whose *height* error is still below the floor and whose sag projects within tau.
- **Displacement** (a tool's ``view.displace``, e.g. the terrain collapse): culling uses the
  displaced bounding points, and the bend of the displacement over a tile (the collapse's
  fold lines; `culling.displacement_bend_m`, scaled to each stride's edge length) is
  added to the geometry error like the chord sag: a tile whose bend projects beyond tau at
  stride 1 splits, and a stride is only as coarse as keeps it within tau, so long edges
  never cut across a fold and no gap opens between tiles. Nothing changes without one.
- **The walk** is the shared quadtree traversal (`traverse`: culling, the per-terrain tile
  cache, the tile budget); this module is Zhang's policy on it (`ZhangWaveletPolicy`).
- **Crack sewing** (Zhang Fig. 4): same-level neighbours of different strides are stitched
  (`IndexVariant.edge_strides`: the finer tile's edge uses the coarser one's vertices);
  neighbours of different levels meet behind skirts (their heights differ: different wavelet
  approximations).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from globeview.plugins.api import (
    MAX_LEVEL,
    MAX_TILES,
    N_STRIDES,
    TAU_OVERRIDE,
    TILE_BUDGET,
    LodPolicy,
    PolicyProvider,
    Setting,
    TerrainStack,
    TileCandidates,
    ViewState,
)


def stop_levels(m: int, max_level: int = MAX_LEVEL) -> np.ndarray:
    """(max_level + 1,) bool: the quadtree levels where an M-band ladder may stop.

    M = 2: every level; M = 4: every second level; other M: the dyadic levels
    ceil(k log2 M), the nearest at least as fine as the exact M-band levels."""
    ok = np.zeros(max_level + 1, dtype=bool)
    ok[0] = True
    step = math.log2(m)
    k = 1
    while True:
        lv = math.ceil(k * step - 1e-9)
        if lv > max_level:
            break
        ok[lv] = True
        k += 1
    ok[max_level] = True  # the walk's end is always a stop
    return ok


class ZhangWaveletPolicy(LodPolicy):
    """Zhang §V level and stride choice as a policy on the shared traversal (module
    docstring): refine by static (roughness) and dynamic (distance) error, the chord sag and
    the M-band ladder (`refine`); draw with the coarsest stride within tau, flat tiles within
    the roughness floor (`stride`); same-level borders sewn.

    Args (the provider's settings): m: bands per wavelet step (2, 3 or 4; a choice's text is
    taken too); static_m: the roughness floor (m); tau_px: the screen error threshold (px;
    None or 0: the view's); max_tiles: the tile budget; stitch: sew same-level neighbours.
    """

    def __init__(
        self,
        m: int | str = 2,
        static_m: float = 2.0,
        tau_px: float | None = None,
        max_tiles: int = 1500,
        stitch: bool = True,
    ) -> None:
        super().__init__(tau_px or None)
        self.m, self.static_m = int(m), float(static_m)
        self.max_tiles, self.stitch = max_tiles, stitch
        self.stops = stop_levels(self.m)
        self.flat_tiles = 0

    def begin(self, view: ViewState, terrain: TerrainStack) -> None:
        super().begin(view, terrain)
        self.max_stride_idx = min(N_STRIDES - 1, int(math.log2(terrain.tile_size - 1)))
        self.flat_tiles = 0

    def refine(self, tiles: TileCandidates, error_px: np.ndarray) -> np.ndarray:
        tau, exag, level = self.tau_px, tiles.view.exaggeration, tiles.level
        herr = tiles.height_err_m  # (N, 7) height error of the approximation, metres
        px_per_m = tiles.px_per_m
        static = herr[:, 0]
        dynamic = static * exag * px_per_m
        # The geometry error at stride 1: the chord sag plus the displacement's bend (fold
        # lines), i.e. what `TileCandidates.err_m` adds to the exaggerated height error.
        sag_px = (tiles.err_m[:, 0] - static * exag) * px_per_m
        rough = static > self.static_m
        finer = tiles.has_finer
        want = (rough & (dynamic > tau) & finer) | (sag_px > tau)
        # A tile whose every coarser stride misses tau needs its full grid at this level: its
        # children draw the same surface with no more triangles (each stride of a level is
        # about the density of the level above), and where the level's approximation is
        # poor - e.g. a layer's border band, a ramp only a few nodes wide here - with far
        # fewer. Refining it keeps the count from growing as tau grows.
        full = ~np.any((error_px <= tau)[:, 1 : self.max_stride_idx + 1], axis=1)
        want |= full & finer & rough
        # At a level that is no stop of the M-band ladder every survivor goes on (children
        # of a tile that stopped at a ladder level and still wanted detail are forced down to
        # the next stop: that is one M-band step).
        forced = not self.stops[level]
        tiles.scratch["priority"] = np.maximum(dynamic, sag_px) + 1e9 * forced
        return want | forced

    def priority(self, tiles: TileCandidates, error_px: np.ndarray) -> np.ndarray:
        return tiles.scratch["priority"]

    def stride(self, tiles: TileCandidates, error_px: np.ndarray, index: np.ndarray) -> np.ndarray:
        # Coarsest stride whose total error projects within tau; flat tiles also keep their
        # height error within the roughness floor (they are flat, not invisible).
        tau, exag = self.tau_px, tiles.view.exaggeration
        herr = tiles.height_err_m.take(index, axis=0)
        total = tiles.err_m.take(index, axis=0)
        px_per_m = tiles.px_per_m.take(index)
        ok = error_px <= tau
        flat = ~(herr[:, 0] > self.static_m)
        sag_ok = (total - herr * exag) * px_per_m[:, None] <= tau
        ok = np.where(flat[:, None], ok | (sag_ok & (herr <= self.static_m)), ok)
        ok[:, self.max_stride_idx + 1 :] = False
        self.flat_tiles += int(np.count_nonzero(flat))
        return np.where(ok.any(axis=1), N_STRIDES - 1 - np.argmax(ok[:, ::-1], axis=1), 0)

    def frame_stats(self) -> dict[str, Any]:
        return {"tiles_flat": self.flat_tiles}


class WaveletProvider(PolicyProvider):
    """Zhang et al.'s M-band wavelet LOD (see the module docstring)."""

    name = "wavelet"
    label = "M-band wavelet (Zhang)"
    policy = ZhangWaveletPolicy
    settings = (
        Setting("m", "choice", "2", choices=("2", "3", "4"), label="M (bands)",
                help="wavelet bands per level step: resolution divides by M per step."),
        Setting("static_m", "float", 2.0, min=0.0, max=1000.0, label="static error (m)",
                help="roughness floor in metres: tiles whose approximation error is below it "
                "count as flat and are not refined for detail."),
        TAU_OVERRIDE,
        replace(TILE_BUDGET, default=1500, max=MAX_TILES),
    )  # fmt: skip
