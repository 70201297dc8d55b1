"""The benchmark views: fixed camera poses over the embedded terrain that the render, LOD,
fragment and overlay benchmarks share, so their figures describe the same pictures.

Each pose is ``(lon deg, lat deg, height m above the ellipsoid, heading deg, pitch deg)``.
"""

from __future__ import annotations

Pose5 = tuple[float, float, float, float, float]

#: name -> pose.
VIEWS: dict[str, Pose5] = {
    "global": (0.0, 20.0, 2.0e7, 0.0, -90.0),
    "regional oblique (Alps, 300 km)": (8.0, 44.0, 3.0e5, 20.0, -35.0),
    "low-altitude oblique (White Mountains, 9 km)": (-71.3, 44.15, 9.0e3, 0.0, -30.0),
    "low-altitude oblique (Crater Lake, 6 km)": (-122.1, 42.85, 6.0e3, 200.0, -25.0),
}
