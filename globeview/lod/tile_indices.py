"""Index buffers over a tile's vertex layout (see render/tile_mesh.py), the shared pool of
them, and where the layout's nodes are (`node_lonlat`: rows north to south, columns west to
east).

Every tile has the same vertex layout, so an index *variant* — a triangulation of the grid at
some stride, with or without skirts, with a pole fan, with edges stitched to coarser
neighbours — is built once and shared by all tiles. LOD providers choose a variant per tile;
the renderer draws all tiles in one multi-draw call with per-draw base vertices.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Literal

import numpy as np

Pole = Literal["north", "south", "both"] | None


def node_lonlat(
    bounds: tuple[float, float, float, float], size: int
) -> tuple[np.ndarray, np.ndarray]:
    """Longitudes (size,) west->east and latitudes (size,) north->south of a tile's nodes."""
    west, south, east, north = bounds
    return np.linspace(west, east, size), np.linspace(north, south, size)


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
    skirt_edges: optional (north, south, west, east) flags: with ``skirts``, only the edges
        flagged get skirts (an edge stitched to a same-level neighbour drawn there shares
        its nodes and needs none); None: every non-pole edge.
    """

    stride: int = 1
    skirts: bool = True
    pole: Pole = None
    edge_strides: tuple[int, int, int, int] | None = None
    skirt_edges: tuple[bool, bool, bool, bool] | None = None


#: Variants whose index lists `grid_indices` keeps (at most ~100 KB each, a 65-node tile at
#: stride 1): enough for the new variants of a frame, which are asked for twice in it.
GRID_INDICES_CACHE = 256


@functools.lru_cache(maxsize=4096)
def index_count(size: int, variant: IndexVariant) -> int:
    """How many indices (3 per triangle) ``variant`` has over a tile of ``size`` nodes per
    side: what the renderer draws for a tile of that variant (cached: a frame uses a few
    dozen variants at most)."""
    return len(grid_indices(size, variant))


@functools.lru_cache(maxsize=GRID_INDICES_CACHE)
def grid_indices(size: int, variant: IndexVariant) -> np.ndarray:
    """uint32 triangle-list indices for ``variant`` over a tile of ``size`` nodes per side,
    read-only and shared: a variant first met in a frame is counted (`index_count`, the
    frame's triangles) and uploaded (the renderer's index pool) from one build (a fast low
    flight meets several stitched-edge variants a frame, ~1 ms CPU each to build)."""
    idx = _build_grid_indices(size, variant)
    idx.flags.writeable = False
    return idx


def _build_grid_indices(size: int, variant: IndexVariant) -> np.ndarray:
    """`grid_indices`' list, built."""
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
    flags = variant.skirt_edges or (True,) * 4
    out = []
    for k, (name, nodes) in enumerate(edge_nodes.items()):
        if variant.pole == name or (variant.pole == "both" and name in ("north", "south")):
            continue
        if not flags[k]:
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
    coarse edge's nodes, so the edge matches the coarser neighbour with no T-junction.

    A border cell touching one coarse edge keeps its two triangles with the corners that lie
    on that edge snapped down to the edge's coarse nodes; the cells along an edge then form
    fans from the inner row to each coarse segment. A corner cell touching two coarse edges is
    first split along the diagonal from its inner corner to the tile's corner, and each half
    is snapped along its own edge only (snapping both at once made overlapping triangles).
    """
    s = variant.stride
    n = size - 1
    north, south, west, east = variant.edge_strides
    coarse = {
        "north": (north > s, rr == 0),
        "south": (south > s, rr == n - s),
        "west": (west > s, cc == 0),
        "east": (east > s, cc == n - s),
    }
    touches = {k: on & m for k, (on, m) in coarse.items()}
    n_touch = sum(t.astype(np.int64) for t in touches.values())
    border = n_touch > 0
    if not border.any():
        return [], keep1, keep2
    keep1 = keep1 & ~border
    keep2 = keep2 & ~border

    def snap(r: np.ndarray, c: np.ndarray, edges: list[str]) -> np.ndarray:
        """Node index after moving nodes that lie on the given coarse edges onto the
        edge's coarse nodes (rounding toward the edge's start)."""
        r, c = r.copy(), c.copy()
        for name in edges:
            es = {"north": north, "south": south, "west": west, "east": east}[name]
            if name in ("north", "south"):
                on = r == (0 if name == "north" else n)
                c = np.where(on, (c // es) * es, c)
            else:
                on = c == (0 if name == "west" else n)
                r = np.where(on, (r // es) * es, r)
        return r * size + c

    tris = []
    # Cells on exactly one coarse edge.
    for name in ("north", "south", "west", "east"):
        sel = touches[name] & (n_touch == 1)
        if not sel.any():
            continue
        r0, c0 = rr[sel], cc[sel]
        cr = np.stack([r0, r0, r0 + s, r0 + s], axis=-1)
        ccol = np.stack([c0, c0 + s, c0, c0 + s], axis=-1)
        q = snap(cr, ccol, [name])  # a, b, c, d
        tris.append(np.stack([q[:, 0], q[:, 2], q[:, 1]], axis=-1))
        tris.append(np.stack([q[:, 1], q[:, 2], q[:, 3]], axis=-1))
    # Corner cells on two coarse edges, as (row, col) offsets in the cell: the inner corner,
    # the cell's other corner on the first edge, the one on the second edge, the tile corner.
    corners = {
        ("north", "west"): ((1, 1), (0, 1), (1, 0), (0, 0)),
        ("north", "east"): ((1, 0), (0, 0), (1, 1), (0, 1)),
        ("south", "west"): ((0, 1), (1, 1), (0, 0), (1, 0)),
        ("south", "east"): ((0, 0), (1, 0), (0, 1), (1, 1)),
    }
    for (e1, e2), (inner, on_e1, on_e2, outer) in corners.items():
        sel = touches[e1] & touches[e2]
        if not sel.any():
            continue
        r0, c0 = rr[sel], cc[sel]

        def node(rc, r0=r0, c0=c0):
            return r0 + rc[0] * s, c0 + rc[1] * s

        (ri, ci), (ro, co) = node(inner), node(outer)
        for edge, mid in ((e1, on_e1), (e2, on_e2)):
            rm, cm = node(mid)
            tri_r = np.stack([ri, rm, ro], axis=-1)
            tri_c = np.stack([ci, cm, co], axis=-1)
            tris.append(snap(tri_r, tri_c, [edge]))
    out = np.concatenate(tris)
    nondegenerate = (out[:, 0] != out[:, 1]) & (out[:, 1] != out[:, 2]) & (out[:, 0] != out[:, 2])
    return [out[nondegenerate]], keep1, keep2
