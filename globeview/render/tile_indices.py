"""Index buffers over a tile's vertex layout (see tile_mesh.py), and the shared pool of them.

Every tile has the same vertex layout, so an index *variant* — a triangulation of the grid at
some stride, with or without skirts, with a pole fan, with edges stitched to coarser
neighbours — is built once and shared by all tiles. LOD providers choose a variant per tile;
the renderer draws all tiles in one multi-draw call with per-draw base vertices.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Pole = Literal["north", "south", "both"] | None


@dataclass(frozen=True)
class IndexVariant:
    """Which triangulation of a tile grid to draw.

    stride: node step of the grid (1 = every node; a power of two up to size - 1).
    skirts: add skirt triangles along the non-pole edges.
    pole: 'north', 'south' or 'both' (a level-0 tile spans pole to pole) if that edge is a
        pole (its nodes are one point): the first or last row of cells becomes a triangle fan
        around the pole (Zhang et al. §III).
    edge_strides: optional (north, south, west, east) strides of the edges, each a multiple
        of ``stride``: an edge drawn at a coarser stride matches a coarser neighbour exactly
        (TREND §4.2.3 / Rishe §3.3 border stitching) instead of relying on skirts.
    """

    stride: int = 1
    skirts: bool = True
    pole: Pole = None
    edge_strides: tuple[int, int, int, int] | None = None


def grid_indices(size: int, variant: IndexVariant) -> np.ndarray:
    """uint32 triangle-list indices for ``variant`` over a tile of ``size`` nodes per side."""
    s = variant.stride
    n = size - 1
    if s < 1 or n % s:
        raise ValueError(f"stride {s} does not divide the tile's {n} cells")
    r = np.arange(0, n, s)
    rr, cc = np.meshgrid(r, r, indexing="ij")
    a = rr * size + cc
    b = a + s
    c = a + s * size
    d = c + s
    tri1 = np.stack([a, c, b], axis=-1)
    tri2 = np.stack([b, c, d], axis=-1)

    keep1 = np.ones(rr.shape, dtype=bool)
    keep2 = np.ones(rr.shape, dtype=bool)
    if variant.pole in ("north", "both"):
        # Row 0 is the pole: a and b coincide; keep (pole, c, d) as a fan around node 0.
        first = rr == 0
        tri2[first] = np.stack([np.zeros_like(c[first]), c[first], d[first]], axis=-1)
        keep1 &= ~first
    if variant.pole in ("south", "both"):
        last = rr == n - s
        tri1[last] = np.stack([a[last], np.full_like(a[last], n * size), b[last]], axis=-1)
        keep2 &= ~last

    if variant.edge_strides is not None:
        tri_list, keep1, keep2 = _stitch_edges(size, variant, tri1, tri2, keep1, keep2, rr, cc)
        parts = [tri1[keep1], tri2[keep2], *tri_list]
    else:
        parts = [tri1[keep1], tri2[keep2]]

    if variant.skirts:
        parts.extend(_skirt_triangles(size, variant))
    return np.concatenate([p.reshape(-1, 3) for p in parts]).astype(np.uint32).reshape(-1)


def _skirt_triangles(size: int, variant: IndexVariant) -> list[np.ndarray]:
    """Two triangles per edge segment joining the edge nodes to their skirt copies."""
    n = size - 1
    base = size * size
    edge_nodes = {
        "north": np.arange(size),
        "south": n * size + np.arange(size),
        "west": np.arange(size) * size,
        "east": np.arange(size) * size + n,
    }
    strides = variant.edge_strides or (variant.stride,) * 4
    out = []
    for k, (name, nodes) in enumerate(edge_nodes.items()):
        if variant.pole == name or (variant.pole == "both" and name in ("north", "south")):
            continue
        s = strides[k]
        i = np.arange(0, n, s)
        top0, top1 = nodes[i], nodes[i + s]
        bot0, bot1 = base + k * size + i, base + k * size + i + s
        out.append(np.stack([top0, bot0, top1], axis=-1))
        out.append(np.stack([top1, bot0, bot1], axis=-1))
    return out


def _stitch_edges(size, variant, tri1, tri2, keep1, keep2, rr, cc):
    """Replace the border cells of edges drawn at a coarser stride by fans that use only the
    coarse edge's nodes, so the edge matches the coarser neighbour with no T-junction."""
    s = variant.stride
    n = size - 1
    north, south, west, east = variant.edge_strides
    extra = []
    border = np.zeros(rr.shape, dtype=bool)
    for es, mask_fn in (
        (north, lambda: rr == 0),
        (south, lambda: rr == n - s),
        (west, lambda: cc == 0),
        (east, lambda: cc == n - s),
    ):
        if es > s:
            border |= mask_fn()
    if not border.any():
        return extra, keep1, keep2
    keep1 = keep1 & ~border
    keep2 = keep2 & ~border
    # Re-triangulate the ring of border cells: every border cell becomes a fan from its inner
    # corner(s) to the nodes of the coarse edge it touches. Simplest exact construction: for
    # each border cell, snap its edge-lying corners to the coarse edge's nodes.
    a = rr * size + cc
    b = a + s
    c = a + s * size
    d = c + s
    cells = np.stack([a, b, c, d], axis=-1)[border]
    r0 = rr[border]
    c0 = cc[border]
    corners_r = np.stack([r0, r0, r0 + s, r0 + s], axis=-1)
    corners_c = np.stack([c0, c0 + s, c0, c0 + s], axis=-1)
    snapped_r = corners_r.copy()
    snapped_c = corners_c.copy()
    for es, on_edge, axis_is_col in (
        (north, corners_r == 0, True),
        (south, corners_r == n, True),
        (west, corners_c == 0, False),
        (east, corners_c == n, False),
    ):
        if es <= s:
            continue
        if axis_is_col:
            snapped_c = np.where(on_edge, (snapped_c // es) * es, snapped_c)
        else:
            snapped_r = np.where(on_edge, (snapped_r // es) * es, snapped_r)
    snapped = snapped_r * size + snapped_c
    del cells
    t1 = np.stack([snapped[:, 0], snapped[:, 2], snapped[:, 1]], axis=-1)
    t2 = np.stack([snapped[:, 1], snapped[:, 2], snapped[:, 3]], axis=-1)
    tris = np.concatenate([t1, t2])
    nondegenerate = (
        (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    )
    extra.append(tris[nondegenerate])
    return extra, keep1, keep2
