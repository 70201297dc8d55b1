"""Geodetic (longitude, latitude, ellipsoidal height) <-> ECEF conversions.

Geodetic coordinates: longitude and latitude in degrees (latitude is geodetic, i.e. the angle
of the ellipsoid normal to the equatorial plane), height in metres above the ellipsoid along
that normal. ECEF: Earth-centred, Earth-fixed Cartesian metres, z along the polar axis, x
through (lon 0, lat 0), y through (lon 90, lat 0).

All functions are vectorised and broadcast their inputs; results are float64. A point that is
not one (a latitude outside [-90, 90], a NaN or infinite coordinate) gives NaN in every output
instead of an exception, as the geoid's and the rays' functions do: one bad element of a batch
does not fail the others.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from globeview.geodesy.ellipsoid import WGS84, Ellipsoid

__all__ = ["ecef_to_geodetic", "ecef_to_lonlat", "geodetic_to_ecef", "lonlat_to_ecef"]

FloatArray = NDArray[np.float64]

#: Beyond this distance from the centre (largest ECEF coordinate, metres) the normal through a
#: point passes through the centre to double precision (the angle between them is about
#: e² a / r < 1e-25 rad), so the far-field form is exact there; the closed form's powers of
#: (r / a) overflow from ~1e58 m on.
FAR_FIELD_M = 1e30
#: `ecef_foot_points` subtracts h times the normal from points nearer than this (metres);
#: farther ones take the round trip, since the subtraction keeps only the point's own
#: rounding (2 µm at 1e10 m, 16 km at 1e20 m).
FOOT_DIRECT_MAX_M = 1e10


def geodetic_to_ecef(
    lon_deg: ArrayLike,
    lat_deg: ArrayLike,
    h_m: ArrayLike,
    ellipsoid: Ellipsoid = WGS84,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Convert geodetic coordinates to ECEF.

    Args:
        lon_deg: longitude in degrees (any range).
        lat_deg: geodetic latitude in degrees, [-90, 90].
        h_m: ellipsoidal height in metres.
        ellipsoid: the reference ellipsoid.

    Returns:
        ``(x, y, z)`` ECEF coordinates in metres, each of the broadcast input shape. NaN where
        the latitude is outside [-90, 90] or not finite (91 degrees is not folded over the
        pole onto 89 on the far meridian).
    """
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat_deg = np.asarray(lat_deg, dtype=np.float64)
    lat = np.radians(np.where(np.abs(lat_deg) <= 90.0, lat_deg, np.nan))
    h = np.asarray(h_m, dtype=np.float64)
    sin_lat = np.sin(lat)
    cos_lat = np.cos(lat)
    # Prime-vertical radius of curvature N(lat).
    n = ellipsoid.a / np.sqrt(1.0 - ellipsoid.e2 * sin_lat * sin_lat)
    rho = (n + h) * cos_lat
    x = rho * np.cos(lon)
    y = rho * np.sin(lon)
    z = (n * (1.0 - ellipsoid.e2) + h) * sin_lat
    x, y, z = np.broadcast_arrays(x, y, z)
    # Copy (broadcast views are read-only); [()] turns 0-d results into numpy scalars.
    return x.copy()[()], y.copy()[()], z.copy()[()]


def _wrap_lon_deg(lon: FloatArray) -> FloatArray:
    """Map longitudes from ``atan2`` ([-180, 180]) into (-180, 180]."""
    return np.where(lon <= -180.0, lon + 360.0, lon)


