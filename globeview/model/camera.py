"""The globe camera: position and orientation in ECEF, float64 on the CPU.

Conventions
-----------
- The camera's own axes follow OpenGL: +x right, +y up, and it looks along -z.
  ``rotation`` holds them as rows (right, up, back) in ECEF, so a world point p maps to camera
  coordinates ``rotation @ (p - eye)``.
- ``heading`` (degrees) is the compass direction of the view, 0 = north, clockwise;
  ``pitch`` (degrees) is 0 looking level and -90 looking straight down; ``roll`` (degrees)
  turns the image clockwise about the view axis. These are Cesium's conventions, measured in
  the local ENU frame under the camera.
- Heights are metres above the WGS84 ellipsoid; lon/lat are geodetic degrees.

Two navigation styles share one state: the globe-orbit operations (``orbit_drag``,
``zoom_toward``, ``tilt_about``, ``rotate_heading_about``) move the camera around points on the
globe; the fly operations (``fly_pitch``, ``fly_yaw``, ``fly_forward``; thesis §3.4) move it
like an aircraft.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from globeview.geodesy import WGS84, ecef_to_lonlat, enu_basis, geodesic_inverse, lonlat_to_ecef
from globeview.validate import check_finite, check_number

#: Lowest height above the ellipsoid the navigation operations allow (m).
MIN_HEIGHT_M = 2.0
#: Highest camera height the navigation operations allow (m).
MAX_HEIGHT_M = 1.0e8
#: Heights (m above the ellipsoid) a camera may be placed at: from below the deepest ocean
#: trench (about -11 km) to far beyond the Moon; outside it the view is meaningless and the
#: clip planes and float32 eye-relative positions stop working.
HEIGHT_RANGE_M = (-12000.0, 1.0e9)
#: Vertical fields of view (degrees) a camera accepts: 0 collapses the projection, 180
#: makes it infinite.
FOV_RANGE_DEG = (1.0, 170.0)


def check_lonlat_hpr(
    lon: float, lat: float, height: float, heading: float, pitch: float, roll: float
) -> tuple[float, float, float, float, float, float]:
    """Validate a camera placement; returns it with lon in -180..180 and heading and roll in
    0..360 (huge but finite angles are reduced, not refused). ValueError, one line, for
    non-finite values, |lat| > 90, a height outside `HEIGHT_RANGE_M` or |pitch| > 90."""
    lon = check_finite("longitude", lon)
    lat = check_number("latitude", lat, -90.0, 90.0, " deg")
    height = check_number("height", height, *HEIGHT_RANGE_M, " m")
    heading = check_finite("heading", heading) % 360.0
    pitch = check_number("pitch", pitch, -90.0, 90.0, " deg")
    roll = check_finite("roll", roll) % 360.0
    return (lon + 180.0) % 360.0 - 180.0, lat, height, heading, pitch, roll


def rotation_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """3x3 rotation matrix turning vectors by ``angle_rad`` about the unit ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * (k @ k)


def rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction ``u`` onto direction ``v`` (both any length)."""
    u = np.asarray(u, dtype=np.float64) / np.linalg.norm(u)
    v = np.asarray(v, dtype=np.float64) / np.linalg.norm(v)
    axis = np.cross(u, v)
    s = np.linalg.norm(axis)
    c = float(np.clip(np.dot(u, v), -1.0, 1.0))
    if s < 1e-15:
        if c > 0:
            return np.eye(3)
        # Opposite directions: turn half a circle about any axis perpendicular to u.
        perp = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        return rotation_about(perp, math.pi)
    return rotation_about(axis / s, math.atan2(s, c))


def perspective(fovy_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """OpenGL perspective projection (camera space -> clip space), float64 4x4."""
    f = 1.0 / math.tan(math.radians(fovy_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0] = f / aspect
    m[1, 1] = f
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


@dataclass
class Camera:
    """A perspective camera in ECEF (metres, float64).

    ``eye`` is the camera position; ``rotation`` the rows (right, up, back) of its axes.
    ``fovy_deg`` is the vertical field of view in degrees.
    """

    eye: np.ndarray = field(default_factory=lambda: np.array([2.0e7, 0.0, 0.0]))
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    fovy_deg: float = 45.0

    def __post_init__(self) -> None:
        self.fovy_deg = check_number("field of view", self.fovy_deg, *FOV_RANGE_DEG, " deg")
        if not np.all(np.isfinite(self.eye)) or not np.all(np.isfinite(self.rotation)):
            raise ValueError("camera position and orientation must be finite numbers")

    # -- construction and read-back ---------------------------------------------------------
    @classmethod
    def from_lonlat(
        cls,
        lon: float,
        lat: float,
        height: float,
        heading: float = 0.0,
        pitch: float = -90.0,
        roll: float = 0.0,
        fovy_deg: float = 45.0,
    ) -> Camera:
        """A camera at (lon, lat, height) looking along (heading, pitch, roll), all degrees.

        ValueError (one line, naming the value and its valid range) for non-finite values,
        |lat| > 90, |pitch| > 90, a height outside `HEIGHT_RANGE_M` or a field of view
        outside `FOV_RANGE_DEG`; see `check_lonlat_hpr`.
        """
        cam = cls(fovy_deg=fovy_deg)
        cam.set_lonlat(lon, lat, height, heading, pitch, roll)
        return cam

    def set_lonlat(
        self,
        lon: float,
        lat: float,
        height: float,
        heading: float = 0.0,
        pitch: float = -90.0,
        roll: float = 0.0,
    ) -> None:
        """Place and orient the camera (see `from_lonlat`; same validation)."""
        lon, lat, height, heading, pitch, roll = check_lonlat_hpr(
            lon, lat, height, heading, pitch, roll
        )
        self.eye = np.asarray(lonlat_to_ecef(lon, lat, height), dtype=np.float64).reshape(3)
        self.rotation = _orientation(lon, lat, heading, pitch, roll)

    def lonlat_hpr(self) -> tuple[float, float, float, float, float, float]:
        """(lon, lat, height, heading, pitch, roll) in degrees and metres."""
        lon_a, lat_a, h_a = ecef_to_lonlat(self.eye)
        lon, lat, h = float(lon_a), float(lat_a), float(h_a)
        e, n, u = enu_basis(lon, lat)
        right, up, back = self.rotation
        fwd = -back
        pitch = math.degrees(math.asin(float(np.clip(fwd @ u, -1.0, 1.0))))
        # The horizontal right vector of an unrolled camera is cos(h) E - sin(h) N, which is
        # well defined even looking straight down, where the forward vector has no azimuth.
        r0 = np.cross(fwd, u)
        if np.linalg.norm(r0) < 1e-9:
            # Straight up/down: heading from the up vector (top of the image).
            top = up if pitch < 0 else -up
            heading = math.degrees(math.atan2(float(top @ e), float(top @ n)))
            roll = 0.0
        else:
            r0 /= np.linalg.norm(r0)
            heading = math.degrees(math.atan2(-float(r0 @ n), float(r0 @ e)))
            u0 = np.cross(r0, fwd)
            # right = cos(roll) r0 - sin(roll) u0 (see _orientation)
            roll = math.degrees(math.atan2(float(-(right @ u0)), float(right @ r0)))
        return lon, lat, h, heading % 360.0, pitch, roll

    # -- derived quantities --------------------------------------------------------------
    @property
    def right(self) -> np.ndarray:
        return self.rotation[0]

    @property
    def up(self) -> np.ndarray:
        return self.rotation[1]

    @property
    def forward(self) -> np.ndarray:
        return -self.rotation[2]

    @property
    def height(self) -> float:
        """Height above the ellipsoid (m)."""
        return float(ecef_to_lonlat(self.eye)[2])

    def clip_range(self, max_terrain_height: float = 9000.0) -> tuple[float, float]:
        """Near and far clip distances (m) for the current height.

        The far plane reaches past the horizon to the highest terrain that can peek over it:
        ``sqrt(h (2R + h)) + sqrt(H (2R + H))`` for camera height h and terrain height H.
        Depth precision does not come from these planes: the terrain shader writes a
        logarithmic depth (see shaders/log_depth.glsl), so the near plane can stay small.
        """
        r = WGS84.a
        h = max(self.height, 0.0)
        hmax = max(max_terrain_height, 0.0)
        far = math.sqrt(h * (2 * r + h)) + math.sqrt(hmax * (2 * r + hmax))
        far = max(far * 1.2, 1.0e4)
        near = max(0.1, min(1.0, h * 1e-4))
        return near, far

    def projection(self, aspect: float, near: float, far: float) -> np.ndarray:
        return perspective(self.fovy_deg, aspect, near, far)

    def ray(self, ndc_x: float, ndc_y: float, aspect: float) -> np.ndarray:
        """Unit ECEF direction of the ray through normalised device coordinates (-1..1)."""
        t = math.tan(math.radians(self.fovy_deg) / 2.0)
        d_cam = np.array([ndc_x * t * aspect, ndc_y * t, -1.0])
        d = self.rotation.T @ d_cam
        return d / np.linalg.norm(d)

    # -- globe-orbit navigation ----------------------------------------------------------
    def rotate_about_earth_axis(self, axis: np.ndarray, angle_rad: float) -> None:
        """Rotate position and orientation together about an axis through the Earth's centre."""
        rot = rotation_about(axis, angle_rad)
        self.eye = rot @ self.eye
        self.rotation = self.rotation @ rot.T

    def orbit_drag(self, grabbed_ecef: np.ndarray, target_ecef: np.ndarray) -> None:
        """Turn the globe so the point under the cursor follows it.

        ``grabbed_ecef`` was under the cursor before the move, ``target_ecef`` is where the
        cursor's ray meets the globe now; the camera turns about the Earth's centre by the
        rotation taking ``target`` onto ``grabbed``, which carries the grabbed point to the
        cursor.
        """
        rot = rotation_between(target_ecef, grabbed_ecef)
        self.eye = rot @ self.eye
        self.rotation = self.rotation @ rot.T

    def zoom_toward(self, target_ecef: np.ndarray, factor: float) -> None:
        """Move toward (factor < 1) or away from (factor > 1) a point, keeping orientation."""
        target = np.asarray(target_ecef, dtype=np.float64)
        new_eye = target + (self.eye - target) * factor
        h = float(ecef_to_lonlat(new_eye)[2])
        if MIN_HEIGHT_M <= h <= MAX_HEIGHT_M:
            self.eye = new_eye

    def tilt_about(self, pivot_ecef: np.ndarray, dpitch_deg: float) -> None:
        """Tilt the view about a pivot on the ground (rotate about the camera's right axis)."""
        self._rotate_about_point(pivot_ecef, self.right, math.radians(dpitch_deg))

    def rotate_heading_about(self, pivot_ecef: np.ndarray, dheading_deg: float) -> None:
        """Turn the view about the local vertical through a pivot on the ground."""
        pivot = np.asarray(pivot_ecef, dtype=np.float64)
        lon, lat, _ = ecef_to_lonlat(pivot)
        up = enu_basis(float(lon), float(lat))[2]
        self._rotate_about_point(pivot, up, -math.radians(dheading_deg))

    def _rotate_about_point(self, pivot: np.ndarray, axis: np.ndarray, angle: float) -> None:
        rot = rotation_about(axis, angle)
        new_eye = pivot + rot @ (self.eye - pivot)
        h = float(ecef_to_lonlat(new_eye)[2])
        if h < MIN_HEIGHT_M:
            return
        self.eye = new_eye
        self.rotation = self.rotation @ rot.T

    # -- fly navigation (thesis §3.4: pitch, yaw, forward/backward) ----------------------
    def fly_yaw(self, deg: float) -> None:
        """Turn left (deg < 0) or right about the local vertical, staying in place."""
        lon, lat, _ = ecef_to_lonlat(self.eye)
        up = enu_basis(float(lon), float(lat))[2]
        rot = rotation_about(up, -math.radians(deg))
        self.rotation = self.rotation @ rot.T

    def fly_pitch(self, deg: float) -> None:
        """Nose up (deg > 0) or down about the camera's right axis, staying in place."""
        rot = rotation_about(self.right, math.radians(deg))
        self.rotation = self.rotation @ rot.T

    def fly_forward(self, metres: float) -> None:
        """Move along the view direction (negative: backwards)."""
        new_eye = self.eye + self.forward * metres
        h = float(ecef_to_lonlat(new_eye)[2])
        if MIN_HEIGHT_M <= h <= MAX_HEIGHT_M:
            self.eye = new_eye

    def copy(self) -> Camera:
        return Camera(self.eye.copy(), self.rotation.copy(), self.fovy_deg)


