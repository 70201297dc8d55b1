"""`chunked-sse`: the default LOD provider, chunked screen-space-error selection (TREND §4.2 /
Cesium style), a policy on the shared quadtree traversal.

The algorithm is `ScreenSpaceErrorPolicy` (globeview.lod.sse_policy, public through the plugin
API because `quadtree-clod` chooses its tiles the same way):

1. the shared traversal (`traverse`) culls candidates against the frustum and the ellipsoid
   horizon, level by level, with camera-independent tile facts cached per terrain;
2. each tile's geometric error is projected to pixels, ``e * K / d`` with K = viewport height
   / (2 tan(fovy/2)) and d a lower bound of the distance to the tile;
3. refine (replace by its four children) when that exceeds tau and finer data exists, or
   when the tile's texels would be magnified beyond ``texel_px`` pixels and finer data exists;
4. draw the others with the coarsest index stride whose error still projects below tau
   (TREND's per-block resolution pyramid, applied to the whole tile).

The error of a tile drawn with stride s is its height error (from the tile store) times the
vertical exaggeration plus the chord sag of the curved ellipsoid between vertices s nodes
apart: flat triangles cut under a curved globe, and at globe scale that dominates.

With ``min_triangles`` (the default) the walk also visits the children of tiles that could be
drawn cheaper, and the tiles drawn are the cheapest cut of what it visited
(`globeview.lod.cheapest_cut`): the fewest triangles meeting tau, and never more triangles
for a larger tau. Without it, a tile whose nearest corner needs stride 1 is drawn whole at
stride 1 (6.6x quadtree-clod's triangles at the White Mountains view, and a tau ladder that
went 2 500 -> 10 928 triangles at the old Crater Lake view as tau rose from 1 to 2 px).

Cracks between tiles drawn at different levels or strides are hidden by skirts.

This module holds the plugin glue only: a `PolicyProvider` naming the policy and its
settings (the policy takes them as keyword arguments). `PolicyProvider` reuses the last
selection while the view is unchanged.
"""

from __future__ import annotations

from globeview.plugins.api import (
    TEXEL_SIZE,
    TILE_BUDGET,
    PolicyProvider,
    ScreenSpaceErrorPolicy,
    Setting,
)


class ChunkedSseProvider(PolicyProvider):
    """The built-in default LOD provider (see the module docstring)."""

    name = "chunked-sse"
    label = "Chunked (screen-space error)"
    # tau comes with the view (ViewState.tau_px): one threshold for every provider.
    policy = ScreenSpaceErrorPolicy
    settings = (
        TEXEL_SIZE,
        TILE_BUDGET,
        Setting(
            "min_triangles",
            "bool",
            True,
            label="fewest triangles",
            help="draw the cheapest set of tiles and strides within tau (children where they "
            "save triangles); off: refine only tiles over tau",
        ),
    )
