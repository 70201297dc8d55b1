"""Tours: camera keyframes and the seconds between them, interpolated as a flight over the
globe, saved as a small versioned JSON or TOML file (Qt-free, GL-free).

A `Tour` is a list of `Keyframe` poses. Each keyframe's ``seconds`` is the time the flight
from the previous keyframe takes to reach it; the first keyframe's ``seconds`` is a hold at
the start (the camera waits there), and a later keyframe with 0 seconds is a cut. Poses
follow the camera's conventions (`globeview.model.camera`): lon/lat geodetic degrees on
WGS84, height metres above the ellipsoid, heading degrees clockwise from north, pitch degrees
from the horizontal (-90 looks straight down), roll degrees turning the image clockwise.

Between two keyframes (`interpolate_keyframes`):

- the position follows the great circle through the two points (a spherical interpolation of
  their unit normals, so a flight across the antimeridian or over a pole takes the short way
  and never jumps);
- the height changes geometrically (equal zoom ratios in equal times: a descent from orbit
  slows down near the ground), linearly where either height is under 1 m;
- heading and roll turn the shorter way round, pitch changes linearly;
- time is eased with a smoothstep per leg (each keyframe is reached at rest), so a movie
  starts and ends still.

The file form is a plain dict (`tour_to_dict` / `tour_from_dict`) so another file (a project)
can embed a tour; `save_tour` / `load_tour` write and read it as ``.json`` or ``.toml``.
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from globeview.errors import GlobeviewError
from globeview.model.camera import check_lonlat_hpr
from globeview.validate import check_number

__all__ = [
    "TOUR_FORMAT",
    "TOUR_VERSION",
    "Keyframe",
    "Tour",
    "TourError",
    "interpolate_keyframes",
    "load_tour",
    "save_tour",
    "tour_from_dict",
    "tour_to_dict",
]

#: The ``format`` key every tour file carries.
TOUR_FORMAT = "globeview-tour"
#: The schema version this globeview writes and the newest it reads.
TOUR_VERSION = 1
#: Longest leg (seconds) a keyframe may take: a day.
MAX_LEG_S = 86_400.0
#: Most keyframes a tour may have.
MAX_KEYFRAMES = 10_000
#: Longest tour file `load_tour` reads (bytes).
MAX_FILE_BYTES = 4 * 1024 * 1024
#: The pose fields of a keyframe, in order.
POSE_FIELDS = ("lon", "lat", "height", "heading", "pitch", "roll")


class TourError(GlobeviewError):
    """A tour or a tour file that is not usable (one line)."""


@dataclass(frozen=True)
class Keyframe:
    """One camera pose of a tour and the seconds the flight to it takes.

    Attributes:
        lon, lat: geodetic degrees (WGS84); lon is stored in -180..180.
        height: metres above the WGS84 ellipsoid.
        heading: degrees clockwise from north (stored 0..360); pitch: degrees from the
            horizontal, -90..90; roll: degrees, turning the image clockwise (stored 0..360).
        seconds: time the flight from the previous keyframe takes (for the first: a hold
            at the start), 0..`MAX_LEG_S`.

    ValueError (one line naming the value and its range) for a value out of range or not
    finite (NaN included).
    """

    lon: float
    lat: float
    height: float
    heading: float = 0.0
    pitch: float = -90.0
    roll: float = 0.0
    seconds: float = 0.0

    def __post_init__(self) -> None:
        pose = check_lonlat_hpr(
            self.lon, self.lat, self.height, self.heading, self.pitch, self.roll
        )
        seconds = check_number("seconds", self.seconds, 0.0, MAX_LEG_S, " s")
        for name, value in zip((*POSE_FIELDS, "seconds"), (*pose, seconds), strict=True):
            object.__setattr__(self, name, float(value))

    @classmethod
    def from_pose(cls, pose: Sequence[float], seconds: float = 0.0) -> Keyframe:
        """A keyframe at ``pose`` = (lon, lat, height[, heading[, pitch[, roll]]])."""
        values = [float(v) for v in pose]
        if not 3 <= len(values) <= 6:
            raise ValueError(
                "a pose is (lon, lat, height[, heading[, pitch[, roll]]]), "
                f"not {len(values)} numbers"
            )
        return cls(*values, seconds=seconds)  # type: ignore[misc]

    @property
    def pose(self) -> tuple[float, float, float, float, float, float]:
        """(lon, lat, height, heading, pitch, roll): degrees and metres."""
        return (self.lon, self.lat, self.height, self.heading, self.pitch, self.roll)


@dataclass
class Tour:
    """Keyframes (in order) and a name; see the module's text for how it is flown."""

    keyframes: list[Keyframe] = field(default_factory=list)
    name: str = ""

    def add(self, keyframe: Keyframe) -> Keyframe:
        """Append ``keyframe``; TourError past `MAX_KEYFRAMES`."""
        if len(self.keyframes) >= MAX_KEYFRAMES:
            raise TourError(f"a tour holds at most {MAX_KEYFRAMES} keyframes")
        self.keyframes.append(keyframe)
        return keyframe

    def set_seconds(self, index: int, seconds: float) -> None:
        """Give keyframe ``index`` a new leg time (seconds; checked as `Keyframe` does)."""
        self.keyframes[index] = replace(self.keyframes[index], seconds=seconds)

    def times(self) -> np.ndarray:
        """Seconds from the start at which each keyframe is reached, (n,) float64."""
        return np.cumsum([k.seconds for k in self.keyframes], dtype=np.float64)

    @property
    def duration(self) -> float:
        """Seconds from the start to the last keyframe (0 for an empty tour)."""
        return float(self.times()[-1]) if self.keyframes else 0.0

    def pose_at(self, t: float) -> tuple[float, float, float, float, float, float]:
        """The camera pose ``t`` seconds into the tour (clamped to 0..duration)."""
        if not self.keyframes:
            raise TourError("the tour has no keyframes")
        times = self.times()
        t = min(max(float(t), 0.0), float(times[-1]))
        i = int(np.searchsorted(times, t, side="right"))
        if i <= 0:
            return self.keyframes[0].pose
        if i >= len(times):
            return self.keyframes[-1].pose
        leg = self.keyframes[i].seconds
        frac = (t - float(times[i - 1])) / leg if leg > 0.0 else 1.0
        return interpolate_keyframes(self.keyframes[i - 1], self.keyframes[i], smoothstep(frac))

    def frame_times(self, fps: float) -> np.ndarray:
        """The tour times (seconds) of a movie's frames at ``fps`` frames per second: about
        ``duration * fps`` frames (at least 2 for a tour that moves), evenly spaced, the
        first at the first keyframe and the last at the last one. One frame for a tour of
        duration 0."""
        if not self.keyframes:
            raise TourError("the tour has no keyframes")
        duration = self.duration
        n = max(2, round(duration * fps)) if duration > 0.0 else 1
        return np.linspace(0.0, duration, n) if n > 1 else np.zeros(1)


