"""`measure`: distance, azimuth and terrain profile between two picked points.

Written only against the public plugin API (`globeview.plugins.api`), as a third-party tool
would be: it is the example of a tool that publishes a plot.

Pick A, then B (left clicks on the terrain; a third click starts a new pair, Escape clears:
the API's `TwoPointPick`):

- the geodesic distance A-B on the WGS84 ellipsoid (Karney's algorithm, via pyproj), the
  forward azimuth at A (toward B) and the back azimuth at B (toward A), degrees clockwise
  from north in [0, 360);
- the straight-line (chord) distance between A and B in ECEF at their terrain heights;
- a terrain profile: ``samples`` points equally spaced along the geodesic, each with the
  composed terrain's orthometric height H (metres above the EGM96 geoid, as ``globeview
  height`` prints it), published as a `Plot` (the window shows it in its Plot dock; CSV
  columns distance_m, lon, lat, height_m).

The geodesic is drawn on the terrain (depth-tested, lifted `LINE_LIFT_M`), the chord
optionally. The measurement text goes to the status line and labels B's marker.
Headless: ``set_points([(lon_a, lat_a), (lon_b, lat_b)])`` measures without events.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from globeview.plugins.api import (
    GlobeviewError,
    KeyEvent,
    Marker,
    Overlay,
    Plot,
    PointerEvent,
    Polyline,
    Setting,
    Tool,
    TwoPointPick,
    geodesic_inverse,
    geodesic_samples,
    lonlat_to_ecef,
    sample_terrain,
)

__all__ = ["MeasureTool", "Measurement"]

#: Metres in one statute mile / one kilometre (the ``units`` setting).
UNIT_M = {"km": 1000.0, "mi": 1609.344}
#: The geodesic line is drawn this far above the terrain (m, before exaggeration), so the
#: depth test does not hide it under a coarser tile's triangles.
LINE_LIFT_M = 30.0
#: At least this many points draw the geodesic (fewer profile samples would cut corners).
MIN_LINE_POINTS = 65
MARKER_RGBA = (0.1, 0.8, 1.0, 1.0)
LINE_RGBA = (0.1, 0.8, 1.0, 1.0)
CHORD_RGBA = (1.0, 0.5, 0.9, 0.9)


def _azimuth_0_360(az_deg: float) -> float:
    """An azimuth in (-180, 180] as [0, 360) degrees clockwise from north."""
    a = float(az_deg) % 360.0
    return 0.0 if a == 360.0 else a


@dataclass(frozen=True)
class Measurement:
    """One A-B measurement. Angles degrees, lengths metres, heights metres.

    a, b: (lon, lat) degrees; distance_m: geodesic length on WGS84; chord_m: straight ECEF
    distance between A and B at their terrain heights (h_a, h_b ellipsoidal);
    azimuth_deg: at A toward B; back_azimuth_deg: at B toward A (both [0, 360));
    profile_s_m, profile_lon, profile_lat: the samples along the geodesic (distance from A,
    degrees); profile_h_m: orthometric terrain height H there (NaN where it could not be
    read); profile_ellipsoidal_m: h there (for drawing).
    """

    a: tuple[float, float]
    b: tuple[float, float]
    distance_m: float
    chord_m: float
    azimuth_deg: float
    back_azimuth_deg: float
    h_a: float
    h_b: float
    profile_s_m: np.ndarray
    profile_lon: np.ndarray
    profile_lat: np.ndarray
    profile_h_m: np.ndarray
    profile_ellipsoidal_m: np.ndarray

    def text(self, units: str = "km") -> str:
        """One line for the status bar: geodesic, chord, azimuths."""
        u = UNIT_M.get(units, 1000.0)
        return (
            f"measure: {self.distance_m / u:,.3f} {units} geodesic, "
            f"{self.chord_m / u:,.3f} {units} straight; "
            f"azimuth {self.azimuth_deg:.2f}\N{DEGREE SIGN} at A, "
            f"back {self.back_azimuth_deg:.2f}\N{DEGREE SIGN} at B"
        )


class MeasureTool(Tool):
    """Measure between two picked points (see the module docstring).

    Settings: ``samples`` (profile points along the geodesic), ``units`` (km or mi for
    distances; heights stay metres), ``show_chord`` (draw the straight line too).
    """

    name = "measure"
    label = "Measure"
    settings = (
        Setting("samples", "int", 256, min=2, max=4096, label="Profile samples",
                help="Points along the geodesic where the terrain height is sampled (count)."),
        Setting("units", "choice", "km", choices=("km", "mi"), label="Units",
                help="Unit of distances (kilometres or statute miles); heights are metres."),
        Setting("show_chord", "bool", False, label="Show chord",
                help="Also draw the straight line (through the Earth) from A to B."),
    )  # fmt: skip

    def __init__(self, context: Any = None) -> None:
        super().__init__(context)
        #: A and B, (lon, lat) degrees: picked by clicks or set by `set_points`.
        self.pick = TwoPointPick()
        self.measurement: Measurement | None = None
        self._plot: Plot | None = None
        self._measured_on: tuple[int, Any] | None = None  # `_terrain_key` of the heights
        self._line: np.ndarray | None = None  # (N, 3): lon, lat (degrees), h ellipsoidal (m)

    # -- settings and state ------------------------------------------------------------------
    def configure(self, values: dict[str, Any]) -> None:
        old = dict(self.values)
        super().configure(values)
        if self.b is not None and old.get("samples") != self.values["samples"]:
            self._measure()  # a new profile with the new sample count
        elif old.get("units") != self.values["units"]:
            self._plot = None  # the axis unit changed
            if self.measurement is not None:
                self.set_status(self.measurement.text(self.units))
        self.request_redraw()

    @property
    def units(self) -> str:
        return str(self.values.get("units", "km"))

    @property
    def a(self) -> tuple[float, float] | None:
        """Point A, (lon, lat) degrees, or None."""
        return self.pick.a

    @property
    def b(self) -> tuple[float, float] | None:
        """Point B, (lon, lat) degrees, or None."""
        return self.pick.b

    @property
    def state(self) -> str:
        """'idle' (no point), 'a_set' (A picked), 'measured' (A and B)."""
        if self.a is None:
            return "idle"
        return "a_set" if self.b is None else "measured"

    def clear(self) -> None:
        """Drop both points and the measurement."""
        self.pick.clear()
        self._forget()
        self.request_redraw()

    def _forget(self) -> None:
        """Drop the measurement (not the points)."""
        self.measurement, self._plot, self._line = None, None, None

    def set_points(self, points: Sequence[Sequence[float]]) -> Measurement | None:
        """Headless input: one (lon, lat) sets A, two set A and B and measure (degrees).
        Returns the measurement (None for one point). Raises ValueError for anything else
        (a one-line message: wrong count, not numbers, NaN, latitude beyond 90)."""
        pts = [tuple(p) for p in points]
        if not 1 <= len(pts) <= 2 or any(len(p) < 2 for p in pts):
            raise ValueError(f"measure takes 1 or 2 points (LON,LAT), got {len(pts)}")
        checked = [self._checked(p[0], p[1]) for p in pts]
        self.clear()
        self.pick.a = checked[0]
        if len(checked) == 2:
            self.pick.b = checked[1]
            return self._measure()
        return None

    def place_points(self, points: Sequence[Sequence[float]]) -> bool:
        """The host's headless entry (``globeview render --tool measure --points A;B``):
        `set_points`, with refused points as a one-line `GlobeviewError` for the user."""
        try:
            self.set_points(points)
        except ValueError as exc:
            raise GlobeviewError(str(exc)) from None
        return True

    @staticmethod
    def _checked(lon: Any, lat: Any) -> tuple[float, float]:
        try:
            lon_f, lat_f = float(lon), float(lat)
        except (TypeError, ValueError):
            raise ValueError(f"measure: point {lon!r},{lat!r} is not two numbers") from None
        if not (np.isfinite(lon_f) and np.isfinite(lat_f)) or abs(lat_f) > 90.0:
            raise ValueError(
                f"measure: point {lon_f:g},{lat_f:g}: longitude must be finite "
                "and latitude in -90..90"
            )
        return lon_f, lat_f

    # -- the measurement ---------------------------------------------------------------------
    def _terrain(self) -> Any:
        return getattr(self.context, "terrain", None)

    def _heights(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(orthometric H, ellipsoidal h) of the context's terrain at the points; NaN and 0
        where the terrain cannot be read (said once in the status line)."""
        try:
            s = sample_terrain(self._terrain(), lon, lat)
        except GlobeviewError as exc:
            self.set_status(f"measure: no terrain heights ({exc})")
            nan = np.full(np.shape(lon), np.nan)
            return nan, np.zeros(np.shape(lon))
        return np.asarray(s.orthometric, np.float64), np.asarray(s.ellipsoidal, np.float64)

    def _measure(self) -> Measurement:
        """Measure A-B now (both set), publish the status text, drop the cached plot."""
        assert self.a is not None and self.b is not None
        (lon_a, lat_a), (lon_b, lat_b) = self.a, self.b
        az12, az21, dist = geodesic_inverse(lon_a, lat_a, lon_b, lat_b)
        n = int(self.values["samples"])
        lons, lats, s = geodesic_samples(lon_a, lat_a, lon_b, lat_b, n)
        h_orth, h_ell = self._heights(lons, lats)
        ends = np.asarray(
            lonlat_to_ecef(np.array([lon_a, lon_b]), np.array([lat_a, lat_b]), h_ell[[0, -1]])
        ).reshape(2, 3)
        m = Measurement(
            (lon_a, lat_a),
            (lon_b, lat_b),
            float(dist),
            float(np.linalg.norm(ends[1] - ends[0])),
            _azimuth_0_360(az12),
            _azimuth_0_360(az21),
            float(h_ell[0]),
            float(h_ell[-1]),
            s,
            lons,
            lats,
            h_orth,
            h_ell,
        )
        self.measurement, self._plot = m, None
        self._measured_on = self._terrain_key()
        if n >= MIN_LINE_POINTS:
            self._line = np.stack([lons, lats, h_ell], axis=1)
        else:  # too few samples to follow the curve: a denser line for drawing only
            ll, la, _ = geodesic_samples(lon_a, lat_a, lon_b, lat_b, MIN_LINE_POINTS)
            self._line = np.stack([ll, la, self._heights(ll, la)[1]], axis=1)
        self.set_status(m.text(self.units))
        self.request_redraw()
        return m

    def _terrain_key(self) -> tuple[int, Any]:
        """Identifies the terrain the heights came from: the stack object and its change
        counter (a DEM opened, hidden or reordered changes it)."""
        terrain = self._terrain()
        return id(terrain), getattr(terrain, "version", None)

    def plot(self) -> Plot | None:
        """The terrain profile A->B (distance in the chosen unit, height in metres), the
        same object until the measurement, the unit or the terrain changes (then A-B is
        measured again, so the profile is always the terrain drawn now); None before B."""
        if self.measurement is not None and self._measured_on != self._terrain_key():
            self._measure()
        m = self.measurement
        if m is None:
            return None
        if self._plot is None:
            units = self.units
            self._plot = Plot(
                title=f"Terrain profile A\N{RIGHTWARDS ARROW}B, {m.text(units)[9:]}",
                x=m.profile_s_m / UNIT_M[units],
                y=m.profile_h_m,
                x_label=f"distance from A ({units})",
                y_label="height above geoid (m)",
                columns={
                    "distance_m": m.profile_s_m,
                    "lon": m.profile_lon,
                    "lat": m.profile_lat,
                    "height_m": m.profile_h_m,
                },
            )
        return self._plot

    # -- events ------------------------------------------------------------------------------
    def on_mouse(self, event: PointerEvent) -> bool:
        """Left press on terrain: first sets A, second sets B and measures; a press after
        that starts a new pair (`TwoPointPick`)."""
        step = self.pick.on_mouse(event)
        if step == "a":
            lon, lat = self.pick.a  # the point just picked
            self._forget()
            self.set_status(f"measure: A at {lon:.5f}, {lat:.5f}; pick B")
            self.request_redraw()
        elif step == "b":
            self._measure()
        return step is not None

    def on_key(self, event: KeyEvent) -> bool:
        """Escape clears the points (the host also leaves the tool on Escape)."""
        if not self.pick.on_key(event):
            return False
        self._forget()
        self.request_redraw()
        return True

    def deactivate(self) -> None:
        """Leaving the tool forgets the measurement."""
        self.clear()

    # -- overlay -----------------------------------------------------------------------------
    def overlay(self, view: Any) -> list[Overlay]:
        """Markers at A and B (on the ellipsoid: the host drapes them on the terrain), the
        geodesic on the terrain (with the view's exaggeration, lifted `LINE_LIFT_M`), and
        the chord between the terrain points when ``show_chord`` is on."""
        out: list[Overlay] = []
        m = self.measurement
        for p, label in ((self.a, "A"), (self.b, "B")):
            if p is not None:
                if label == "B" and m is not None:
                    label = f"B {m.distance_m / UNIT_M[self.units]:,.2f} {self.units}"
                pos = np.asarray(lonlat_to_ecef(p[0], p[1], 0.0), np.float64).ravel()
                out.append(Marker(tuple(float(v) for v in pos), MARKER_RGBA, 10.0, label))
        if m is None or self._line is None:
            return out
        exag = float(getattr(view, "exaggeration", 1.0) or 1.0)
        line = self._line
        pts = np.asarray(
            lonlat_to_ecef(line[:, 0], line[:, 1], line[:, 2] * exag + LINE_LIFT_M), np.float64
        ).reshape(-1, 3)
        out.append(Polyline(pts, LINE_RGBA, 3.0))
        if self.values.get("show_chord"):
            out.append(Polyline(pts[[0, -1]], CHORD_RGBA, 2.0))
        return out
