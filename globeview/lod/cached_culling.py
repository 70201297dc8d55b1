"""The frustum and horizon tests of the shared traversal, on the tile facts the per-terrain
cache holds (`globeview.lod.tile_cache`), with conservative prefilters.

Each gives exactly the answer of its plain counterpart in `globeview.lod.culling`
(`frustum_visible`, `horizon_visible`: the exact tests use the same floating-point operations
on the same operands), but settles most tiles from their bounding sphere or box centre and
runs the exact test only on those near a frustum plane or the horizon. Frames: ECEF metres;
angles in radians.
"""

from __future__ import annotations

import math

import numpy as np

from globeview.lod.culling import box_angular_distance_pre
from globeview.lod.tile_cache import (
    COL_EAST,
    COL_NORTH_R,
    COL_PEAK,
    COL_SOUTH_R,
    COL_SPAN,
    COL_UX,
    COL_UZ,
    COL_WEST,
)
from globeview.lod.view_state import ViewState


class FrustumFrame:
    """Per-view constants of the frustum tests: the eye, the plane normals (as
    `culling.frustum_visible` slices them, and as contiguous columns), each plane's signed
    distance of the eye, and the prefilter's slack ``tol`` (m)."""

    def __init__(self, view: ViewState) -> None:
        planes = view.frustum_planes
        self.eye = view.eye
        self.normals = planes[:, :3]
        self.normals_t = np.ascontiguousarray(planes[:, :3].T)
        self.d_eye = planes[:, :3] @ view.eye + planes[:, 3]
        self.tol = 1e-3 + 1e-12 * (float(np.abs(view.eye).sum()) + view.far)
        self.d_tol = self.d_eye + self.tol

    def exact_planes(
        self, points: np.ndarray, margin: np.ndarray, planes: np.ndarray
    ) -> np.ndarray:
        """`exact` testing each tile against the planes ``planes`` (N, 6) bool marks only
        (those its prefilter left open; the others it passes): per tile and marked plane
        the same operations on the same operands as `exact`, so the same answer, with a
        sixth of the work where one plane is open."""
        tile, plane = np.nonzero(planes)
        rel = points.take(tile, axis=0) - self.eye  # (P, K, 3)
        # einsum sums over j in order, as exact's "nkj,pj->npk" does (the same floats).
        dist = np.einsum("nkj,nj->nk", rel, self.normals.take(plane, axis=0)).max(axis=1)
        ok = dist + self.d_eye.take(plane) >= -margin.take(tile)
        fails = np.bincount(tile.compress(~ok), minlength=len(points))
        return fails == 0

    def exact(self, points: np.ndarray, margin: np.ndarray) -> np.ndarray:
        """`culling.frustum_visible`, the same operations on the same operands (so the same
        floats), with the per-view terms computed once."""
        dist = np.einsum("nkj,pj->npk", points - self.eye, self.normals).max(axis=2)
        return ((dist + self.d_eye) >= -margin[:, None]).all(axis=1)


def frustum_prefilter(
    frame: FrustumFrame, rel_centre: np.ndarray, margin: np.ndarray, sphere: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`frustum_visible` decided from each tile's bounding sphere where that is conclusive.

    With c the mean of a tile's points (``rel_centre`` = c - eye, (N, 3)) and r their
    farthest distance from c (``sphere``), every point's signed plane distance lies in
    [dist(c) - r, dist(c) + r], and their mean is dist(c). So a plane has some point within
    the margin when dist(c) >= -margin, and all of them beyond it when dist(c) + r < -margin.
    Both tests keep a slack (orders of magnitude above float64 rounding at these
    magnitudes), so they never disagree with the exact test; tiles neither decides come back
    as ambiguous, for the exact `frustum_visible` (`FrustumFrame.exact`).

    Returns (visible, ambiguous, open_planes): (N,) bool each, ``visible`` False where
    ambiguous; and (N, 6) bool, the planes the centre does not settle (the only ones the
    exact test of an ambiguous tile needs, `FrustumFrame.exact_planes`)."""
    # Per plane dist(c) + margin + tol; over the planes, the least.
    mp = rel_centre @ frame.normals_t + frame.d_tol + margin[:, None]
    m = mp.min(axis=1)
    inside = m >= 2.0 * frame.tol  # dist(c) + margin >= tol on every plane
    outside = m + sphere < 0.0  # dist(c) + r + margin < -tol on some plane
    return inside, ~(inside | outside), mp < 2.0 * frame.tol


#: Slack (radians) of the horizon prefilter, far above the rounding of the exact test.
HORIZON_TOL = 1e-6


def horizon_visible_cached(
    view: ViewState, cap: float, c: np.ndarray, u0: np.ndarray | None
) -> np.ndarray:
    """`culling.horizon_visible` of tiles from their cached columns ``c`` (N_COLS, N), with
    ``cap`` = `culling.horizon_cap` and ``u0`` the unit vector of the eye's (lon, lat).

    `culling.box_angular_distance` is the spherical distance from the eye's (lon, lat) to
    the nearest point of the box whenever that is below 90 degrees, hence at most the
    distance to the box's centre. So a tile whose centre is within min(cap + peak, 90 deg)
    minus a slack is visible without the exact test, which then runs only on the others
    (those near the horizon). ``u0`` None skips the prefilter (eye almost on the ground)."""
    limit = cap + c[COL_PEAK]
    if u0 is not None:
        thr = np.cos(np.minimum(limit - HORIZON_TOL, math.pi / 2 - HORIZON_TOL))
        vis = u0 @ c[COL_UX : COL_UZ + 1] >= thr
        n_vis = np.count_nonzero(vis)
        if n_vis == len(vis):
            return vis
        ai = (~vis).nonzero()[0]
        c, limit = c.take(ai, axis=1), limit.take(ai)
    lon0, lat0, _ = view.eye_lonlat_h
    exact = (
        box_angular_distance_pre(
            lon0, lat0, c[COL_WEST : COL_EAST + 1], c[COL_SPAN], c[COL_SOUTH_R], c[COL_NORTH_R]
        )
        <= limit
    )
    if u0 is None:
        return exact
    vis[ai] = exact
    return vis
