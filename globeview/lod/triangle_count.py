"""How many triangles a candidate selection would draw (plugin API 1.2: `triangle_count`).

A provider trading detail for speed (a triangle budget, a "cheapest cut" of its own) needs
the count before it returns a set. It is the frame stats' own count: the renderer draws each
tile's index variant (or custom index list) and reports ``triangles`` as
`RenderSet.index_counts` summed over three (`GlobeRenderer.draw_terrain`), skirts and pole
fans included.
"""

from __future__ import annotations

from globeview.lod.candidates import Selection
from globeview.lod.render_set import RenderSet
from globeview.lod.stitching import render_set_by_stride

__all__ = ["DEFAULT_TILE_SIZE", "triangle_count"]

#: Nodes per tile side of the stores globeview builds (`TerrainStack.tile_size`).
DEFAULT_TILE_SIZE = 65


def triangle_count(candidate: RenderSet | Selection, tile_size: int = DEFAULT_TILE_SIZE) -> int:
    """Triangles the renderer would draw for ``candidate`` over tiles of ``tile_size`` nodes
    per side (pass ``terrain.tile_size``): the number the frame's ``triangles`` stat gives,
    but for the default provider's sets (``block_tau_px`` set), whose frames draw at most this
    many: the renderer stitches their same-level tile edges instead of skirting them and
    draws blocks at their own strides (issue #27).

    A `RenderSet` counts as it is (its variants and custom index lists). A `Selection` (what
    a policy's ``render_set`` receives) counts as the default policy draws it: each tile at
    its stride with skirts and pole fans, no stitching (`LodPolicy.render_set` without
    ``stitch``); a policy building its own set counts that set instead. Raises ValueError
    for a stride that does not divide the tile's cells."""
    if isinstance(candidate, Selection):
        candidate = render_set_by_stride(candidate.keys, candidate.stride_idx, candidate.error_px)
    if not isinstance(candidate, RenderSet):
        raise TypeError(
            f"triangle_count needs a RenderSet or a Selection, not {type(candidate).__name__}"
        )
    return candidate.triangles(tile_size)
