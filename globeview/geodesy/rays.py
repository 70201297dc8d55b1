"""Ray / ellipsoid intersection (picking, horizon tests, camera collision).

Rays live in ECEF metres: ``point(t) = origin + t * direction``. The direction need not be a
unit vector; ``t`` is measured in multiples of it (metres when it is a unit vector).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from globeview.geodesy.ellipsoid import WGS84, Ellipsoid

__all__ = ["ray_ellipsoid_intersection", "ray_ellipsoid_t"]

FloatArray = NDArray[np.float64]


def ray_ellipsoid_t(
    origin: ArrayLike,
    direction: ArrayLike,
    ellipsoid: Ellipsoid = WGS84,
    h: ArrayLike = 0.0,
) -> FloatArray:
    """Ray parameter of the nearest intersection in front of the ray origin.

    The surface is the ellipsoid *inflated* by ``h`` metres: semi-axes ``a + h`` and
    ``b + h``. This approximates the true surface at constant ellipsoidal height ``h`` (which
    is not an ellipsoid); on WGS84 their heights differ by at most ≈ 1.4 cm at h = 10 km and
    ≈ 1.2 m at h = 1000 km, and they agree exactly at the equator and the poles.

    Args:
        origin: ray origins, ECEF metres, shape ``(..., 3)``.
        direction: ray directions (any non-zero length), ECEF, shape ``(..., 3)``.
        ellipsoid: the reference ellipsoid.
        h: inflation height in metres (broadcasts over ``(...)``).

    Returns:
        ``t >= 0`` of shape ``(...)``: the first hit in front of the origin; for an origin
        inside the surface, the exit point. NaN where the ray misses, only grazes it
        (tangent), or where the surface lies entirely behind the origin.
    """
    origin = np.asarray(origin, dtype=np.float64)
    direction = np.asarray(direction, dtype=np.float64)
    h = np.asarray(h, dtype=np.float64)
    semi = np.stack(np.broadcast_arrays(ellipsoid.a + h, ellipsoid.a + h, ellipsoid.b + h), -1)
    # Scale space so the ellipsoid becomes the unit sphere; t is unchanged by the scaling.
    o = origin / semi
    d = direction / semi
    qa = np.sum(d * d, axis=-1)
    qb = np.sum(o * d, axis=-1)  # half the linear coefficient
    qc = np.sum(o * o, axis=-1) - 1.0
    disc = qb * qb - qa * qc
    hit = disc > 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        # Numerically stable roots: never subtract two nearly equal numbers.
        s = -(qb + np.copysign(np.sqrt(np.where(hit, disc, 0.0)), qb))
        t1 = s / qa
        t2 = qc / s
    t_near = np.minimum(t1, t2)
    t_far = np.maximum(t1, t2)
    t = np.where(t_near >= 0.0, t_near, t_far)
    t = np.where(hit & (t >= 0.0), t, np.nan)
    return t[()]


def ray_ellipsoid_intersection(
    origin: ArrayLike,
    direction: ArrayLike,
    ellipsoid: Ellipsoid = WGS84,
    h: ArrayLike = 0.0,
) -> FloatArray:
    """ECEF point (metres, shape ``(..., 3)``) where each ray first meets the inflated
    ellipsoid, or NaN where it misses. See `ray_ellipsoid_t` for the conventions."""
    origin = np.asarray(origin, dtype=np.float64)
    direction = np.asarray(direction, dtype=np.float64)
    t = np.asarray(ray_ellipsoid_t(origin, direction, ellipsoid, h))
    return origin + t[..., np.newaxis] * direction
