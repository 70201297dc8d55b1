"""Terrain-collapse geometry on the WGS84 ellipsoid (CPU, float64, vectorised).

The collapse of Wang's thesis (ch. 6) moved onto the curved globe: the land between two
points A and B is squeezed along the A->B axis by a ratio r so that A and B come r times as
close while everything outside the zone slides rigidly toward the zone. The derivation, the
departures from the thesis's printed §6.2 formulas and the precision analysis are in
docs/collapse.md; in short:

- Frame. a, b = geocentric unit directions of the ellipsoid foot points of A and B;
  n = unit(a x b) (normal of the great-circle plane through A and B), m = unit(a + b) (the
  midpoint direction), t = n x m (the axis direction at the midpoint M, toward B). M is the
  ellipsoid point in direction m; R_M = |M| (m).
- Along-axis coordinate of a point P: with F its ellipsoid foot point (geodetic normal
  through P) and u = F/|F|, psi = atan2(u.t, u.m) (radians; -psi0 at A, +psi0 at B where
  2 psi0 is the angle between a and b), s = R_M psi (metres). Cross-axis coordinate:
  c = asin(u.n).
- Mapping. psi' = r psi inside the zone (|psi| <= psi0), psi' = psi -+ (1 - r) psi0 outside
  (continuous at the edges). The far side of the globe must absorb the lost length somewhere
  (a circle cannot shrink rigidly), so beyond psi_k = (pi + psi0) / 2 (always > 90 degrees
  from M, out of sight when the zone is in view) the shift tapers linearly to zero at the
  antipodal half-meridian psi = +-pi: the mapping is continuous and one-to-one everywhere.
- Move. u is rotated about n by phi = psi' - psi (this keeps u.n, the cross-axis angle,
  exactly); the foot point goes back onto the ellipsoid along the rotated direction; the
  ellipsoidal height h is re-added along the geodetic normal there, so heights are kept
  exactly.

Everything here takes and returns absolute ECEF metres (float64); the GPU twin
(collapse.glsl) evaluates the same formulas relative to the eye.
"""

from __future__ import annotations

import contextlib
import math
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from globeview.plugins.api import (
    WGS84,
    displacement_chord_error_m,
    ecef_foot_points,
    lonlat_to_ecef,
)

__all__ = ["CollapseFrame", "rotate_about"]

#: A and B closer than this (m) collapse nothing (the frame is undefined).
MIN_SEPARATION_M = 0.5
#: A and B must be less than this far apart (radians of geocentric angle): near-antipodal
#: points have no unique great circle, and the far-side taper needs room.
MAX_ANGLE_RAD = math.radians(170.0)

#: Margin (rad) on a tile's geocentric along-axis angles for the foot point's (the map's psi
#: differs from the point's own direction by the geodetic-geocentric deflection, <= 0.0034
#: rad, times height / distance from the normal's axis; `BEND_RHO_MIN` keeps that small).
BEND_PSI_MARGIN = 2e-3
#: Tiles closer than this fraction of R_M to the A-B plane's normal axis get the exact bend.
BEND_RHO_MIN = 0.05
#: Ellipsoid term of the smooth-region bend bound (`CollapseFrame.bend_bound_m`), calibrated
#: with a wide safety factor against the exact measure (tests/collapse/test_collapse_bend.py).
BEND_ELLIPSOID_K = 0.05
#: Batches of fewer tiles than this (or with a quarter or more crossed by a kink) get the
#: exact measure throughout: cheaper there than the bound, and never larger.
BEND_EXACT_BELOW = 64

