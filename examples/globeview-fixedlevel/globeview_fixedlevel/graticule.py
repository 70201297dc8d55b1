"""`GraticuleLayerType`: a layer type with a file format of its own, ``.graticule``.

A ``.graticule`` file is UTF-8 text, one ``key = value`` per line; ``#`` starts a comment,
blank lines are ignored, every key is optional::

    # lines every 15 degrees, parallels every 10
    step_deg = 15           # spacing of parallels and meridians, degrees (0.5 .. 90)
    lat_step_deg = 10       # parallels only (overrides step_deg)
    lon_step_deg = 15       # meridians only (overrides step_deg)
    color = 1 1 1 0.6       # RGBA, each 0..1
    width_px = 1.5          # line width, screen pixels (0.5 .. 10)

``open`` returns data, not GL objects: one `Lines` drawable (the plugin API's drawable
primitives) with ``interpolation="rhumb"``, under which a segment between two points of the
same latitude stays on that parallel and a meridian stays a meridian; the host densifies,
drapes and draws it. Bad input raises `GlobeviewError` naming the file and line (one line).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from globeview.plugins.api import GlobeviewError, LayerType, Lines

#: Largest .graticule file read (bytes): the format is a handful of lines.
MAX_BYTES = 64 * 1024
#: Allowed spacing of the lines, degrees (finer would draw tens of thousands of lines).
STEP_RANGE = (0.5, 90.0)
WIDTH_RANGE = (0.5, 10.0)
DEFAULTS: dict[str, object] = {"step_deg": 15.0, "color": (1.0, 1.0, 1.0, 0.6), "width_px": 1.5}
KEYS = ("step_deg", "lat_step_deg", "lon_step_deg", "color", "width_px")


def read_graticule(path: str | Path) -> dict[str, object]:
    """The settings of a ``.graticule`` file (missing keys take `DEFAULTS`), checked.

    Returns a dict with ``lat_step_deg``, ``lon_step_deg`` (degrees), ``color`` (RGBA) and
    ``width_px``. Raises `GlobeviewError` ("FILE:LINE: what is wrong") for bad input.
    """
    p = Path(path)
    try:
        if p.stat().st_size > MAX_BYTES:
            raise GlobeviewError(f"{p}: not a graticule file (larger than {MAX_BYTES} bytes)")
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise GlobeviewError(f"{p}: not a graticule file (not UTF-8 text)") from None
    except OSError as exc:
        raise GlobeviewError(f"{p}: cannot read: {exc.strerror or exc}") from None
    values: dict[str, object] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"{p}:{number}"
        key, sep, value = (part.strip() for part in line.partition("="))
        if not sep or not key:
            raise GlobeviewError(f"{where}: expected 'key = value', got {line[:40]!r}")
        if key not in KEYS:
            raise GlobeviewError(f"{where}: unknown key {key[:40]!r} (known: {', '.join(KEYS)})")
        if key in values:
            raise GlobeviewError(f"{where}: {key} given twice")
        values[key] = _parse(key, value, where)
    step = values.get("step_deg", DEFAULTS["step_deg"])
    return {
        "lat_step_deg": values.get("lat_step_deg", step),
        "lon_step_deg": values.get("lon_step_deg", step),
        "color": values.get("color", DEFAULTS["color"]),
        "width_px": values.get("width_px", DEFAULTS["width_px"]),
    }


def _number(text: str, where: str, key: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise GlobeviewError(f"{where}: {key}: {text[:40]!r} is not a number") from None
    if not math.isfinite(v):
        raise GlobeviewError(f"{where}: {key}: {text[:40]!r} is not a finite number")
    return v


def _parse(key: str, value: str, where: str) -> object:
    """One checked value of ``key``."""
    if key == "color":
        parts = value.split()
        if len(parts) != 4:
            raise GlobeviewError(
                f"{where}: color needs 4 numbers R G B A (0..1), not {value[:40]!r}"
            )
        rgba = tuple(_number(v, where, key) for v in parts)
        if not all(0.0 <= c <= 1.0 for c in rgba):
            raise GlobeviewError(f"{where}: color components must be within 0..1")
        return rgba
    lo, hi = WIDTH_RANGE if key == "width_px" else STEP_RANGE
    v = _number(value, where, key)
    if not lo <= v <= hi:
        raise GlobeviewError(f"{where}: {key} {v:g} is outside {lo:g}..{hi:g}")
    return v


def graticule_paths(lat_step: float, lon_step: float) -> list[np.ndarray]:
    """Parallels every ``lat_step`` degrees (poles excluded, the equator included) and
    meridians every ``lon_step`` degrees from -180, as (N, 2) (lon, lat) polylines.

    Parallels have a vertex every 90 degrees of longitude (the host's rhumb interpolation
    fills in, staying on the parallel); meridians run pole to pole (the host stops rhumb
    lines just short of the poles)."""
    paths: list[np.ndarray] = []
    lats = np.arange(0.0, 90.0, lat_step)
    for lat in np.unique(np.concatenate([-lats, lats])):
        lon = np.linspace(-180.0, 180.0, 5)
        paths.append(np.stack([lon, np.full(5, lat)], axis=1))
    for lon in np.arange(-180.0, 180.0, lon_step):
        paths.append(np.array([[lon, -90.0], [lon, 0.0], [lon, 90.0]]))
    return paths


class GraticuleLayerType(LayerType):
    """Opens ``.graticule`` files as lines of constant latitude and longitude. The manifest
    declares the same ``extensions``, so the host dispatches files here without importing
    the plugin first."""

    name = "graticule"
    label = "Graticule (lat/lon grid)"
    extensions = (".graticule",)

    def open(self, path: str) -> Lines:
        """The graticule a file describes, as one `Lines` drawable (rhumb interpolation)."""
        g = read_graticule(path)
        return Lines(
            graticule_paths(float(g["lat_step_deg"]), float(g["lon_step_deg"])),
            interpolation="rhumb",
            color=g["color"],
            width_px=float(g["width_px"]),
            name=Path(path).name,
        )