def ecef_to_geodetic(
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    ellipsoid: Ellipsoid = WGS84,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Convert ECEF coordinates to geodetic, exactly (closed form, no iteration).

    Uses Vermeille's analytical method (H. Vermeille, "An analytical method to transform
    geocentric into geodetic coordinates", J. Geodesy 85:105-117, 2011), which is valid
    everywhere: on the polar axis, on the equator, deep inside the Earth (inside the evolute
    of the meridian ellipse, including the centre) and far out in space. Beyond
    `FAR_FIELD_M` the far-field form (geocentric latitude, distance less the foot's radius)
    is taken, which is exact there and does not overflow.

    Degenerate points get a definite answer: on the polar axis the longitude is 0; at the
    centre of the Earth the result is the north pole at height ``-b``; on the equatorial plane
    inside the evolute (where two normals meet) the northern solution is returned.

    Args:
        x, y, z: ECEF coordinates in metres (broadcast together).
        ellipsoid: the reference ellipsoid.

    Returns:
        ``(lon_deg, lat_deg, h_m)``: longitude in degrees in (-180, 180], geodetic latitude in
        degrees, ellipsoidal height in metres. NaN, all three, where a coordinate is NaN or
        infinite (PROJ gives no height there either); h is +inf where the distance from the
        centre overflows float64 (~1.8e308 m) although the coordinates do not.
    """
    x, y, z = np.broadcast_arrays(
        np.asarray(x, dtype=np.float64),
        np.asarray(y, dtype=np.float64),
        np.asarray(z, dtype=np.float64),
    )
    finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    extent = np.maximum(np.maximum(np.abs(x), np.abs(y)), np.abs(z))
    far = finite & (extent > FAR_FIELD_M)
    near = finite & ~far
    if near.all():
        lat, h = _closed_form(x, y, z, ellipsoid)
    else:
        # The closed form gets a stand-in (a point on the equator) for the points it does not
        # answer, so that none of its powers overflows; those are filled in below.
        lat, h = _closed_form(
            np.where(near, x, ellipsoid.a),
            np.where(near, y, 0.0),
            np.where(near, z, 0.0),
            ellipsoid,
        )
        lat = np.where(finite, lat, np.nan)
        h = np.where(finite, h, np.nan)
        if far.any():
            lat[far], h[far] = _far_field(x[far], y[far], z[far], extent[far], ellipsoid)
    with np.errstate(invalid="ignore"):  # atan2 of NaN is NaN, as wanted
        lon = _wrap_lon_deg(np.degrees(np.arctan2(y, x)))
    lon = np.where(finite, lon, np.nan)
    # [()] turns 0-d results (scalar input) into numpy scalars, leaving arrays alone.
    return lon[()], np.degrees(lat)[()], h[()]


def _closed_form(
    x: FloatArray, y: FloatArray, z: FloatArray, ellipsoid: Ellipsoid
) -> tuple[FloatArray, FloatArray]:
    """Vermeille's geodetic latitude (radians) and height (metres) of finite ECEF points
    (metres) nearer than `FAR_FIELD_M`."""
    a = ellipsoid.a
    e2 = ellipsoid.e2
    e4 = e2 * e2
    rho = np.hypot(x, y)

    # Vermeille's notation: p, q are the squared, a-normalised equatorial and polar parts.
    p = (rho / a) ** 2
    q = (1.0 - e2) * (z / a) ** 2
    r = (p + q - e4) / 6.0
    border = 8.0 * r**3 + e4 * p * q  # sign says outside (>0) or inside (<0) the evolute
    outside = border > 0.0
    general = outside | (q != 0.0)

    # Every branch is evaluated for every element and the right one picked with np.where, so
    # the branches that do not apply may produce NaN/inf: silence those warnings here only.
    with np.errstate(invalid="ignore", divide="ignore"):
        # Outside the evolute (almost everywhere): Cardano's real root.
        u_out, rad2 = _cardano_root(r, np.where(outside, border, 0.0), p, q, e2)
        # Inside the evolute (within ~43 km of the centre for WGS84): trigonometric root.
        rad1_in = np.sqrt(np.where(outside, 0.0, -border))
        rad2_in = np.sqrt(np.where(outside, 0.0, -8.0 * r**3))
        ang = 2.0 * np.arctan2(rad2, rad1_in + rad2_in) / 3.0
        u_in = -4.0 * r * np.sin(ang) * np.cos(np.pi / 6.0 + ang)
        u = np.where(outside, u_out, u_in)

        k, d, dz = _normal_terms(u, rho, z, q, e2)
        h_gen = (k + e2 - 1.0) * dz / k
        lat_gen = 2.0 * np.arctan2(z, dz + d)

        # Equatorial plane inside the evolute (q == 0, border <= 0), centre included: the
        # foot point is off the equator at cos(lat) = sqrt(p (1 - e2)) / (e sqrt(e2 - p)).
        # Derived directly (normals through (rho, 0) satisfy rho = N e2 cos(lat)).
        sqrt_p = np.sqrt(p)
        lat_eq = np.arctan2(np.sqrt(np.maximum(e4 - p, 0.0)), sqrt_p * np.sqrt(1.0 - e2))
        # At the centre of a sphere the expression is 0/0; call it the north pole, as for
        # the ellipsoid, so the centre has one answer for every ellipsoid.
        lat_eq = np.where(p == 0.0, np.pi / 2.0, lat_eq)
        sin_eq = np.sin(lat_eq)
        h_eq = -a * (1.0 - e2) / np.sqrt(1.0 - e2 * sin_eq * sin_eq)  # -N (1 - e2)

    return np.where(general, lat_gen, lat_eq), np.where(general, h_gen, h_eq)


def _far_field(
    x: FloatArray, y: FloatArray, z: FloatArray, extent: FloatArray, ellipsoid: Ellipsoid
) -> tuple[FloatArray, FloatArray]:
    """Geodetic latitude (radians) and height (metres) of ECEF points (metres) beyond
    `FAR_FIELD_M`, whose normal runs through the centre: the geocentric latitude, and the
    distance less the foot's n.foot = a sqrt(1 - e2 sin^2 lat). Computed on the coordinates
    divided by their largest (``extent``), so only a distance past float64 overflows (inf)."""
    xs, ys, zs = x / extent, y / extent, z / extent
    rho = np.hypot(xs, ys)
    lat = np.arctan2(zs, rho)
    with np.errstate(over="ignore"):
        dist = extent * np.hypot(rho, zs)
    sin_lat = np.sin(lat)
    return lat, dist - ellipsoid.a * np.sqrt(1.0 - ellipsoid.e2 * sin_lat * sin_lat)


def _cardano_root(
    r: FloatArray, border: FloatArray, p: FloatArray, q: FloatArray, e2: float
) -> tuple[FloatArray, FloatArray]:
    """Vermeille's u outside the evolute (``border`` > 0; elsewhere its value is not used),
    and sqrt(e^4 p q), which the inside root needs too."""
    e4 = e2 * e2
    rad1 = np.sqrt(border)
    rad2 = np.sqrt(e4 * p * q)
    cb_plus = np.cbrt((rad1 + rad2) ** 2)
    # Two algebraically equal forms; the first avoids rad1 - rad2 cancellation far out,
    # the second avoids dividing by a tiny cube root close to the evolute.
    u_far = r + 0.5 * cb_plus + 2.0 * r * r / cb_plus
    u_near = r + 0.5 * cb_plus + 0.5 * np.cbrt((rad1 - rad2) ** 2)
    return np.where(border > 10.0 * e2, u_far, u_near), rad2


def _normal_terms(
    u: FloatArray, rho: FloatArray, z: FloatArray, q: FloatArray, e2: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Vermeille's k, d and dz = hypot(d, z) from the root u: the geodetic normal at the foot
    point has direction (d x / rho, d y / rho, z) / dz, and the height is (k + e2 - 1) dz / k."""
    v = np.sqrt(u * u + e2 * e2 * q)
    w = e2 * (u + v - q) / (2.0 * v)
    k = (u + v) / (np.sqrt(w * w + u + v) + w)
    d = k * rho / (k + e2)
    return k, d, np.hypot(d, z)


def ecef_foot_points(
    points_ecef: ArrayLike, ellipsoid: Ellipsoid = WGS84
) -> tuple[FloatArray, FloatArray]:
    """Foot points on the ellipsoid (N, 3) ECEF m, along the geodetic normal, and heights
    (N,) m of ECEF points (N, 3) m: what `ecef_to_geodetic` then `lonlat_to_ecef` at h = 0
    give, without angles or the round trip (the same closed form; about a third of the
    numpy calls, which is what costs on small batches). Points inside the evolute (within
    ~43 km of the Earth's centre), beyond `FOOT_DIRECT_MAX_M` or not finite take that round
    trip (NaN feet and heights for NaN or infinite points)."""
    pts = np.asarray(points_ecef, dtype=np.float64).reshape(-1, 3)
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    a, e2 = ellipsoid.a, ellipsoid.e2
    rho = np.hypot(x, y)
    # Huge or infinite points overflow here; they are sent to the round trip just below.
    with np.errstate(over="ignore", invalid="ignore"):
        p = (rho / a) ** 2
        q = (1.0 - e2) * (z / a) ** 2
        r = (p + q - e2 * e2) / 6.0
        border = 8.0 * r**3 + e2 * e2 * p * q
    # r is about (distance / a)^2 / 6; NaN for a NaN point, which fails the test below too.
    r_direct_max = (FOOT_DIRECT_MAX_M / a) ** 2 / 6.0
    if not ((border > 0.0) & (r < r_direct_max)).all():
        lon, lat, h = ecef_to_geodetic(x, y, z, ellipsoid)
        foot = np.stack(geodetic_to_ecef(lon, lat, 0.0, ellipsoid), axis=-1).reshape(-1, 3)
        return foot, np.asarray(h, dtype=np.float64).reshape(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        u, _ = _cardano_root(r, border, p, q, e2)
    k, d, dz = _normal_terms(u, rho, z, q, e2)
    h = (k + e2 - 1.0) * dz / k
    # On the polar axis (rho = 0) the normal is (0, 0, sign z): any horizontal unit will do.
    c = d / (dz * np.where(rho > 0.0, rho, 1.0))
    n = np.stack([c * x, c * y, z / dz], axis=1)
    return pts - h[:, None] * n, h


def lonlat_to_ecef(
    lon: ArrayLike,
    lat: ArrayLike,
    h: ArrayLike = 0.0,
    ellipsoid: Ellipsoid = WGS84,
) -> FloatArray:
    """Convert geodetic coordinates to stacked ECEF points.

    Args:
        lon: longitude in degrees.
        lat: geodetic latitude in degrees.
        h: ellipsoidal height in metres (default: on the ellipsoid).
        ellipsoid: the reference ellipsoid.

    Returns:
        ECEF positions in metres, shape ``(..., 3)`` for inputs broadcasting to ``(...)``;
        NaN (all three) where the latitude is outside [-90, 90] or not finite.
    """
    return np.stack(geodetic_to_ecef(lon, lat, h, ellipsoid), axis=-1)


def ecef_to_lonlat(
    xyz: ArrayLike,
    ellipsoid: Ellipsoid = WGS84,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Convert stacked ECEF points ``(..., 3)`` in metres to ``(lon_deg, lat_deg, h_m)``.

    Each output has shape ``(...)``; see `ecef_to_geodetic` for conventions (NaN for NaN or
    infinite points).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.shape[-1:] != (3,):
        raise ValueError(f"expected an array of shape (..., 3), got {xyz.shape}")
    return ecef_to_geodetic(xyz[..., 0], xyz[..., 1], xyz[..., 2], ellipsoid)