def smoothstep(s: float) -> float:
    """Ease in and out over a leg: 0 -> 0, 1 -> 1, zero speed at both ends."""
    s = min(max(s, 0.0), 1.0)
    return s * s * (3.0 - 2.0 * s)


def _wrap180(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


def _normal(lon: float, lat: float) -> np.ndarray:
    """The unit vector of (lon, lat) degrees on the sphere."""
    lo, la = math.radians(lon), math.radians(lat)
    return np.array([math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)])


def great_circle(a: tuple[float, float], b: tuple[float, float], s: float) -> tuple[float, float]:
    """(lon, lat) degrees a fraction ``s`` of the way from ``a`` to ``b`` along the great
    circle through them, the shorter arc (antipodes, where every great circle is as short:
    the one leaving ``a`` northward, or along the 0 meridian's plane from a pole)."""
    na, nb = _normal(*a), _normal(*b)
    dot = float(np.clip(na @ nb, -1.0, 1.0))
    omega = math.acos(dot)
    if omega < 1e-12:
        return a
    if math.pi - omega < 1e-9:  # antipodes: leave northward (or along a meridian at a pole)
        north = np.array([0.0, 0.0, 1.0]) - na * na[2]
        axis_dir = north if np.linalg.norm(north) > 1e-9 else np.array([1.0, 0.0, 0.0])
        axis_dir = axis_dir / np.linalg.norm(axis_dir)
        p = math.cos(math.pi * s) * na + math.sin(math.pi * s) * axis_dir
    else:
        p = (math.sin((1.0 - s) * omega) * na + math.sin(s * omega) * nb) / math.sin(omega)
    lat = math.degrees(math.asin(float(np.clip(p[2], -1.0, 1.0))))
    lon = math.degrees(math.atan2(float(p[1]), float(p[0]))) if abs(lat) < 90.0 - 1e-12 else a[0]
    return lon, lat


def interpolate_keyframes(
    a: Keyframe, b: Keyframe, s: float
) -> tuple[float, float, float, float, float, float]:
    """The pose a fraction ``s`` (0..1, already eased) of the way from ``a`` to ``b``:
    great-circle position, geometric height, shorter-way heading and roll, linear pitch.
    At 0 and 1, exactly ``a``'s and ``b``'s poses."""
    if s <= 0.0 or s >= 1.0:
        return a.pose if s <= 0.0 else b.pose
    lon, lat = great_circle((a.lon, a.lat), (b.lon, b.lat), s)
    if min(a.height, b.height) >= 1.0:
        height = math.exp(math.log(a.height) + (math.log(b.height) - math.log(a.height)) * s)
    else:
        height = a.height + (b.height - a.height) * s
    heading = (a.heading + _wrap180(b.heading - a.heading) * s) % 360.0
    roll = (a.roll + _wrap180(b.roll - a.roll) * s) % 360.0
    pitch = a.pitch + (b.pitch - a.pitch) * s
    return _wrap180(lon), lat, float(height), float(heading), float(pitch), float(roll)


