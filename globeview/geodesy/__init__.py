"""Geodesy: the WGS84 ellipsoid, geodetic<->ECEF, local tangent (ENU) frames, rays.

Pure numpy/pyproj, float64, vectorised over arrays. Angles are degrees unless a name says
radians; lengths are metres; ECEF is the Earth-centred, Earth-fixed frame of the ellipsoid.
"""

from globeview.geodesy.ellipsoid import GRS80, SPHERE, WGS84, Ellipsoid
from globeview.geodesy.enu import ecef_to_enu, enu_basis, enu_to_ecef, surface_normal
from globeview.geodesy.geodesic import geodesic_direct, geodesic_inverse, geodesic_points
from globeview.geodesy.rays import ray_ellipsoid_intersection, ray_ellipsoid_t
from globeview.geodesy.transforms import (
    ecef_foot_points,
    ecef_to_geodetic,
    ecef_to_lonlat,
    geodetic_to_ecef,
    lonlat_to_ecef,
)

__all__ = [
    "GRS80",
    "SPHERE",
    "WGS84",
    "Ellipsoid",
    "ecef_foot_points",
    "ecef_to_enu",
    "ecef_to_geodetic",
    "ecef_to_lonlat",
    "enu_basis",
    "enu_to_ecef",
    "geodesic_direct",
    "geodesic_inverse",
    "geodesic_points",
    "geodetic_to_ecef",
    "lonlat_to_ecef",
    "ray_ellipsoid_intersection",
    "ray_ellipsoid_t",
    "surface_normal",
]