_A2 = WGS84.a**2
_B2 = WGS84.b**2
#: Gradient scale of the ellipsoid equation, (1/a^2, 1/a^2, 1/b^2) (m^-2).
INV_AXES2 = np.array([1.0 / _A2, 1.0 / _A2, 1.0 / _B2])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def rotate_about(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (N, 3) about the unit ``axis`` (3,) by ``angle`` (N,) radians,
    right-handed (Rodrigues)."""
    angle = np.asarray(angle, dtype=np.float64)[..., None]
    ax = np.asarray(axis, dtype=np.float64)
    # axis x v as one matrix product with axis's cross-product matrix (np.cross costs several
    # times more on the LOD's small batches).
    skew = np.array([[0.0, -ax[2], ax[1]], [ax[2], 0.0, -ax[0]], [-ax[1], ax[0], 0.0]])
    cos = np.cos(angle)
    return v * cos + (v @ skew.T) * np.sin(angle) + (v @ ax)[..., None] * ax * (1.0 - cos)


class FootMemo:
    """Foot points, heights and along-axis angles of recently moved point sets, for one A-B
    pair (any ratio): while the collapse animates only the ratio changes, and the LOD moves
    the same tile lattices every frame, so their feet are looked up, not recomputed. Keyed
    by the points' bytes; the oldest of more than `SIZE` sets are dropped."""

    SIZE = 96

    def __init__(self) -> None:
        self._sets: OrderedDict[tuple, tuple[np.ndarray, np.ndarray, np.ndarray]] = OrderedDict()

    def get(self, p: np.ndarray, mtn: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(xyz, h, psi) of points ``p`` (N, 3): the foot points' coordinates on the axes
        ``mtn`` (3, 3) (rows m, t, n), the heights and the along-axis angles."""
        key = (p.shape, p.tobytes())
        hit = self._sets.get(key)
        if hit is not None:
            # Another thread (picking beside the LOD) may have dropped it meanwhile: harmless.
            with contextlib.suppress(KeyError):
                self._sets.move_to_end(key)
            return hit
        foot, h = ecef_foot_points(p)
        xyz = foot @ mtn.T
        psi = np.arctan2(xyz[:, 1], xyz[:, 0])
        self._sets[key] = (xyz, h, psi)
        if len(self._sets) > self.SIZE:
            with contextlib.suppress(KeyError):
                self._sets.popitem(last=False)
        return xyz, h, psi


def ellipsoid_point_along(directions: np.ndarray) -> np.ndarray:
    """The ellipsoid point in each geocentric direction (N, 3) (any length): ECEF metres."""
    d = np.asarray(directions, dtype=np.float64)
    q = np.sum(d * d * INV_AXES2, axis=-1, keepdims=True)
    return d / np.sqrt(q)


def geodetic_normal(points_on_ellipsoid: np.ndarray) -> np.ndarray:
    """Unit geodetic normals at ellipsoid points (N, 3) ECEF."""
    g = points_on_ellipsoid * INV_AXES2
    return g / np.sqrt(np.einsum("...j,...j->...", g, g))[..., None]


@dataclass(frozen=True)
class CollapseFrame:
    """The collapse between A and B with ratio ``ratio``, in ECEF.

    Attributes:
        lon_a, lat_a, lon_b, lat_b: the two points (degrees; heights ignored).
        ratio: r in (0, 1]: how much the zone's along-axis length is scaled (1 = identity).
        m, t, n: unit ECEF vectors: midpoint direction, axis direction at M (toward B),
            normal of the A-B great-circle plane (t = n x m).
        m_ecef: M, the ellipsoid point in direction m (ECEF m); r_m = |M| (m).
        psi0: half the geocentric angle between A and B (rad); d = 2 r_m psi0 is the
            along-axis length of the zone (m).
    """

    lon_a: float
    lat_a: float
    lon_b: float
    lat_b: float
    ratio: float
    m: np.ndarray
    t: np.ndarray
    n: np.ndarray
    m_ecef: np.ndarray
    r_m: float
    psi0: float
    #: Feet of recently moved points, shared by the frames of one A-B pair (`with_ratio`).
    feet: FootMemo = field(default_factory=FootMemo, compare=False, repr=False)

    @classmethod
    def from_lonlat(
        cls,
        lon_a: float,
        lat_a: float,
        lon_b: float,
        lat_b: float,
        ratio: float,
        feet: FootMemo | None = None,
    ) -> CollapseFrame:
        """Build the frame. Raises ValueError for r outside (0, 1] or A, B (near-)antipodal.
        A and B closer than ``MIN_SEPARATION_M`` give the identity (psi0 = 0). ``feet``: the
        memo of another frame of the same A and B (default: a new one)."""
        feet = FootMemo() if feet is None else feet
        if not (0.0 < ratio <= 1.0):
            raise ValueError(f"collapse ratio must lie in (0, 1], got {ratio!r}")
        fa = lonlat_to_ecef(lon_a, lat_a, 0.0)
        fb = lonlat_to_ecef(lon_b, lat_b, 0.0)
        a, b = _unit(fa), _unit(fb)
        cross = np.cross(a, b)
        sin_ang = float(np.linalg.norm(cross))
        angle = math.atan2(sin_ang, float(a @ b))
        if angle > MAX_ANGLE_RAD:
            raise ValueError(
                f"A and B are {math.degrees(angle):.1f} degrees apart; the collapse needs "
                f"less than {math.degrees(MAX_ANGLE_RAD):.0f}"
            )
        m = _unit(a + b)
        m_ecef = ellipsoid_point_along(m)
        if np.linalg.norm(fa - fb) < MIN_SEPARATION_M or sin_ang == 0.0:
            # No axis: any frame will do, the mapping is the identity.
            n = _unit(np.cross(m, [0.0, 0.0, 1.0]) + np.array([0.0, 1e-12, 0.0]))
            n = _unit(np.cross(m, np.cross(n, m)))
            return cls(lon_a, lat_a, lon_b, lat_b, 1.0, m, np.cross(n, m), n, m_ecef,
                       float(np.linalg.norm(m_ecef)), 0.0, feet)  # fmt: skip
        n = cross / sin_ang
        t = np.cross(n, m)
        return cls(
            float(lon_a), float(lat_a), float(lon_b), float(lat_b), float(ratio),
            m, t, n, m_ecef, float(np.linalg.norm(m_ecef)), 0.5 * angle, feet,
        )  # fmt: skip

    def with_ratio(self, ratio: float) -> CollapseFrame:
        """The same A and B with another ratio (the animation interpolates it), sharing this
        frame's memo of foot points."""
        return CollapseFrame.from_lonlat(
            self.lon_a, self.lat_a, self.lon_b, self.lat_b, ratio, self.feet
        )

    # -- the along-axis coordinate --------------------------------------------------------------
    @property
    def d_m(self) -> float:
        """Along-axis length of the zone (m): 2 R_M psi0."""
        return 2.0 * self.r_m * self.psi0

    @property
    def psi_k(self) -> float:
        """Start of the far-side taper (rad): halfway between the zone edge and the antipode."""
        return 0.5 * (math.pi + self.psi0)

    def axis_angles(self, points_ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(psi, c) of points (N, 3) ECEF: along-axis angle atan2(u.t, u.m) and cross-axis
        angle asin(u.n) (radians) of the geocentric direction u of each point's ellipsoid
        foot point."""
        foot, _, _ = self._foot(points_ecef)
        u = _unit(foot)
        psi = np.arctan2(u @ self.t, u @ self.m)
        c = np.arcsin(np.clip(u @ self.n, -1.0, 1.0))
        return psi, c

    def rotation_angle(self, psi: np.ndarray, inverse: bool = False) -> np.ndarray:
        """phi = psi' - psi (rad) for along-axis angles ``psi`` (forward), or, with
        ``inverse``, the angle that takes displaced angles ``psi`` back (psi - psi')."""
        psi = np.asarray(psi, dtype=np.float64)
        r, p0, pk = self.ratio, self.psi0, self.psi_k
        shift = (1.0 - r) * p0
        a = np.abs(psi)
        sgn = np.where(psi < 0.0, -1.0, 1.0)
        if not inverse:
            inside = (r - 1.0) * psi
            outside = -sgn * shift
            # Far taper: |psi'| = pi - (pi - |psi|) * (pi - pk + shift) / (pi - pk).
            far = -sgn * (math.pi - a) * shift / (math.pi - pk)
            return np.where(a <= p0, inside, np.where(a <= pk, outside, far))
        p0d, pkd = r * p0, pk - shift  # the same knots after the collapse
        inside = (1.0 / r - 1.0) * psi
        outside = sgn * shift
        far = sgn * (math.pi - a) * shift / (math.pi - pkd)
        return np.where(a <= p0d, inside, np.where(a <= pkd, outside, far))

    # -- the mapping ------------------------------------------------------------------------
    def _foot(self, points_ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p = np.asarray(points_ecef, dtype=np.float64).reshape(-1, 3)
        foot, h = ecef_foot_points(p)
        return foot, h, p

    def _move(self, points_ecef: np.ndarray, inverse: bool) -> np.ndarray:
        shape = np.shape(points_ecef)
        if self.ratio == 1.0 or self.psi0 == 0.0:
            return np.asarray(points_ecef, dtype=np.float64).copy()
        p = np.ascontiguousarray(points_ecef, dtype=np.float64).reshape(-1, 3)
        xyz, h, psi = self.feet.get(p, self._mtn)
        phi = self.rotation_angle(psi, inverse=inverse)
        # The foot point rotated about n by phi, in the (m, t, n) axes (t = n x m, so m turns
        # toward t): (x cos - y sin, x sin + y cos, z); the same as `rotate_about` with fewer
        # numpy calls (their overhead, not the points, is the cost on the LOD's batches).
        c, s = np.cos(phi), np.sin(phi)
        x, y = xyz[:, 0], xyz[:, 1]
        rot = np.stack([x * c - y * s, x * s + y * c, xyz[:, 2]], axis=1) @ self._mtn
        g = rot / np.sqrt(np.einsum("ij,ij->i", rot * INV_AXES2, rot))[:, None]
        up = g * INV_AXES2
        up /= np.sqrt(np.einsum("ij,ij->i", up, up))[:, None]
        out = g + h[:, None] * up
        out = np.where((phi == 0.0)[:, None], p, out)
        return out.reshape(shape)

    @cached_property
    def _mtn(self) -> np.ndarray:
        """(3, 3) rows m, t, n: ECEF -> the collapse's axes (orthonormal)."""
        return np.stack([self.m, self.t, self.n])

    def forward(self, points_ecef: np.ndarray) -> np.ndarray:
        """Collapse (..., 3) true ECEF points (m) to where they are drawn."""
        return self._move(points_ecef, inverse=False)

    def inverse(self, points_ecef: np.ndarray) -> np.ndarray:
        """Drawn (collapsed) ECEF points (..., 3) back to the true ones (exact inverse)."""
        return self._move(points_ecef, inverse=True)

    # -- bend bound for LOD providers ---------------------------------------------------------
    def bend_bound_m(self, points: np.ndarray, displaced: np.ndarray | None = None) -> np.ndarray:
        """A cheap upper bound (m, (N,)) of `culling.displacement_chord_error_m` of `forward`
        over tile bounding lattices ``points`` (N, K, 3) (true ECEF); ``displaced`` =
        ``forward(points)`` if the caller has it. See docs/collapse.md ("Cracks").

        The lattice's geocentric along-axis angles (no foot points: cheap) give each tile's psi
        range; the straight edges between lattice points stay inside it (psi is monotonic
        along a chord). Tiles whose range, widened by ``BEND_PSI_MARGIN``, avoids the kinks
        (|psi| = psi0 and psi_k) lie where the map is smooth: on a sphere it is
        (rho, psi, z) -> (rho, g psi + const, z) about the A-B plane's normal, whose second
        derivative is at most |1 - g^2| / rho (g = r inside the zone, 1 outside, the taper's
        stretch beyond psi_k), so an edge of length L bends at most L^2 / 8 of that; the
        ellipsoid adds ``BEND_ELLIPSOID_K`` * (shift + |1 - g|) / rho. Those tiles get the
        bound; the others (a kink inside, the antipodal half-meridian, close to the normal's
        axis) get the exact measure, displacing only their edges' midpoints. Small batches and
        batches with many kinked tiles get the exact measure throughout (``BEND_EXACT_BELOW``):
        numpy's per-call overhead, not the points, is what costs there."""
        pts = np.asarray(points, dtype=np.float64)
        n = pts.shape[0]
        if n == 0 or self.ratio == 1.0 or self.psi0 == 0.0:
            return np.zeros(n)
        k = pts.shape[1] // 2
        low = pts[:, :k]  # the lower surface, as the exact measure
        xy = low @ self._mt
        psi = np.arctan2(xy[..., 1], xy[..., 0])
        lo, hi = psi.min(axis=1), psi.max(axis=1)
        p0, pk, r = self.psi0, self.psi_k, self.ratio
        eps = BEND_PSI_MARGIN
        shift = (1.0 - r) * p0
        g_taper = 1.0 + shift / (math.pi - pk)
        knots = np.array([-pk, -p0, p0, pk])
        hits = (lo[:, None] <= knots + eps) & (hi[:, None] >= knots - eps)
        kinked = hits.any(axis=1) | (hi - lo >= math.pi)  # a kink inside, or the wrap at pi
        if n < BEND_EXACT_BELOW or 4 * np.count_nonzero(kinked) >= n:
            # Few tiles, or many crossed by a kink: one exact call costs less than the bound's
            # extra numpy calls (per-call overhead dominates small arrays) and is tighter.
            return displacement_chord_error_m(self.forward, pts, displaced)
        side = round(math.sqrt(k))
        idx = np.arange(k).reshape(side, side)
        ia = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
        ib = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
        d = low[:, ia] - low[:, ib]
        edge = np.sqrt(np.max(np.einsum("nej,nej->ne", d, d), axis=1))
        # rho is 1-Lipschitz: every edge point is within edge / 2 of a lattice point.
        rho = np.sqrt(np.min(np.einsum("nkj,nkj->nk", xy, xy), axis=1)) - 0.5 * edge
        a_lo = np.where((lo <= 0.0) & (hi >= 0.0), 0.0, np.minimum(np.abs(lo), np.abs(hi)))
        a_hi = np.maximum(np.abs(lo), np.abs(hi)) + eps
        g_max_dev = np.where(a_hi > pk, np.maximum(g_taper - 1.0, 0.0), 0.0)
        touches_zone = a_lo <= p0 + eps
        c_in = np.where(touches_zone, 1.0 - r * r, 0.0)
        c_taper = np.where(a_hi > pk, g_taper * g_taper - 1.0, 0.0)
        dev = np.maximum(np.where(touches_zone, 1.0 - r, 0.0), g_max_dev)
        curv = np.maximum(c_in, c_taper) + BEND_ELLIPSOID_K * (shift + dev)
        exact = kinked | (rho <= BEND_RHO_MIN * self.r_m)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = edge * edge / 8.0 * curv / rho
        rest = exact.nonzero()[0]
        if len(rest) == n:
            return displacement_chord_error_m(self.forward, pts, displaced)
        if len(rest):
            disp = None if displaced is None else np.asarray(displaced).take(rest, axis=0)
            out[rest] = displacement_chord_error_m(self.forward, pts.take(rest, axis=0), disp)
        return out

    @cached_property
    def _mt(self) -> np.ndarray:
        """(3, 2) columns m, t: ECEF -> coordinates in the A-B great circle's plane."""
        return np.stack([self.m, self.t], axis=1)

    # -- overlays ---------------------------------------------------------------------------
    def edge_line(self, psi: float, half_extent_rad: float, n_points: int = 64) -> np.ndarray:
        """Points (n_points, 3) ECEF on the ellipsoid along the line of constant along-axis
        angle ``psi`` (rad), cross-axis angle from -half_extent to +half_extent (rad)."""
        c = np.linspace(-half_extent_rad, half_extent_rad, n_points)[:, None]
        base = math.cos(psi) * self.m + math.sin(psi) * self.t
        return ellipsoid_point_along(np.cos(c) * base + np.sin(c) * self.n)

    def gpu_uniforms(self, eye_ecef: np.ndarray) -> dict[str, float | tuple[float, ...]]:
        """Values of the GLSL twin's uniforms for an eye at ``eye_ecef`` (m): M - eye is
        formed here in float64, so the GPU never rounds an absolute position."""
        m_rel = self.m_ecef - np.asarray(eye_ecef, dtype=np.float64)
        r = self.ratio if self.psi0 > 0.0 else 1.0
        return {
            "gv_u_m_rel": tuple(float(v) for v in m_rel),
            "gv_u_m": tuple(float(v) for v in self.m),
            "gv_u_t": tuple(float(v) for v in self.t),
            "gv_u_n": tuple(float(v) for v in self.n),
            "gv_u_rm": float(self.r_m),
            "gv_u_map": (float(self.psi0), float(self.psi_k), float(r), 0.0),
            "gv_u_ell": (_A2 / _B2, _A2 / _B2 - 1.0, 1.0 / WGS84.a, 0.0),
        }
