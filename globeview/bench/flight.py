"""Camera paths: a JSON list of keyframes interpolated by time (pure; no GL).

Format::

    {
      "name": "canyon run",
      "description": "...",
      "terrain": "embedded",            # or "big-dem" (benchmarks/make_big_dem.py)
      "keyframes": [
        {"t": 0.0, "lon": -71.3, "lat": 44.2, "height": 9000, "heading": 0, "pitch": -30},
        ...
      ]
    }

``t`` is in seconds and strictly increasing; lon/lat/heading/pitch in degrees, height in
metres above the ellipsoid. Between keyframes lon, lat and pitch are interpolated linearly,
height linearly in log(height) (so a descent from orbit slows down near the ground), and
lon/heading along the shorter way round the circle.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from globeview.errors import GlobeviewError

FIELDS = ("t", "lon", "lat", "height", "heading", "pitch")
TERRAINS = ("embedded", "big-dem")


class FlightError(GlobeviewError):
    """A camera path file is malformed."""


@dataclass(frozen=True)
class Pose:
    """One camera pose: degrees and metres."""

    lon: float
    lat: float
    height: float
    heading: float
    pitch: float

    def as_tuple(self) -> tuple[float, float, float, float, float]:
        return (self.lon, self.lat, self.height, self.heading, self.pitch)


def _wrap(deg: np.ndarray) -> np.ndarray:
    """Unwrap an angle sequence (degrees) so consecutive values differ by at most 180."""
    return np.degrees(np.unwrap(np.radians(deg)))


@dataclass
class Flight:
    """A camera path: keyframe arrays (sorted by time) plus a name and a terrain."""

    name: str
    t: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    height: np.ndarray
    heading: np.ndarray
    pitch: np.ndarray
    terrain: str = "embedded"
    description: str = ""

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @classmethod
    def from_dict(cls, data: dict, name: str = "flight") -> Flight:
        """Validate and build a flight from the parsed JSON object."""
        if not isinstance(data, dict) or not isinstance(data.get("keyframes"), list):
            raise FlightError(f"{name}: a flight is an object with a 'keyframes' list")
        frames = data["keyframes"]
        if len(frames) < 2:
            raise FlightError(f"{name}: a flight needs at least 2 keyframes")
        cols: dict[str, list[float]] = {f: [] for f in FIELDS}
        for i, kf in enumerate(frames):
            if not isinstance(kf, dict):
                raise FlightError(f"{name}: keyframe {i} is not an object")
            for f in FIELDS:
                if f not in kf:
                    raise FlightError(f"{name}: keyframe {i} lacks {f!r}")
                try:
                    v = float(kf[f])
                except (TypeError, ValueError):
                    raise FlightError(
                        f"{name}: keyframe {i} {f}={kf[f]!r} is not a number"
                    ) from None
                if not math.isfinite(v):
                    raise FlightError(f"{name}: keyframe {i} {f} is not finite")
                cols[f].append(v)
        arr = {f: np.asarray(v, dtype=np.float64) for f, v in cols.items()}
        if np.any(np.diff(arr["t"]) <= 0):
            raise FlightError(f"{name}: keyframe times must increase strictly")
        if np.any(arr["height"] <= 0):
            raise FlightError(f"{name}: heights must be > 0 m")
        if np.any(np.abs(arr["lat"]) > 90):
            raise FlightError(f"{name}: latitudes must lie in -90..90")
        terrain = str(data.get("terrain", "embedded"))
        if terrain not in TERRAINS:
            raise FlightError(f"{name}: terrain must be one of {', '.join(TERRAINS)}")
        return cls(
            name=str(data.get("name", name)),
            t=arr["t"],
            lon=_wrap(arr["lon"]),
            lat=arr["lat"],
            height=arr["height"],
            heading=_wrap(arr["heading"]),
            pitch=arr["pitch"],
            terrain=terrain,
            description=str(data.get("description", "")),
        )

    @classmethod
    def load(cls, path: str | Path) -> Flight:
        """Read a flight JSON file (FlightError on a missing or malformed file)."""
        p = Path(path)
        try:
            data = json.loads(p.read_text())
        except OSError as exc:
            raise FlightError(f"cannot read flight {p}: {exc.strerror or exc}") from None
        except json.JSONDecodeError as exc:
            raise FlightError(f"{p}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
        return cls.from_dict(data, name=p.stem)

    def pose(self, t: float) -> Pose:
        """The interpolated camera pose at time ``t`` (clamped to the path's span)."""
        t = float(np.clip(t, self.t[0], self.t[-1]))
        lon = float(np.interp(t, self.t, self.lon))
        lon = (lon + 180.0) % 360.0 - 180.0
        heading = float(np.interp(t, self.t, self.heading)) % 360.0
        return Pose(
            lon=lon,
            lat=float(np.interp(t, self.t, self.lat)),
            height=float(np.exp(np.interp(t, self.t, np.log(self.height)))),
            heading=heading,
            pitch=float(np.interp(t, self.t, self.pitch)),
        )

    def times(self, frames: int | None = None, fps: float | None = None) -> np.ndarray:
        """Sample times: ``frames`` evenly spaced over the path (ends included), or one every
        1/``fps`` seconds (a real-time flight at that frame rate)."""
        if frames is not None and fps is not None:
            raise ValueError("give frames or fps, not both")
        if fps is not None:
            if fps <= 0:
                raise ValueError("fps must be > 0")
            n = math.floor(self.duration * fps + 1e-9) + 1
            return self.t[0] + np.arange(n) / fps
        n = 60 if frames is None else int(frames)
        if n < 1:
            raise ValueError("frames must be >= 1")
        if n == 1:
            return self.t[:1].copy()
        return np.linspace(self.t[0], self.t[-1], n)


def shipped_flights_dir() -> Path:
    """The shipped camera paths: package data (globeview/bench/flights/), so `globeview bench`
    finds them after a wheel install too, not only in a source checkout."""
    return Path(__file__).resolve().parent / "flights"


def resolve_flight(name_or_path: str) -> Path:
    """A path as given, else a shipped flight by stem (``canyon`` -> bench/flights/...)."""
    p = Path(name_or_path)
    if p.exists():
        return p
    cand = shipped_flights_dir() / f"{name_or_path}.json"
    if cand.exists():
        return cand
    raise FlightError(f"no flight file {name_or_path!r} (nor a shipped flight of that name)")
