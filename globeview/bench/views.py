"""The benchmark views: fixed camera poses over the embedded terrain that the render, LOD,
fragment and overlay benchmarks share, so their figures describe the same pictures.

Each pose is ``(lon deg, lat deg, height m above the ellipsoid, heading deg, pitch deg)``.
One view looks at each regional DEM of the embedded data (White Mountains N44W072, Crater
Lake, Vancouver topobathy), so each is benchmarked, not only the global base under it.
"""

from __future__ import annotations

Pose5 = tuple[float, float, float, float, float]

#: name -> pose.
VIEWS: dict[str, Pose5] = {
    "global": (0.0, 20.0, 2.0e7, 0.0, -90.0),
    "regional oblique (Alps, 300 km)": (8.0, 44.0, 3.0e5, 20.0, -35.0),
    "low-altitude oblique (White Mountains, 9 km)": (-71.3, 44.15, 9.0e3, 0.0, -30.0),
    # From south of the caldera looking north over it (the 30 m DEM spans -122.165..-122.050,
    # 42.904..42.979; until 2026-11 this view looked south-west, away from it).
    "low-altitude oblique (Crater Lake, 6 km)": (-122.108, 42.86, 6.0e3, 0.0, -25.0),
    # North-west up the Strait of Georgia, bathymetry and the Coast Mountains.
    "regional oblique (Vancouver topobathy, 60 km)": (-123.0, 48.6, 6.0e4, 315.0, -30.0),
}
