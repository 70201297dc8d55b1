"""Geodesy and terrain sampling for plugins (exported through `globeview.plugins.api`).

Frames and units as everywhere in the API: geodetic degrees on WGS84 (longitude east,
latitude north), azimuths in degrees clockwise from north, distances in metres along the
ellipsoid, ECEF metres (float64). Heights: ellipsoidal h (metres above WGS84, what the globe
draws), the EGM96 geoid undulation N, and the orthometric height H = h - N ("above sea
level"), exactly as ``globeview height`` reports them (`globeview.terrain.compose.height_query`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from globeview.errors import GlobeviewError
from globeview.geodesy import ecef_to_lonlat, lonlat_to_ecef
from globeview.geodesy.geodesic import geodesic_direct, geodesic_inverse

__all__ = [
    "TerrainSample",
    "ecef_to_lonlat",
    "geodesic_direct",
    "geodesic_inverse",
    "geodesic_samples",
    "lonlat_to_ecef",
    "sample_terrain",
]


def geodesic_samples(
    lon1: float, lat1: float, lon2: float, lat2: float, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` >= 2 points equally spaced along the geodesic from point 1 to point 2 (degrees),
    both ends included: ``(lons, lats, s_m)`` with ``s_m`` the distance along it from point 1
    (metres, 0 .. the geodesic length). Raises ValueError for ``n`` < 2."""
    n = int(n)
    if n < 2:
        raise ValueError(f"need at least 2 samples along a geodesic, got {n}")
    az12, _, dist = geodesic_inverse(lon1, lat1, lon2, lat2)
    s = np.linspace(0.0, float(dist), n)
    lons, lats, _ = geodesic_direct(lon1, lat1, az12, s)
    lons, lats = np.atleast_1d(lons).copy(), np.atleast_1d(lats).copy()
    # The ends are the points themselves (the direct solution agrees to nanometres; keep
    # them exact). pyproj already gives the others in [-180, 180].
    lons[0], lats[0], lons[-1], lats[-1] = lon1, lat1, lon2, lat2
    return lons, lats, s


@dataclass(frozen=True)
class TerrainSample:
    """Heights of the composed terrain at points (arrays of the points' shape, metres).

    ellipsoidal: h above WGS84 (what the mesh holds; 0 where no layer has data);
    undulation: N, the EGM96 geoid above the ellipsoid;
    orthometric: H = h - N (above the geoid, "a.s.l."), what ``globeview height`` calls H.
    """

    ellipsoidal: np.ndarray
    undulation: np.ndarray
    orthometric: np.ndarray


def sample_terrain(terrain: Any, lon: ArrayLike, lat: ArrayLike) -> TerrainSample:
    """Heights of the composed ``terrain`` (the context's `TerrainStack`, or None: the bare
    ellipsoid) at the points (degrees), from the finest level any visible layer has,
    interpolated as the mesh spans its nodes: the numbers ``globeview height`` prints.

    The heights have the points' shape: a scalar ``lon, lat`` gives 0-d arrays (``float()``
    of them works), arrays of shape S give arrays of shape S. Raises a one-line
    `GlobeviewError` for a bad point (NaN, |lat| > 90), for ``lon`` and ``lat`` of different
    shapes, or for unreadable terrain."""
    # Deferred (heavy): the API imports this module when a manifest is read, which must not
    # load the terrain.
    from globeview.terrain.compose.height_query import (
        check_lonlat,
        composed_heights,
        geoid_undulation,
    )

    shape = np.shape(lon)
    if np.shape(lat) != shape:
        raise GlobeviewError(
            f"{np.size(lon)} longitudes (shape {shape}) but {np.size(lat)} latitudes "
            f"(shape {np.shape(lat)})"
        )
    # The height queries work on flat point lists; the caller's shape is put back at the end
    # (a scalar came back as shape (1,), and float() of that raises under numpy 2).
    lon_a, lat_a = check_lonlat(np.ravel(lon), np.ravel(lat))
    if terrain is None or not terrain.visible_layers:
        h = np.zeros(lon_a.shape, dtype=np.float64)
    else:
        h = composed_heights(terrain, lon_a, lat_a)
    n = geoid_undulation(lon_a, lat_a)
    return TerrainSample(h.reshape(shape), n.reshape(shape), (h - n).reshape(shape))
