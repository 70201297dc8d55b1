"""Local tangent frames: East-North-Up (ENU) at a geodetic origin, and the surface normal.

ENU axes at geodetic (lon, lat): E points east (along increasing longitude), N points north
(along increasing latitude, tangent to the meridian) and U is the ellipsoid normal (geodetic
"up"). The frame is right-handed: E × N = U. Coordinates are metres; angles are degrees.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from globeview.geodesy.ellipsoid import WGS84, Ellipsoid
from globeview.geodesy.transforms import lonlat_to_ecef

__all__ = ["ecef_to_enu", "enu_basis", "enu_to_ecef", "surface_normal"]

FloatArray = NDArray[np.float64]


def enu_basis(lon_deg: ArrayLike, lat_deg: ArrayLike) -> FloatArray:
    """The ENU unit vectors at geodetic (lon, lat), expressed in ECEF.

    The basis depends only on the direction of the geodetic normal, so it needs no
    ellipsoid: the same (lon, lat) gives the same frame on any ellipsoid.

    Args:
        lon_deg: longitude in degrees.
        lat_deg: geodetic latitude in degrees.

    Returns:
        Array of shape ``(..., 3, 3)`` whose rows are E, N, U (ECEF components). It is the
        rotation matrix taking ECEF vectors to ENU components: ``enu = R @ ecef_vector``.
    """
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon, lat = np.broadcast_arrays(lon, lat)
    sl, cl = np.sin(lon), np.cos(lon)
    sp, cp = np.sin(lat), np.cos(lat)
    zero = np.zeros_like(lon)
    east = np.stack([-sl, cl, zero], axis=-1)
    north = np.stack([-sp * cl, -sp * sl, cp], axis=-1)
    up = np.stack([cp * cl, cp * sl, sp], axis=-1)
    return np.stack([east, north, up], axis=-2)


def ecef_to_enu(
    xyz: ArrayLike,
    origin_lon: ArrayLike,
    origin_lat: ArrayLike,
    origin_h: ArrayLike,
    ellipsoid: Ellipsoid = WGS84,
) -> FloatArray:
    """Express ECEF points in the ENU frame anchored at a geodetic origin.

    Args:
        xyz: ECEF positions in metres, shape ``(..., 3)``.
        origin_lon, origin_lat: origin longitude and geodetic latitude in degrees.
        origin_h: origin ellipsoidal height in metres.
        ellipsoid: the reference ellipsoid.

    Returns:
        ENU coordinates in metres (east, north, up), shape ``(..., 3)`` (broadcast with the
        origin's shape).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    origin = lonlat_to_ecef(origin_lon, origin_lat, origin_h, ellipsoid)
    basis = enu_basis(origin_lon, origin_lat)
    return np.einsum("...ij,...j->...i", basis, xyz - origin)


def enu_to_ecef(
    enu: ArrayLike,
    origin_lon: ArrayLike,
    origin_lat: ArrayLike,
    origin_h: ArrayLike,
    ellipsoid: Ellipsoid = WGS84,
) -> FloatArray:
    """Inverse of `ecef_to_enu`: ENU metres at a geodetic origin back to ECEF metres.

    Args:
        enu: local (east, north, up) coordinates in metres, shape ``(..., 3)``.
        origin_lon, origin_lat: origin longitude and geodetic latitude in degrees.
        origin_h: origin ellipsoidal height in metres.
        ellipsoid: the reference ellipsoid.

    Returns:
        ECEF positions in metres, shape ``(..., 3)``.
    """
    enu = np.asarray(enu, dtype=np.float64)
    origin = lonlat_to_ecef(origin_lon, origin_lat, origin_h, ellipsoid)
    basis = enu_basis(origin_lon, origin_lat)
    # The basis is orthonormal, so its transpose is its inverse.
    return origin + np.einsum("...ji,...j->...i", basis, enu)


def surface_normal(xyz: ArrayLike, ellipsoid: Ellipsoid = WGS84) -> FloatArray:
    """Unit outward normal of the ellipsoid surface through a point, in ECEF.

    It is the normalised gradient of ``x²/a² + y²/a² + z²/b²``. For a point on the
    ellipsoid this is exactly the geodetic "up" (U of `enu_basis`); for a point off the
    surface it is the normal of the similar (scaled) ellipsoid through that point, which is
    close to but not exactly the geodetic normal at that point's foot.

    Args:
        xyz: ECEF positions in metres, shape ``(..., 3)``; not the centre of the Earth.
        ellipsoid: the reference ellipsoid.

    Returns:
        Unit vectors, shape ``(..., 3)``.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    # Scale by a² rather than dividing by a² and b²: same direction, no tiny numbers.
    ratio = (ellipsoid.a / ellipsoid.b) ** 2
    grad = xyz * np.array([1.0, 1.0, ratio])
    return grad / np.linalg.norm(grad, axis=-1, keepdims=True)
