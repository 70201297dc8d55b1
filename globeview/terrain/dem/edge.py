"""A DEM's surface continued past its data edge, for sampling it onto the quadtree's nodes.

Bilinear interpolation between a level's nodes reproduces a source DEM only in the grid cells
whose four corner nodes all hold its heights. A cell that meets the DEM's data but has a
corner beyond it (its last node spacing: GDAL's warp leaves a node NaN where the source cell
holding it is nodata or off the raster) would otherwise ramp toward whatever fills the missing
corner: the ellipsoid when the DEM is alone (issue #29). `Dem.read_grid_parts` gives those
corners the DEM's surface continued linearly (`continue_surface`), sampled bilinearly at the
node; which nodes they are is decided on the source's own cells (`DataCells`).

Pure numpy on (rows, cols) arrays; NaN is "no data". Positions are fractional pixel
coordinates of the array (pixel (c, r) spans [c, c + 1] x [r, r + 1], its sample at the
centre). Heights are whatever the array holds (metres in the source's own vertical datum).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DataCells", "continuation_rings", "continue_surface", "edge_candidates", "next_to"]

#: The 8 neighbour directions (row, column).
_DIRECTIONS = tuple((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc)
#: Overlaps thinner than this (pixels) do not count: float noise where a node's cell and the
#: source's cells share an edge exactly.
_EPS = 1e-9


def next_to(mask: np.ndarray) -> np.ndarray:
    """Cells with a True cell among their 8 neighbours (the cell itself not counted)."""
    rows, cols = mask.shape
    padded = np.pad(mask, 1, constant_values=False)
    out = np.zeros_like(mask)
    for dr, dc in _DIRECTIONS:
        out |= padded[1 + dr : 1 + dr + rows, 1 + dc : 1 + dc + cols]
    return out


def edge_candidates(data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the NaN nodes of a grid that may be corners of a cell meeting the data:
    those next to a data node, and those on the grid's border (their neighbour beyond it, in
    the caller's next window, may be data).

    Complete where the grid's node spacing is at most two source cells (a source read at its
    own level or finer: every cell meeting the data then has a corner in GDAL's footprint,
    which reaches half a cell past the samples); coarser grids may miss a sliver's corners.
    """
    nan = np.isnan(data)
    cand = nan & next_to(~nan)
    cand[[0, -1], :] |= nan[[0, -1], :]
    cand[:, [0, -1]] |= nan[:, [0, -1]]
    rows, cols = np.nonzero(cand)
    return rows, cols


class DataCells:
    """The cells between an array's samples whose four samples hold data (the footprint the
    source's bilinear surface covers)."""

    def __init__(self, arr: np.ndarray) -> None:
        ok = np.isfinite(arr)
        self.cells = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]

    def meet(self, cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Whether each quadrilateral overlaps a data cell with positive area, judged by its
        bounding box (exact for a box; a rotated quadrilateral's box may touch one more).
        ``cols``, ``rows``: (n, 2, 2) pixel coordinates of the corners. Cell (i, j) spans
        [j + 0.5, j + 1.5] x [i + 0.5, i + 1.5] (between the samples at the pixel centres)."""
        nr, nc = self.cells.shape
        # Cells j with j + 0.5 < cmax and j + 1.5 > cmin (by more than float noise).
        j0 = np.maximum(np.floor(cols.min(axis=(1, 2)) - 1.5 + _EPS).astype(np.int64) + 1, 0)
        j1 = np.minimum(np.ceil(cols.max(axis=(1, 2)) - 0.5 - _EPS).astype(np.int64), nc)
        i0 = np.maximum(np.floor(rows.min(axis=(1, 2)) - 1.5 + _EPS).astype(np.int64) + 1, 0)
        i1 = np.minimum(np.ceil(rows.max(axis=(1, 2)) - 0.5 - _EPS).astype(np.int64), nr)
        out = np.zeros(cols.shape[0], dtype=bool)
        if out.size == 0:
            return out
        # A few cells a side (a node cell spans about as many source cells as the grid is
        # coarser): look at each offset in the boxes, vectorised over the quadrilaterals.
        for di in range(max(0, int((i1 - i0).max()))):
            for dj in range(max(0, int((j1 - j0).max()))):
                i, j = i0 + di, j0 + dj
                inside = (i < i1) & (j < j1)
                out[inside] |= self.cells[i[inside], j[inside]]
        return out


def continuation_rings(node_cells: float) -> int:
    """Rings of source cells `continue_surface` must fill so that a node that is a corner of a
    grid cell meeting the data (within one node spacing, ``node_cells`` source cells, of a
    data cell) lies among filled cells, bilinear from the four around it; one more ring for
    rounding."""
    return math.ceil(node_cells) + 2


def continue_surface(arr: np.ndarray, rings: int) -> np.ndarray:
    """A float32 copy of ``arr`` whose NaN cells within ``rings`` cells (8-connected) of data
    hold the data's surface continued linearly, ring by ring outwards.

    A cell of the next ring gets the mean, over the directions d in which the two cells d and
    2d away hold values, of the linear continuation 2 a[d] - a[2d] (exact for a plane, in
    every direction); a cell with no such pair (a one-cell-wide spur) takes the mean of its
    neighbours with values. Each ring is computed from the rings inside it only, so the
    result does not depend on the order of the cells. Cells farther out stay NaN.
    """
    margin = rings + 2  # a ring cell's cells 2 away stay inside the padded array
    p = np.pad(arr.astype(np.float32), margin, constant_values=np.nan)
    flat = p.reshape(-1)  # a view: writes land in p
    offsets = np.array([dr * p.shape[1] + dc for dr, dc in _DIRECTIONS], dtype=np.int64)
    known = np.isfinite(p)
    front = np.flatnonzero(~known & next_to(known))
    mark = np.zeros(flat.size, dtype=bool)
    for ring in range(rings):
        if front.size == 0:
            break
        flat[front] = _continued_values(flat, front, offsets)
        if ring + 1 < rings:
            # The next ring: the still-empty neighbours of this one (never past the margin:
            # a cell of ring r lies r cells out, the padding is rings + 2 wide).
            around = (front[:, None] + offsets[None, :]).reshape(-1)
            mark[around[np.isnan(flat[around])]] = True
            front = np.flatnonzero(mark)
            mark[front] = False
    return p[margin:-margin, margin:-margin].copy()


def _continued_values(flat: np.ndarray, cells: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Linear continuation into ``cells`` (flat indices) from their neighbours (see
    `continue_surface`), float32."""
    total = np.zeros(cells.size)
    count = np.zeros(cells.size)
    near_total = np.zeros(cells.size)
    near_count = np.zeros(cells.size)
    for off in offsets:
        one = flat[cells + off].astype(np.float64)
        two = flat[cells + 2 * off].astype(np.float64)
        line = 2.0 * one - two
        ok = np.isfinite(line)
        total[ok] += line[ok]
        count += ok
        near = np.isfinite(one)
        near_total[near] += one[near]
        near_count += near
    with np.errstate(invalid="ignore", divide="ignore"):
        values = np.where(count > 0, total / count, near_total / near_count)
    return values.astype(np.float32)