def _orientation(lon: float, lat: float, heading: float, pitch: float, roll: float) -> np.ndarray:
    """Rows (right, up, back) in ECEF for a view (heading, pitch, roll) at (lon, lat)."""
    e, n, u = enu_basis(lon, lat)
    hd, pt, rl = math.radians(heading), math.radians(pitch), math.radians(roll)
    fwd = math.cos(pt) * (math.sin(hd) * e + math.cos(hd) * n) + math.sin(pt) * u
    right = math.cos(hd) * e - math.sin(hd) * n
    up = np.cross(right, fwd)
    if rl:
        # Roll turns the image clockwise: the right vector dips toward -up.
        right, up = (
            math.cos(rl) * right - math.sin(rl) * up,
            math.sin(rl) * right + math.cos(rl) * up,
        )
    rot = np.array([right, up, -fwd], dtype=np.float64)
    # Re-orthonormalise against rounding.
    u_, _, vt = np.linalg.svd(rot)
    return u_ @ vt


def camera_for_bounds(
    west: float, south: float, east: float, north: float, fovy_deg: float = 45.0
) -> Camera:
    """A camera looking straight down on a lon/lat box (degrees), high enough to see all of it."""
    if east < west:  # crosses the antimeridian
        east += 360.0
    lon = (west + east) / 2.0
    lon = (lon + 180.0) % 360.0 - 180.0
    lat = (south + north) / 2.0
    _, _, width = geodesic_inverse(west, lat, min(east, west + 179.9), lat)
    _, _, height = geodesic_inverse(lon, south, lon, north)
    extent = max(float(width), float(height), 1000.0)
    h = extent / (2.0 * math.tan(math.radians(fovy_deg) / 2.0)) * 1.3
    return Camera.from_lonlat(lon, lat, min(h, 2.5e7), 0.0, -90.0, fovy_deg=fovy_deg)
