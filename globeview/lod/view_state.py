"""`ViewState`: everything an LOD provider needs to know about one frame's view.

All positions are ECEF metres in float64 on the CPU; the GPU never sees absolute ECEF
coordinates (relative-to-centre rendering, see tile_pool.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol

import numpy as np

from globeview.geodesy import WGS84, ecef_to_lonlat
from globeview.validate import check_exaggeration, check_tau

#: (1/a², 1/a², 1/b²) of WGS84: shaders scale an ECEF position by it to get the direction of
#: the geodetic normal there (the gradient of the ellipsoid equation).
INV_AXES2 = (1.0 / WGS84.a**2, 1.0 / WGS84.a**2, 1.0 / WGS84.b**2)


class CameraLike(Protocol):
    """What `ViewState.from_camera` reads of a camera (`globeview.model.camera.Camera`):
    ECEF eye (m), world-from-camera rotation, vertical field of view (degrees)."""

    eye: np.ndarray
    rotation: np.ndarray
    fovy_deg: float

    def clip_range(self, max_height_m: float) -> tuple[float, float]: ...

    def projection(self, aspect: float, near: float, far: float) -> np.ndarray: ...


@dataclass(frozen=True)
class ViewState:
    """One frame's view.

    Attributes:
        eye: camera position, ECEF metres, shape (3,), float64.
        rotation: rows (right, up, back) of the camera axes in ECEF (3x3, float64);
            ``rotation @ (p - eye)`` maps an ECEF point to camera coordinates.
        proj: OpenGL projection matrix (4x4, float64).
        viewport: (width, height) in pixels.
        fovy_deg: vertical field of view, degrees.
        near, far: clip distances, metres.
        speed_mps: navigation speed of the camera, metres per second (Rishe's HSpeed).
        tau_px: screen-space error threshold, pixels.
        exaggeration: vertical exaggeration applied to heights (1 = true relief).
        frame_rate_hz: the frame rate the navigation speed is measured against.
        displace: the active tool's vertex displacement on the CPU, (N, 3) ECEF -> (N, 3) ECEF
            (e.g. the terrain collapse), or None. LOD providers apply it to tile bounding
            points so culling and screen-space error see the terrain where it is drawn.
        displacement_bend: the active tool's cheap bound of how far ``displace`` bends straight
            edges, ``(points (N, K, 3), displaced (N, K, 3) | None) -> (N,)`` metres per
            tile bounding lattice (`Tool.displacement_bend_m`), or None: LOD providers then
            use the exact `culling.displacement_chord_error_m`. Call it through
            `culling.displacement_bend_m`, which picks.
        displacement_key: a hashable summary of ``displace`` from the tool
            (``displacement_key()``, e.g. the collapse's points and ratio): equal keys promise
            the same displacement, so providers may cache displaced tile data across frames
            under it; None when the tool gives none (providers then fingerprint ``displace``).
    """

    eye: np.ndarray
    rotation: np.ndarray
    proj: np.ndarray
    viewport: tuple[int, int]
    fovy_deg: float
    near: float
    far: float
    speed_mps: float = 0.0
    tau_px: float = 2.0
    exaggeration: float = 1.0
    frame_rate_hz: float = 30.0
    displace: Callable[[np.ndarray], np.ndarray] | None = field(default=None, compare=False)
    displacement_bend: Callable[[np.ndarray, np.ndarray | None], np.ndarray] | None = field(
        default=None, compare=False
    )
    displacement_key: object | None = field(default=None, compare=False)
    extras: dict = field(default_factory=dict, compare=False)

    @classmethod
    def from_camera(
        cls,
        camera: CameraLike,
        viewport: tuple[int, int],
        *,
        tau_px: float = 2.0,
        exaggeration: float = 1.0,
        speed_mps: float = 0.0,
        max_terrain_height: float = 9000.0,
        displace: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> ViewState:
        """The view of ``camera`` in a ``viewport`` (pixels). ValueError (one line) for a
        tau or exaggeration outside `validate.TAU_RANGE_PX` / `validate.EXAGGERATION_RANGE`
        or non-finite, and for an empty viewport: whatever set them (window, plugin, CLI)
        gets told, instead of the LOD selection dividing by zero or walking to NaN."""
        tau_px = check_tau(tau_px)
        exaggeration = check_exaggeration(exaggeration)
        w, h = int(viewport[0]), int(viewport[1])
        if w < 1 or h < 1:
            raise ValueError(f"viewport must be at least 1x1 pixels, not {w}x{h}")
        near, far = camera.clip_range(max_terrain_height * max(exaggeration, 1.0))
        proj = camera.projection(w / h, near, far)
        return cls(
            eye=np.asarray(camera.eye, dtype=np.float64).copy(),
            rotation=np.asarray(camera.rotation, dtype=np.float64).copy(),
            proj=proj,
            viewport=(w, h),
            fovy_deg=float(camera.fovy_deg),
            near=near,
            far=far,
            speed_mps=float(speed_mps),
            tau_px=float(tau_px),
            exaggeration=float(exaggeration),
            displace=displace,
        )

    # -- derived ---------------------------------------------------------------------------
    @property
    def aspect(self) -> float:
        return self.viewport[0] / self.viewport[1]

    @cached_property
    def sse_factor(self) -> float:
        """Pixels per metre of error at one metre distance: ``height / (2 tan(fovy / 2))``.

        A geometric error e (m) seen at distance d (m) covers ``e * sse_factor / d`` pixels.
        """
        return self.viewport[1] / (2.0 * math.tan(math.radians(self.fovy_deg) / 2.0))

    @cached_property
    def eye_lonlat_h(self) -> tuple[float, float, float]:
        """The eye's geodetic longitude, latitude (degrees) and height (m)."""
        lon, lat, h = ecef_to_lonlat(self.eye)
        return float(lon), float(lat), float(h)

    @cached_property
    def view(self) -> np.ndarray:
        """World (ECEF) -> camera 4x4 matrix with the translation, float64."""
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = -self.rotation @ self.eye
        return m

    @cached_property
    def frustum_planes(self) -> np.ndarray:
        """(6, 4) planes (n, d) in ECEF with n . p + d >= 0 inside: left, right, bottom, top,
        near, far. Normals are unit length, so n . p + d is a signed distance in metres."""
        t = math.tan(math.radians(self.fovy_deg) / 2.0)
        ta = t * self.aspect
        cam = np.array(
            [
                [1.0, 0.0, -ta, 0.0],
                [-1.0, 0.0, -ta, 0.0],
                [0.0, 1.0, -t, 0.0],
                [0.0, -1.0, -t, 0.0],
                [0.0, 0.0, -1.0, -self.near],
                [0.0, 0.0, 1.0, self.far],
            ]
        )
        cam[:, :3] /= np.linalg.norm(cam[:, :3], axis=1, keepdims=True)
        # The side planes pass through the eye; normalising keeps their d = 0.
        normals = cam[:, :3] @ self.rotation  # = (R^T n_cam)^T for each row
        d = cam[:, 3] - normals @ self.eye
        return np.concatenate([normals, d[:, None]], axis=1)

    def in_local_frames(
        self, origins: np.ndarray, bases: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The eye and frustum planes expressed in local frames (e.g. each tile's ENU frame).

        Args:
            origins: (N, 3) ECEF origins of the frames (m).
            bases: (N, 3, 3) rows = the frame's axes (E, N, U for ENU) in ECEF.

        Returns:
            eye_local (N, 3) metres, and planes_local (N, 6, 4) with n . p + d >= 0 inside.
        """
        origins = np.asarray(origins, dtype=np.float64)
        bases = np.asarray(bases, dtype=np.float64)
        eye_local = np.einsum("nij,nj->ni", bases, self.eye[None, :] - origins)
        planes = self.frustum_planes
        n_local = np.einsum("nij,pj->npi", bases, planes[:, :3])
        d_local = planes[None, :, 3] + origins @ planes[:, :3].T
        return eye_local, np.concatenate([n_local, d_local[..., None]], axis=2)

    def project(self, points_ecef: np.ndarray) -> np.ndarray:
        """Pixel coordinates (x right, y down from the top-left) and view depth of points.

        Returns (N, 3): x_px, y_px, depth_m (distance along the view axis; <= 0 behind).
        """
        p = np.atleast_2d(np.asarray(points_ecef, dtype=np.float64)) - self.eye
        cam = p @ self.rotation.T
        w = -cam[:, 2]
        t = math.tan(math.radians(self.fovy_deg) / 2.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            ndc_x = cam[:, 0] / (w * t * self.aspect)
            ndc_y = cam[:, 1] / (w * t)
        x = (ndc_x + 1.0) * 0.5 * self.viewport[0]
        y = (1.0 - ndc_y) * 0.5 * self.viewport[1]
        return np.stack([x, y, w], axis=1)

    def pixel_ray(self, x_px: float, y_px: float) -> np.ndarray:
        """Unit ECEF direction through the centre of pixel (x_px, y_px) (top-left origin)."""
        ndc_x = 2.0 * (x_px + 0.5) / self.viewport[0] - 1.0
        ndc_y = 1.0 - 2.0 * (y_px + 0.5) / self.viewport[1]
        t = math.tan(math.radians(self.fovy_deg) / 2.0)
        d_cam = np.array([ndc_x * t * self.aspect, ndc_y * t, -1.0])
        d = self.rotation.T @ d_cam
        return d / np.linalg.norm(d)