# -- the file form ----------------------------------------------------------------------------
def tour_to_dict(tour: Tour) -> dict[str, Any]:
    """The tour as plain data (str, float, list, dict) for JSON or TOML, or for embedding in
    another file: ``{"format": "globeview-tour", "version": 1, "name": ..., "keyframes":
    [{"lon": ..., "lat": ..., "height": ..., "heading": ..., "pitch": ..., "roll": ...,
    "seconds": ...}, ...]}``."""
    return {
        "format": TOUR_FORMAT,
        "version": TOUR_VERSION,
        "name": tour.name,
        "keyframes": [
            {f.name: getattr(k, f.name) for f in fields(Keyframe)} for k in tour.keyframes
        ],
    }


def tour_from_dict(data: object, where: str = "tour") -> Tour:
    """A `Tour` from `tour_to_dict`'s form, every value checked. TourError, one line naming
    ``where`` and the keyframe (counted from 1), for anything else: not a tour, a newer
    version, a missing, unknown or non-numeric key, a value out of range (NaN included)."""
    if not isinstance(data, dict) or data.get("format") != TOUR_FORMAT:
        raise TourError(f"{where} is not a globeview tour (no format = {TOUR_FORMAT!r})")
    version = data.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise TourError(f"{where}: version must be a whole number >= 1, not {version!r:.40}")
    if version > TOUR_VERSION:
        raise TourError(
            f"{where} is tour version {version}, newer than this globeview reads "
            f"({TOUR_VERSION}); upgrade globeview"
        )
    name = data.get("name", "")
    frames = data.get("keyframes")
    if not isinstance(name, str):
        raise TourError(f"{where}: name must be text")
    if not isinstance(frames, list) or not frames:
        raise TourError(f"{where}: keyframes must be a non-empty list")
    if len(frames) > MAX_KEYFRAMES:
        raise TourError(f"{where}: {len(frames)} keyframes (at most {MAX_KEYFRAMES})")
    return Tour([_keyframe(k, f"{where}: keyframe {i}") for i, k in enumerate(frames, 1)], name)


def _keyframe(item: object, where: str) -> Keyframe:
    """One keyframe of the file form, checked (TourError naming ``where``)."""
    if not isinstance(item, dict):
        raise TourError(f"{where} must be a table of lon, lat, height, ... seconds")
    known = {f.name for f in fields(Keyframe)}
    unknown = sorted(set(item) - known)
    missing = [k for k in ("lon", "lat", "height") if k not in item]
    if unknown or missing:
        what = f"unknown key {unknown[0]!r}" if unknown else f"no {missing[0]}"
        raise TourError(f"{where}: {what} (keys: {', '.join(f.name for f in fields(Keyframe))})")
    bad = next(
        (k for k, v in item.items() if isinstance(v, bool) or not isinstance(v, int | float)), None
    )
    if bad is not None:
        raise TourError(f"{where}: {bad} must be a number, not {item[bad]!r:.40}")
    try:
        return Keyframe(**item)
    except ValueError as exc:
        raise TourError(f"{where}: {exc}") from None


def tour_text(tour: Tour, suffix: str) -> str:
    """The tour file's text: JSON for ``.json``, TOML for ``.toml``."""
    data = tour_to_dict(tour)
    if suffix == ".json":
        return json.dumps(data, indent=2) + "\n"
    lines = [f"{k} = {_toml_value(data[k])}" for k in ("format", "version", "name")]
    for kf in data["keyframes"]:
        lines += ["", "[[keyframes]]", *(f"{k} = {_toml_value(v)}" for k, v in kf.items())]
    return "\n".join(lines) + "\n"


def _toml_value(value: object) -> str:
    """A str, int or finite float as TOML writes it (JSON's string escapes are TOML's)."""
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


#: The file kinds a tour is saved and loaded as.
SUFFIXES = (".json", ".toml")


def save_tour(tour: Tour, path: str | os.PathLike[str]) -> Path:
    """Write ``tour`` to ``path`` (``.json`` or ``.toml``) atomically: nothing is left on
    failure. One line (`GlobeviewError`) for another suffix or a path that cannot be
    written."""
    from globeview.fileio import atomic_write_text, check_output_file

    out = Path(check_output_file(path, "tour", SUFFIXES))
    if not tour.keyframes:
        raise TourError("the tour has no keyframes; nothing written")
    return atomic_write_text(out, tour_text(tour, out.suffix.lower()))


def load_tour(path: str | os.PathLike[str]) -> Tour:
    """Read a tour file (`save_tour`'s ``.json`` or ``.toml``); one line (`TourError`) for
    a file that cannot be read or is not a tour."""
    p = Path(path)
    try:
        if p.stat().st_size > MAX_FILE_BYTES:
            raise TourError(f"{p}: over {MAX_FILE_BYTES // 2**20} MiB, not a tour file")
        raw = p.read_bytes()
    except OSError as exc:
        raise TourError(f"cannot read the tour {p}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
        data = tomllib.loads(text) if p.suffix.lower() == ".toml" else json.loads(text)
    except (UnicodeDecodeError, ValueError) as exc:  # JSON's and TOML's errors are ValueErrors
        kind = "TOML" if p.suffix.lower() == ".toml" else "JSON"
        why = " ".join(str(exc).split())[:120]
        raise TourError(f"{p} is not a globeview tour (not {kind}: {why})") from None
    return tour_from_dict(data, str(p))
