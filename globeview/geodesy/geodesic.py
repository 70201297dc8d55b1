"""Geodesics on the ellipsoid (shortest paths), via pyproj.Geod (Karney's algorithms).

Angles are degrees, azimuths clockwise from north, distances metres along the ellipsoid.
Unlike the conversions in `globeview.geodesy.transforms` (NaN for a bad element), these
refuse bad input with a ValueError naming the value (`globeview.validate`): a latitude
outside [-90, 90] or a NaN/infinite number. PROJ would answer NaN without a word, and a path
or a distance between places that do not exist is a caller's bug, not data.
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from pyproj import Geod

from globeview.geodesy.ellipsoid import WGS84, Ellipsoid
from globeview.validate import check_number, check_numbers

__all__ = ["geodesic_direct", "geodesic_inverse", "geodesic_points"]

FloatArray = NDArray[np.float64]


@functools.lru_cache(maxsize=16)
def _geod(ellipsoid: Ellipsoid) -> Geod:
    """A pyproj Geod for the ellipsoid (cached: the dataclass is frozen and hashable)."""
    from pyproj import Geod  # deferred: the window's launch needs no geodesic (issue #27)

    return Geod(a=ellipsoid.a, f=ellipsoid.f)


def _float_arrays(*values: ArrayLike) -> list[FloatArray]:
    # pyproj wants equal shapes and writable float64 buffers: broadcast, then copy.
    arrays = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in values))
    return [np.array(a, dtype=np.float64, copy=True) for a in arrays]


def _checked_point(which: str, lon: ArrayLike, lat: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Finite longitudes and latitudes in [-90, 90] (degrees) of ``which``, as float64;
    ValueError naming the first bad value otherwise."""
    return (
        check_numbers(f"longitude of {which}", lon, unit=" deg"),
        check_numbers(f"latitude of {which}", lat, -90.0, 90.0, " deg"),
    )


def _azimuth(az: ArrayLike) -> FloatArray:
    """Azimuths (degrees) from PROJ's [-180, 180] into (-180, 180]: due south is 180, and
    -0 is 0 (adding 0.0 turns -0.0 into 0.0)."""
    a = np.asarray(az, dtype=np.float64)
    return np.where(a <= -180.0, a + 360.0, a) + 0.0


def geodesic_inverse(
    lon1: ArrayLike,
    lat1: ArrayLike,
    lon2: ArrayLike,
    lat2: ArrayLike,
    ellipsoid: Ellipsoid = WGS84,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Solve the inverse geodesic problem between point 1 and point 2.

    Args:
        lon1, lat1, lon2, lat2: end points in degrees (broadcast together).
        ellipsoid: the reference ellipsoid.

    Returns:
        ``(azimuth12_deg, azimuth21_deg, distance_m)``: the azimuth at point 1 toward
        point 2, the azimuth at point 2 toward point 1 (the back azimuth), both in
        (-180, 180], and the geodesic distance in metres.

    Raises:
        ValueError: a longitude not finite, a latitude outside [-90, 90] or not finite.
    """
    a1, b1, a2, b2 = _float_arrays(
        *_checked_point("point 1", lon1, lat1), *_checked_point("point 2", lon2, lat2)
    )
    az12, az21, dist = _geod(ellipsoid).inv(a1, b1, a2, b2, return_back_azimuth=True)
    return (
        _azimuth(az12)[()],
        _azimuth(az21)[()],
        np.asarray(dist, dtype=np.float64)[()],
    )


def geodesic_direct(
    lon: ArrayLike,
    lat: ArrayLike,
    azimuth_deg: ArrayLike,
    distance_m: ArrayLike,
    ellipsoid: Ellipsoid = WGS84,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Solve the direct geodesic problem: travel ``distance_m`` from (lon, lat) at an azimuth.

    Args:
        lon, lat: start point in degrees.
        azimuth_deg: start azimuth in degrees, clockwise from north.
        distance_m: distance in metres (may be negative: travel backwards).
        ellipsoid: the reference ellipsoid.

    Returns:
        ``(lon2, lat2, back_azimuth_deg)``: end point in degrees (longitude in [-180, 180])
        and the azimuth at the end point pointing back toward the start, in (-180, 180].

    Raises:
        ValueError: a longitude, azimuth or distance not finite, a latitude outside
            [-90, 90] or not finite.
    """
    a, b, az, dist = _float_arrays(
        *_checked_point("the start point", lon, lat),
        check_numbers("azimuth", azimuth_deg, unit=" deg"),
        check_numbers("distance", distance_m, unit=" m"),
    )
    lon2, lat2, back = _geod(ellipsoid).fwd(a, b, az, dist, return_back_azimuth=True)
    return (
        np.asarray(lon2, dtype=np.float64)[()],
        np.asarray(lat2, dtype=np.float64)[()],
        _azimuth(back)[()],
    )


def geodesic_points(
    lon1: float,
    lat1: float,
    lon2: float,
    lat2: float,
    spacing_m: float,
    ellipsoid: Ellipsoid = WGS84,
) -> tuple[FloatArray, FloatArray]:
    """Densify one geodesic into equally spaced points, both end points included.

    Args:
        lon1, lat1, lon2, lat2: end points in degrees (scalars).
        spacing_m: the largest allowed distance between consecutive points, metres (> 0).
        ellipsoid: the reference ellipsoid.

    Returns:
        ``(lons, lats)`` in degrees, 1-D arrays of equal length >= 2, starting at point 1 and
        ending at point 2, consecutive points equally spaced by at most ``spacing_m``.

    Raises:
        ValueError: a bad spacing, a longitude not finite, a latitude outside [-90, 90] or
            not finite.
    """
    if not (spacing_m > 0 and math.isfinite(spacing_m)):
        raise ValueError(f"spacing must be a positive finite length in metres, got {spacing_m}")
    lon1 = check_number("longitude of point 1", lon1, -math.inf, math.inf, " deg")
    lat1 = check_number("latitude of point 1", lat1, -90.0, 90.0, " deg")
    lon2 = check_number("longitude of point 2", lon2, -math.inf, math.inf, " deg")
    lat2 = check_number("latitude of point 2", lat2, -90.0, 90.0, " deg")
    geod = _geod(ellipsoid)
    _, _, dist = geod.inv(lon1, lat1, lon2, lat2, return_back_azimuth=True)
    npts = max(math.ceil(dist / spacing_m) + 1, 2)
    line = geod.inv_intermediate(
        lon1,
        lat1,
        lon2,
        lat2,
        npts=npts,
        initial_idx=0,
        terminus_idx=0,
        return_back_azimuth=True,
    )
    return np.asarray(line.lons, dtype=np.float64), np.asarray(line.lats, dtype=np.float64)
