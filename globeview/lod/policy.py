"""The narrow interface an LOD provider implements to steer the shared quadtree traversal
(Cesium's ``QuadtreeTileProvider`` beside its ``QuadtreePrimitive``). The default
screen-space-error policy built on it is `globeview.lod.sse_policy.ScreenSpaceErrorPolicy`.

`globeview.lod.traversal.traverse` walks the quadtree, culls, caches and budgets; a policy
only answers, for one level's visible tiles (`TileCandidates`, vectorised over N tiles):

- `LodPolicy.error_px`: what error each tile has, in pixels, at each index stride;
- `LodPolicy.refine`: which tiles to replace by their four children;
- `LodPolicy.stride`: for the tiles drawn, which index stride;
- optionally `LodPolicy.cull` (its own culling on top of the frustum and horizon),
  `LodPolicy.max_tiles` and `LodPolicy.priority` (a tile budget: the worst refine first),
  `LodPolicy.max_level`, `LodPolicy.stitch` or `LodPolicy.render_set` (index variants,
  stitching) and `LodPolicy.frame_stats`.

A policy whose answers depend only on each tile's own facts and the view (no values handed
from one level to the next) may say so with `LodPolicy.per_tile`: with a selection state
(`traverse(..., state=)`, which `PolicyProvider` keeps) the traversal then evaluates last
frame's whole candidate tree in one pass (`globeview.lod.flat_walk`) instead of walking it
level by level, with the same result.

A policy takes its settings as keyword arguments, so that a new LOD provider is a policy
plus a manifest (`globeview.plugins.api.PolicyProvider` builds the policy from the
provider's setting values each frame)::

    class CoarsePolicy(LodPolicy):
        def __init__(self, factor=4.0):
            super().__init__()
            self.factor = factor

        def refine(self, tiles, error_px):
            return (error_px[:, 0] > self.factor * self.tau_px) & tiles.has_finer

    class CoarseProvider(PolicyProvider):
        policy = CoarsePolicy
        settings = (Setting("factor", "float", 4.0, min=1.0, max=64.0),)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from globeview.lod.candidates import MAX_LEVEL, Selection, TileCandidates, TreeRows
from globeview.lod.render_set import RenderSet
from globeview.lod.stitching import render_set_by_stride, render_set_from_tiles
from globeview.lod.view_state import ViewState
from globeview.terrain.compose.metadata import N_STRIDES
from globeview.terrain.compose.stack import TerrainStack

#: Weights picking the coarsest acceptable stride (`coarsest_stride_within`).
_STRIDE_RANK = np.arange(1, N_STRIDES + 1)


def coarsest_stride_within(error_px: np.ndarray, tau_px: float) -> np.ndarray:
    """(N,) index of the coarsest stride whose projected error (``error_px`` (N, N_STRIDES),
    pixels) is within ``tau_px``, or 0 (stride 1) where none is."""
    # The highest rank among the acceptable strides, minus one, or 0.
    return np.maximum((error_px <= tau_px) * _STRIDE_RANK, 1).max(axis=1) - 1


class LodPolicy:
    """What a provider decides in the shared traversal (module docstring). The defaults are
    plain screen-space error: refine while the error at stride 1 exceeds ``tau_px`` and finer
    data exists, draw with the coarsest stride within ``tau_px``, no budget.

    Attributes:
        max_level: deepest quadtree level to visit (at most `candidates.MAX_LEVEL`).
        max_tiles: the tile budget (None: none; `render_set.MAX_TILES` holds either way).
        per_tile: the policy's `cull`, `error_px`, `refine`, `priority` and `stride` answer
            for each tile from that tile's own facts and the view alone (nothing kept in
            ``scratch`` across levels, no state changed per level), so they may be asked
            about tiles of several levels at once (`TileCandidates.flat`: ``tiles.level``
            an array) and about tiles the walk will not reach. With a selection state the
            traversal then uses the flat walk (`globeview.lod.flat_walk`): the same tiles,
            strides and errors, a fraction of the numpy calls. Default False (the level
            walk, for any policy).
        stitch: whether the default `render_set` stitches same-level neighbours drawn at
            different strides (`render_set_from_tiles`) instead of leaving the cracks to the
            skirts (`render_set_by_stride`).
        tau_px: the screen-space error threshold (pixels) of this frame; `begin` sets it
            from the view unless the policy was given one (``tau_px`` argument).
        view, terrain: the frame's, set by `begin`.
    """

    max_level: int = MAX_LEVEL
    max_tiles: int | None = None
    stitch: bool = False
    per_tile: bool = False

    def __init__(self, tau_px: float | None = None) -> None:
        self._tau_override = tau_px
        self.tau_px = 2.0
        self.view: ViewState | None = None
        self.terrain: TerrainStack | None = None

    # -- per frame --------------------------------------------------------------------------
    def begin(self, view: ViewState, terrain: TerrainStack) -> None:
        """Start a frame: keep the view and terrain and compute per-frame constants."""
        self.view, self.terrain = view, terrain
        tau = self._tau_override
        self.tau_px = float(tau if tau is not None else view.tau_px)

    def frame_stats(self) -> dict[str, Any]:
        """Counters of the frame (numbers) for the render set's stats."""
        return {}

    def stop_level(self, rows: TreeRows) -> int | None:
        """`per_tile` policies on the flat walk: the level from which a level-by-level walk
        of ``rows`` (every candidate row: ``visited`` and ``refine`` as if nothing stopped
        it) would refine nothing more, e.g. a bound on the tiles visited; None: none (the
        default). Asked after each growth of the tree, the last answer is the frame's; what
        it decides must depend only on the rows of that level and above."""
        return None

    # -- per level ------------------------------------------------------------------------------
    def cull(self, tiles: TileCandidates) -> np.ndarray | None:
        """(N,) bool: which of the visible tiles to keep (None: all)."""
        return None

    def error_px(self, tiles: TileCandidates) -> np.ndarray:
        """(N, N_STRIDES) projected error (pixels) of drawing each tile at each stride."""
        return tiles.err_m * tiles.px_per_m[:, None]

    def refine(self, tiles: TileCandidates, error_px: np.ndarray) -> np.ndarray:
        """(N,) bool: which tiles to replace by their children. Asked at every level,
        ``max_level`` included (where the answer is ignored: nothing deeper is visited), so
        what it leaves in ``tiles.scratch`` is always there for `stride`."""
        return (error_px[:, 0] > self.tau_px) & tiles.has_finer

    def priority(self, tiles: TileCandidates, error_px: np.ndarray) -> np.ndarray:
        """(N,) how badly each tile wants refining (the budget refines the largest first)."""
        return error_px[:, 0]

    def stride(self, tiles: TileCandidates, error_px: np.ndarray, index: np.ndarray) -> np.ndarray:
        """(M,) stride index (stride = 2**index) of the drawn tiles, rows ``index`` of
        ``tiles``; ``error_px`` is already those rows (M, N_STRIDES)."""
        return coarsest_stride_within(error_px, self.tau_px)

    # -- the result -------------------------------------------------------------------------------
    def render_set(self, selection: Selection, size: int) -> RenderSet:
        """The `RenderSet` of what the traversal drew (default: skirts and pole fans, and
        with ``stitch`` same-level borders stitched; without, one index variant per stride
        and pole, cracks hidden by the skirts)."""
        if self.stitch:
            return render_set_from_tiles(
                selection.keys, selection.stride_idx, selection.error_px, size, True
            )
        return render_set_by_stride(selection.keys, selection.stride_idx, selection.error_px)
