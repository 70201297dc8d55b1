"""Reference ellipsoids of revolution (oblate spheroids) and their derived constants.

Lengths are metres. An ellipsoid is described by its equatorial semi-axis ``a`` and its
flattening ``f = (a - b) / a``; everything else is derived.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["GRS80", "SPHERE", "WGS84", "Ellipsoid"]


@dataclass(frozen=True)
class Ellipsoid:
    """An ellipsoid of revolution about the z (polar) axis.

    Attributes:
        name: human-readable name, e.g. ``"WGS84"``.
        a: equatorial semi-axis (semi-major axis) in metres.
        f: flattening ``(a - b) / a``, dimensionless; ``0`` makes a sphere.
    """

    name: str
    a: float
    f: float

    def __post_init__(self) -> None:
        # Reject nonsense early: every formula downstream divides by a, b or (1 - f).
        if not (self.a > 0 and math.isfinite(self.a)):
            raise ValueError(f"semi-major axis must be a positive finite length, got {self.a!r}")
        if not (0.0 <= self.f < 1.0):
            raise ValueError(f"flattening must lie in [0, 1), got {self.f!r}")

    @property
    def b(self) -> float:
        """Polar semi-axis (semi-minor axis) in metres: ``a (1 - f)``."""
        return self.a * (1.0 - self.f)

    @property
    def e2(self) -> float:
        """First eccentricity squared: ``(a² - b²) / a² = f (2 - f)``."""
        return self.f * (2.0 - self.f)

    @property
    def ep2(self) -> float:
        """Second eccentricity squared: ``(a² - b²) / b² = e² / (1 - e²)``."""
        return self.e2 / (1.0 - self.e2)


#: The World Geodetic System 1984 ellipsoid (GPS, EPSG:4326/4978/4979).
WGS84 = Ellipsoid("WGS84", 6378137.0, 1.0 / 298.257223563)

#: The Geodetic Reference System 1980 ellipsoid (ITRF, ETRS89, NAD83).
GRS80 = Ellipsoid("GRS80", 6378137.0, 1.0 / 298.257222101)

#: A sphere with the mean Earth radius (IUGG R1); handy in tests as a limiting case.
SPHERE = Ellipsoid("SPHERE", 6371008.8, 0.0)
