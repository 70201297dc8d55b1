"""The overlay layer models: what a layer type's ``open()`` result becomes on the globe.

A layer type returns drawables (`globeview.model.drawables`: `Lines`, `Points`,
`RasterDrape`, `RasterFile`, a list of them, or an object with ``drawables()``), or, as in API
1.0, its own object with ``attach(renderer)``/``detach(renderer)``. `host_layer` checks the
drawables (`drawable_problem`: garbage is the plugin's fault, one line) and builds the overlay
layer objects the session keeps and the overlay panel edits:

- `VectorLayer` (lines densified along geodesics or rhumb lines, draped on the drawn mesh),
- `PointsLayer` (placemarks or 3-D objects, with labels),
- `ImageryOverlayLayer` (a drape: a raster file warped per tile, or an in-memory RGBA image),
- `DrawnLayer`: several of these listed as one overlay.

Every layer object has ``name``, ``kind`` ('imagery', 'thematic', 'vector', 'points' or
'drawing'), ``set_visible(visible)`` and, by kind, ``set_opacity(opacity)`` or
``set_style(**style)``. They hold no GL objects: the renderer makes each layer's GPU twin
when a frame draws it (`globeview.render.overlay_imagery.OverlaySet.sync`). Each setter that
changes something emits the layer's ``changed`` signal once (nothing for a no-op); the
`Globe` showing the layer re-emits it as ``globe.events.overlays``, so an edit made by
code or a plugin reaches the window like one made in the overlay panel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from psygnal import Signal

from globeview.model.drawables import (
    INTERPOLATIONS,
    POINT_KINDS,
    Lines,
    Points,
    RasterDrape,
    RasterFile,
)
from globeview.terrain.imagery import (
    DEFAULT_TEX_SIZE,
    HillshadeImagery,
    ImageryLayer,
    RasterImagery,
    texel_grid,
)
from globeview.terrain.quadtree import TileKey, tile_bounds
from globeview.terrain.vectors import (
    Polylines,
    densify,
    densify_rhumb,
    segment_lengths_m,
    thin,
)

__all__ = [
    "ArrayImagery",
    "DrawnLayer",
    "ImageryOverlayLayer",
    "LegendEntry",
    "PointsLayer",
    "VectorLayer",
    "as_drawables",
    "drawable_problem",
    "hillshade_layer",
    "host_layer",
]

#: Most vertices a layer's lines may have after densification: a finer ``segment_m`` than
#: this allows over the lines' length is coarsened (a plugin asking for 1 mm pieces along the
#: coastlines would otherwise ask for billions of vertices).
MAX_LINE_VERTICES = 2_000_000
#: Most vertices / points / drawables one layer may hand over.
MAX_INPUT_VERTICES = 5_000_000
MAX_POINTS = 1_000_000
#: Most distinct point labels, and characters in one: the labels are rasterised into one
#: atlas texture, which must stay within GL's texture size (16 384 px on llvmpipe).
MAX_DISTINCT_LABELS = 2_000
MAX_LABEL_CHARS = 64
MAX_DRAWABLES = 1_000
#: Largest in-memory drape side (pixels).
MAX_DRAPE_SIDE = 16_384
#: Coarser line levels: x4 spacing each, up to about 1000 km.
_COARSER_MAX_M = 1.3e6
_MEAN_RADIUS_M = 6_371_008.8
#: Lines of fewer segments get no thinned levels below ``segment_m`` (nothing to gain).
_THIN_MIN_SEGMENTS = 10_000


# -- layer objects (models: data + style + visible, no GL) ------------------------------------
# The renderer builds each layer's GPU twin when a frame draws it
# (`globeview.render.overlay_imagery.OverlaySet.sync`, by ``gpu_kind``), so opening, adding,
# removing, showing or restyling an overlay never needs a GL context, and the setters take
# no renderer. (An API 1.0 plugin object is attached and told its visibility by
# `OverlayHost.prepare_gpu` at frame time.)
class _ModelLayer:
    """What every host layer model shares: shown or hidden, and ``changed`` (a psygnal
    signal, no arguments) emitted once per setter call that changed something
    (`Globe.add_overlay` connects it to ``globe.events.overlays``)."""

    visible: bool
    #: Emitted after a setter changed the layer (visibility, opacity, style).
    changed = Signal()

    def set_visible(self, visible: bool) -> bool:
        """Show or hide the layer (next frame); True (and ``changed``) if it changed."""
        if bool(visible) == bool(self.visible):
            return False
        self.visible = bool(visible)
        self.changed.emit()
        return True


# eq=False: a layer is equal only to itself (identity). The generated __eq__ would compare
# numpy arrays field by field ("truth value of an array is ambiguous") whenever a list of
# overlays is searched (``in``, ``remove``), and two files opened alike would be "equal".
@dataclass(eq=False)
class ImageryOverlayLayer(_ModelLayer):
    """An imagery/thematic drape. ``opacity`` 0..1; visibility and opacity live on the
    `ImageryLayer` the drape composes."""

    layer: ImageryLayer
    kind: str = "imagery"
    gpu_kind = "imagery"

    @property
    def name(self) -> str:
        return self.layer.name

    @property
    def visible(self) -> bool:
        return bool(self.layer.visible)

    @visible.setter
    def visible(self, value: bool) -> None:
        self.layer.visible = bool(value)

    def set_opacity(self, opacity: float) -> bool:
        """Set the opacity, clipped to 0..1 (ValueError for NaN: nothing changes); True
        (and ``changed``) if it changed."""
        opacity = float(opacity)
        if math.isnan(opacity):
            raise ValueError(f"{self.name!r:.60} opacity {opacity!r} is not a number")
        opacity = float(np.clip(opacity, 0.0, 1.0))
        if opacity == float(self.layer.opacity):
            return False
        self.layer.opacity = opacity
        self.changed.emit()
        return True


@dataclass(frozen=True)
class LegendEntry:
    """One row of a layer's legend: its ``label`` (e.g. a field's value or a range of
    values) and the ``color`` (RGBA 0..1) it is drawn in."""

    label: str
    color: tuple[float, float, float, float]


class _StyledLayer(_ModelLayer):
    """Vector and point layers: a style edited live; ``style_version`` counts the edits, so
    the renderer rebuilds the layer's GPU twin once after a change."""

    style_version: int
    color: tuple[float, float, float, float]
    #: This layer's legend text ("": not in the legend), from its drawable's ``legend``.
    legend_label: str
    #: The attributes `set_style` changes (the rest is the layer's data).
    style_fields: tuple[str, ...] = ()

    def check_style(self, style: dict[str, Any]) -> None:
        """ValueError (one line) for a style name this layer lacks or a bad value."""
        for k, v in style.items():
            if k not in self.style_fields:
                raise ValueError(f"{type(self).__name__} has no style {k!r}")
            problem = style_problem(k, v)
            if problem is not None:
                raise ValueError(f"{type(self).__name__} style {problem}")

    @property
    def legend(self) -> list[LegendEntry]:
        """The layer's legend: one entry in its colour, or none."""
        return [LegendEntry(self.legend_label, self.color)] if self.legend_label else []

    def set_style(self, **style: Any) -> bool:
        """Change style attributes (colour, width_px, size_px, ...); next frame. An unknown
        name or a bad value (`style_problem`) is refused (ValueError, one line) and nothing
        changes: no frame trips over a NaN width or a colour that is not 3-4 numbers.
        True (and one ``changed``, one GPU rebuild) if a value differs from the current."""
        self.check_style(style)
        new = {}
        for k, v in style.items():
            if k in ("color", "label_color"):
                v = tuple(float(c) for c in [*v, 1.0][:4])
            elif k in ("width_px", "dash_px", "size_px", "scale_m"):
                v = float(v)
            if v != getattr(self, k):
                new[k] = v
        if not new:
            return False
        for k, v in new.items():
            setattr(self, k, v)
        self.style_version += 1
        self.changed.emit()
        return True


@dataclass(eq=False)
class VectorLayer(_StyledLayer):
    """Polylines (densified along geodesics or rhumb lines) with a line style: colour RGBA
    0..1, width and dash length in pixels."""

    name: str
    lines: Polylines
    color: tuple[float, float, float, float] = (1.0, 0.9, 0.2, 1.0)
    width_px: float = 1.5
    dash_px: float = 0.0
    kind: str = "vector"
    coarser: list = field(default_factory=list)  # (max segment m, Polylines), for far views
    visible: bool = True
    legend_label: str = ""
    style_version: int = field(default=0, repr=False)
    gpu_kind = "vectors"
    style_fields = ("color", "width_px", "dash_px")


#: A `PointsLayer` style value -> the per-point array it replaces when set.
_PER_POINT = {"size_px": "point_sizes_px", "scale_m": "point_scales_m", "color": "point_colors"}


@dataclass(eq=False)
class PointsLayer(_StyledLayer):
    """Point objects: placemarks with labels, or boxes/cones (kind in overlay_points.KINDS);
    size in pixels for placemarks, scale in metres for objects.

    ``point_sizes_px``, ``point_scales_m`` (N,) and ``point_colors`` (N, 4) RGBA are a size
    or colour per point (API 1.2), drawn instead of the one value; a `set_style` of that
    value (the overlay panel's) gives every point the new one (the array is dropped)."""

    name: str
    lon: np.ndarray
    lat: np.ndarray
    names: list[str]
    object_kind: str = "placemark"
    size_px: float = 10.0
    scale_m: float = 1000.0
    color: tuple[float, float, float, float] = (1.0, 0.25, 0.15, 1.0)
    labels: bool = True
    label_color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    kind: str = "points"
    visible: bool = True
    legend_label: str = ""
    style_version: int = field(default=0, repr=False)
    point_sizes_px: np.ndarray | None = field(default=None, repr=False)
    point_scales_m: np.ndarray | None = field(default=None, repr=False)
    point_colors: np.ndarray | None = field(default=None, repr=False)
    gpu_kind = "points"
    style_fields = ("object_kind", "size_px", "scale_m", "color", "labels", "label_color")

    def set_style(self, **style: Any) -> bool:
        """`_StyledLayer.set_style`; setting ``size_px``, ``scale_m`` or ``color`` also
        drops that per-point array (every point gets the value, even one equal to the
        first point's, which alone would be no change)."""
        self.check_style(style)
        dropped = [a for k, a in _PER_POINT.items() if k in style and getattr(self, a) is not None]
        for attr in dropped:
            setattr(self, attr, None)
        changed = super().set_style(**style)
        if dropped and not changed:  # the arrays went: the GPU twin must be rebuilt
            self.style_version += 1
            self.changed.emit()
        return changed or bool(dropped)


class DrawnLayer(_ModelLayer):
    """Several overlay layers (a layer type's list of drawables) listed and toggled as one.

    Style edits go to every part that has the attribute (the first part's value is shown)."""

    kind = "drawing"

    def __init__(self, name: str, parts: list) -> None:
        self.name = name
        self.parts = list(parts)
        self.visible = True

    @property
    def legend(self) -> list[LegendEntry]:
        """The parts' legend entries, each label once (the first part's colour), in order."""
        seen: dict[str, LegendEntry] = {}
        for p in self.parts:
            for entry in getattr(p, "legend", ()):
                seen.setdefault(entry.label, entry)
        return list(seen.values())

    def set_visible(self, visible: bool) -> bool:
        """Show or hide every part; one ``changed`` if the group's visibility changed."""
        if bool(visible) == self.visible:
            return False
        self.visible = bool(visible)
        for p in self.parts:
            p.set_visible(self.visible)
        self.changed.emit()
        return True

    def set_opacity(self, opacity: float) -> bool:
        """Set every drape part's opacity; one ``changed`` if any part changed."""
        if math.isnan(float(opacity)):
            raise ValueError(f"{self.name!r:.60} opacity {opacity!r} is not a number")
        changed = [p.set_opacity(opacity) for p in self.parts if hasattr(p, "set_opacity")]
        if any(changed):
            self.changed.emit()
        return any(changed)

    def set_style(self, **style: Any) -> bool:
        # Checked for every part first, so a refused value changes no part.
        for k, v in style.items():
            if not any(k in getattr(p, "style_fields", ()) for p in self.parts):
                raise ValueError(f"{self.name!r:.60} has no style {k!r}")
            problem = style_problem(k, v)
            if problem is not None:
                raise ValueError(f"{self.name!r:.60} style {problem}")
        changed = False
        for p in self.parts:
            own = {k: v for k, v in style.items() if k in getattr(p, "style_fields", ())}
            if own and hasattr(p, "set_style"):
                changed = bool(p.set_style(**own)) or changed
        if changed:
            self.changed.emit()
        return changed


# -- in-memory drapes ------------------------------------------------------------------------
class ArrayImagery:
    """An imagery source over an in-memory RGBA image on a lon/lat box (plate carree): each
    terrain tile's texels sample it bilinearly (alpha 0 outside the box).

    Args:
        rgba: (H, W, 4) uint8, row 0 at ``north``; bounds: (west, south, east, north) degrees.
    """

    mode = "rgba"

    def __init__(
        self,
        rgba: np.ndarray,
        bounds: tuple[float, float, float, float],
        name: str = "drape",
        tex_size: int = DEFAULT_TEX_SIZE,
    ) -> None:
        self.rgba = np.ascontiguousarray(rgba, np.uint8)
        self.bounds = tuple(float(v) for v in bounds)
        self.tex_size = int(tex_size)
        self.path = Path(name)

    def intersects(self, key: tuple[int, int, int]) -> bool:
        w, s, e, n = tile_bounds(TileKey(*key))
        bw, bs, be, bn = self.bounds
        return not (e < bw or w > be or n < bs or s > bn)

    def tile_rgba(self, key: tuple[int, int, int]) -> np.ndarray | None:
        if not self.intersects(key):
            return None
        t = self.tex_size
        tr, _ = texel_grid(key, t)
        centres = np.arange(t) + 0.5
        lon = tr.c + tr.a * centres  # texel column centres
        lat = tr.f + tr.e * centres  # texel row centres (north first)
        h, w = self.rgba.shape[:2]
        west, south, east, north = self.bounds
        # Fractional source pixel coordinates of the texel centres (pixel centres at +0.5).
        fx = (lon - west) / (east - west) * w - 0.5
        fy = (north - lat) / (north - south) * h - 0.5
        inside_x = (lon >= west) & (lon <= east)
        inside_y = (lat >= south) & (lat <= north)
        x0 = np.clip(np.floor(fx).astype(np.int64), 0, w - 1)
        y0 = np.clip(np.floor(fy).astype(np.int64), 0, h - 1)
        x1 = np.minimum(x0 + 1, w - 1)
        y1 = np.minimum(y0 + 1, h - 1)
        tx = np.clip(fx - x0, 0.0, 1.0)[None, :, None]
        ty = np.clip(fy - y0, 0.0, 1.0)[:, None, None]
        # Gather the four corner texels first, then widen: converting the whole image per
        # tile cost ~100 ms at 4096 x 2048 (every visible tile is redone on an opacity change).
        src = self.rgba

        def corner(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
            return src[rows[:, None], cols[None, :]].astype(np.float32)

        top = corner(y0, x0) * (1 - tx) + corner(y0, x1) * tx
        bot = corner(y1, x0) * (1 - tx) + corner(y1, x1) * tx
        out = top * (1 - ty) + bot * ty
        out[..., 3] *= (inside_y[:, None] & inside_x[None, :]).astype(np.float32)
        return np.clip(np.round(out), 0, 255).astype(np.uint8)


# -- checks of what a layer type returned (garbage fails its plugin) ------------------------
def as_drawables(result: Any) -> list | None:
    """The drawables in a layer type's ``open()`` result (one, a list/tuple, or an object with
    ``drawables()``), or None when it is none of these (e.g. an attach/detach layer)."""
    if isinstance(result, Lines | Points | RasterDrape | RasterFile):
        return [result]
    if isinstance(result, list | tuple):
        return list(result)
    return None


def _rgba_problem(color: Any, what: str) -> str | None:
    try:
        c = [float(v) for v in color]
    except Exception:  # noqa: BLE001  plugin data may raise anything: a one-line problem
        return f"{what} {color!r:.40} is not 3 or 4 numbers"
    if len(c) not in (3, 4) or not all(math.isfinite(v) for v in c):
        return f"{what} {color!r:.40} is not 3 or 4 finite numbers"
    return None


def _positive(value: Any, what: str, limit: float) -> str | None:
    try:
        v = float(value)
    except Exception:  # noqa: BLE001  plugin data may raise anything: a one-line problem
        return f"{what} {value!r:.40} is not a number"
    if not (math.isfinite(v) and 0 < v <= limit):
        return f"{what} {v!r} is not in (0, {limit:g}]"
    return None


def _floats(values: object) -> np.ndarray | None:
    """``values`` as a float64 array, or None when it is not numbers (plugin data may be
    anything, and may raise when read)."""
    try:
        return np.asarray(values, dtype=np.float64)
    except Exception:  # noqa: BLE001  plugin data may raise anything: a failed check
        return None


def point_sizes_problem(values: object, n: int, what: str, limit: float) -> str | None:
    """What is wrong with a `Points` size (``size_px`` or ``scale_m``: one number, or one
    per point, API 1.2) for ``n`` points, each in (0, ``limit``], or None."""
    arr = _floats(values)
    if arr is None:
        return f"{what} {values!r:.40} is not a number or {n} numbers"
    if arr.ndim == 0:
        v = float(arr)
        return (
            None
            if math.isfinite(v) and 0 < v <= limit
            else f"{what} {v!r} is not in (0, {limit:g}]"
        )
    if arr.ndim != 1 or len(arr) != n:
        return f"{what} of {arr.size} values for {n} points"
    if not (np.isfinite(arr) & (arr > 0) & (arr <= limit)).all():
        return f"{what} values not in (0, {limit:g}]"
    return None


def point_colors_problem(values: object, n: int, what: str) -> str | None:
    """What is wrong with a `Points` colour (one RGBA of 3 or 4 numbers, or one per point as
    (n, 3 or 4), API 1.2; components 0..1 by convention, finite checked), or None."""
    arr = _floats(values)
    if arr is None or arr.ndim == 0:
        return f"{what} {values!r:.40} is not 3 or 4 numbers"
    if arr.ndim == 1:
        if len(arr) not in (3, 4) or not np.isfinite(arr).all():
            return f"{what} {values!r:.40} is not 3 or 4 finite numbers"
        return None
    if arr.ndim != 2 or arr.shape[1] not in (3, 4):
        return f"{what} of shape {arr.shape}, not 3 or 4 numbers or ({n}, 3 or 4)"
    if len(arr) != n:
        return f"{what} of {len(arr)} rows for {n} points"
    if not np.isfinite(arr).all():
        return f"{what} with NaN or infinite components"
    return None


def drawable_problem(d: Any) -> str | None:
    """What is wrong with one drawable (one line), or None."""
    if isinstance(d, Lines):
        if d.interpolation not in INTERPOLATIONS:
            return f"Lines interpolation {d.interpolation!r:.40} (one of {INTERPOLATIONS})"
        try:
            paths = d.path_list()
        except Exception:  # noqa: BLE001  plugin data may raise anything: a one-line problem
            return "Lines paths that are not (N, 2) arrays of numbers"
        if not paths:
            return "Lines without a path"
        total = 0
        for p in paths:
            if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2:
                return f"a Lines path of shape {p.shape}, not (N >= 2, 2) lon/lat"
            if not np.isfinite(p).all():
                return "a Lines path with NaN or infinite coordinates"
            if (np.abs(p[:, 1]) > 90).any() or (np.abs(p[:, 0]) > 540).any():
                return "a Lines path outside lon -540..540, lat -90..90 degrees"
            total += len(p)
        if total > MAX_INPUT_VERTICES:
            return f"Lines with {total} vertices (at most {MAX_INPUT_VERTICES})"
        return (
            _legend_problem(d.legend, "Lines")
            or _rgba_problem(d.color, "Lines color")
            or _positive(d.width_px, "Lines width_px", 200.0)
            or (None if d.dash_px == 0 else _positive(d.dash_px, "Lines dash_px", 1e4))
            or _positive(d.segment_m, "Lines segment_m", 1e7)
        )
    if isinstance(d, Points):
        try:
            lon = np.asarray(d.lon, np.float64).reshape(-1)
            lat = np.asarray(d.lat, np.float64).reshape(-1)
        except Exception:  # noqa: BLE001  plugin data may raise anything: a one-line problem
            return "Points lon/lat that are not numbers"
        if lon.shape != lat.shape or len(lon) == 0 or len(lon) > MAX_POINTS:
            return f"Points with {len(lon)} lon and {len(lat)} lat (1..{MAX_POINTS}, equal)"
        if not (np.isfinite(lon).all() and np.isfinite(lat).all()) or (np.abs(lat) > 90).any():
            return "Points with NaN, infinite or out-of-range coordinates"
        labels = list(d.labels) if d.labels is not None else []
        if labels and len(labels) != len(lon):
            return f"Points with {len(labels)} labels for {len(lon)} points"
        if any(not isinstance(s, str) for s in labels):
            return "Points labels that are not strings"
        if len(set(labels)) > MAX_DISTINCT_LABELS:
            return f"Points with {len(set(labels))} distinct labels (at most {MAX_DISTINCT_LABELS})"
        if d.kind not in POINT_KINDS:
            return f"Points kind {d.kind!r:.40} (one of {POINT_KINDS})"
        count = len(lon)
        return (
            _legend_problem(d.legend, "Points")
            or point_colors_problem(d.color, count, "Points color")
            or _rgba_problem(d.label_color, "Points label_color")
            or point_sizes_problem(d.size_px, count, "Points size_px", 500.0)
            or point_sizes_problem(d.scale_m, count, "Points scale_m", 1e7)
        )
    if isinstance(d, RasterDrape):
        a = d.rgba
        if not isinstance(a, np.ndarray) or a.dtype != np.uint8:
            return f"a RasterDrape image of {type(a).__name__}, not a uint8 numpy array"
        if a.ndim != 3 or a.shape[2] not in (3, 4) or min(a.shape[:2]) < 1:
            return f"a RasterDrape image of shape {a.shape}, not (H, W, 3 or 4)"
        if max(a.shape[:2]) > MAX_DRAPE_SIDE:
            return f"a RasterDrape image of {a.shape[1]}x{a.shape[0]} (at most {MAX_DRAPE_SIDE})"
        try:
            w, s, e, n = (float(v) for v in d.bounds)
        except Exception:  # noqa: BLE001  plugin data may raise anything: a one-line problem
            return f"RasterDrape bounds {d.bounds!r:.60}, not (west, south, east, north)"
        if not all(map(math.isfinite, (w, s, e, n))) or not (w < e and s < n):
            return f"RasterDrape bounds {d.bounds!r:.60}, not west < east, south < north"
        if not (w >= -540 and e <= 540 and s >= -90 and n <= 90):
            return f"RasterDrape bounds {d.bounds!r:.60} outside lon/lat degrees"
        return None if _finite(d.opacity) else f"RasterDrape opacity {d.opacity!r:.40}"
    if isinstance(d, RasterFile):
        if not isinstance(d.path, str | Path):
            return f"a RasterFile path of {type(d.path).__name__}"
        return None if _finite(d.opacity) else f"RasterFile opacity {d.opacity!r:.40}"
    return f"a {type(d).__name__}, not a drawable (Lines, Points, RasterDrape, RasterFile)"


def style_problem(name: str, value: Any) -> str | None:
    """What is wrong with one style value of a vector or point layer (one line), or None:
    the same limits `drawable_problem` holds a layer type's drawables to."""
    if name in ("color", "label_color"):
        return _rgba_problem(value, name)
    if name == "dash_px":
        return None if _finite(value) and float(value) == 0 else _positive(value, name, 1e4)
    if name in ("width_px", "size_px", "scale_m"):
        limit = {"width_px": 200.0, "size_px": 500.0, "scale_m": 1e7}[name]
        return _positive(value, name, limit)
    if name == "labels":
        return None if isinstance(value, bool) else f"labels {value!r:.40} is not True/False"
    if name == "object_kind":
        return None if value in POINT_KINDS else f"object_kind {value!r:.40} ({POINT_KINDS})"
    return None


def _legend_problem(text: Any, what: str) -> str | None:
    if not isinstance(text, str):
        return f"{what} legend {text!r:.40} is not a string"
    return None if len(text) <= 200 else f"{what} legend of {len(text)} characters (at most 200)"


def _finite(v: Any) -> bool:
    try:
        return math.isfinite(float(v))
    except Exception:  # noqa: BLE001  plugin data may raise anything: a one-line problem
        return False


def drawables_problem(items: list) -> str | None:
    """What is wrong with a layer type's drawables (the first fault), or None."""
    if not items:
        return "an empty list of drawables"
    if len(items) > MAX_DRAWABLES:
        return f"{len(items)} drawables (at most {MAX_DRAWABLES})"
    for d in items:
        problem = drawable_problem(d)
        if problem is not None:
            return problem
    return None


# -- building layers from (checked) drawables -----------------------------------------------
def _polylines(d: Lines) -> Polylines:
    paths = d.path_list()
    if d.closed:
        paths = [np.concatenate([p, p[:1]]) for p in paths]
    xy = np.concatenate(paths)
    starts = np.concatenate([[0], np.cumsum([len(p) for p in paths])]).astype(np.int64)
    return Polylines(xy[:, 0].copy(), xy[:, 1].copy(), starts)


def _length_m(pl: Polylines) -> float:
    """Rough total length (great circles on the mean sphere), for the vertex budget."""
    a, b = pl.segments()
    lon1, lat1, lon2, lat2 = (np.radians(v) for v in (pl.lon[a], pl.lat[a], pl.lon[b], pl.lat[b]))
    h = (
        np.sin((lat2 - lat1) / 2) ** 2
        + np.cos(lat1) * np.cos(lat2) * np.sin((lon2 - lon1) / 2) ** 2
    )
    # A rhumb segment is at most ~pi/2 times its great circle over these spans.
    return float(np.sum(2 * _MEAN_RADIUS_M * np.arcsin(np.sqrt(np.clip(h, 0, 1))))) * 1.6


def _level_spacings(lengths: np.ndarray, step: float) -> list[float]:
    """The coarser line levels' spacings (m): x4 each from ``step`` up to ~1000 km, and
    below ``step`` x2 each from four times the median segment (``lengths``, m) of dense
    input (a layer of vertices metres apart, drawn from far away, thinned level by level:
    x2, so the level a view picks has segments of 1.5 to 6 pixels, not down to 0.4)."""
    coarse = [step * 4.0**k for k in range(1, 6) if step * 4.0**k <= _COARSER_MAX_M]
    if len(lengths) < _THIN_MIN_SEGMENTS:
        return coarse
    fine = 4.0 * max(float(np.median(lengths)), 1.0)
    below = []
    while fine < step:
        below.append(fine)
        fine *= 2.0
    return below + coarse


def vector_layer(d: Lines, name: str) -> VectorLayer:
    """A `VectorLayer` of checked `Lines`: densified along its interpolation, with coarser
    levels for far views (`_level_spacings`: each thinned to half its spacing, then densified
    to at most its spacing or ``segment_m``)."""
    raw = _polylines(d)
    lengths = segment_lengths_m(raw)
    step = float(d.segment_m)
    step = max(step, _length_m(raw) / MAX_LINE_VERTICES)
    rhumb = d.interpolation == "rhumb"

    def level(thin_m: float | None, target_m: float) -> Polylines:
        pl = raw if thin_m is None else thin(raw, thin_m, lengths)
        seg = lengths if thin_m is None else segment_lengths_m(pl)
        # Geodesic lines already finer than the target are kept as they are (densify would
        # insert nothing); rhumb lines are always unwrapped and clipped by densify_rhumb.
        if not rhumb and (not len(seg) or float(seg.max()) < 0.98 * target_m):
            return pl
        return (densify_rhumb if rhumb else densify)(pl, target_m)

    fine = level(None, step)
    coarser = [(m, level(m / 2.0, max(m, step))) for m in _level_spacings(lengths, step)]
    color = tuple(float(v) for v in [*d.color, 1.0][:4])
    return VectorLayer(
        d.name or name,
        fine,
        color=color,  # type: ignore[arg-type]
        width_px=float(d.width_px),
        dash_px=float(d.dash_px),
        coarser=coarser,
        legend_label=str(d.legend),
    )


def _cut(label: str) -> str:
    return label if len(label) <= MAX_LABEL_CHARS else label[: MAX_LABEL_CHARS - 3] + "..."


# A per-point size or colour (API 1.2) becomes the layer's one value (the first point's: what
# the overlay panel shows and edits) plus the per-point array the renderer draws.
def _sizes(values: Any) -> tuple[float, np.ndarray | None]:
    """A checked size (a number, or one per point) as (one value, per-point array or None)."""
    arr = np.asarray(values, np.float64)
    if arr.ndim == 0:
        return float(arr), None
    arr = arr.reshape(-1).copy()
    arr.setflags(write=False)
    return float(arr[0]), arr


def _colours(values: Any) -> tuple[tuple[float, ...], np.ndarray | None]:
    """A checked colour (3-4 numbers, or (N, 3-4) one per point) as (one RGBA, per-point
    (N, 4) RGBA or None); alpha 1 where only RGB is given."""
    arr = np.asarray(values, np.float64)
    if arr.ndim == 1:
        return tuple(float(v) for v in [*arr, 1.0][:4]), None
    rgba = np.concatenate([arr, np.ones((len(arr), 4 - arr.shape[1]))], axis=1)
    rgba.setflags(write=False)
    return tuple(float(v) for v in rgba[0]), rgba


def points_layer(d: Points, name: str) -> PointsLayer:
    # Longer labels are cut (with an ellipsis), not refused: a name field may be long.
    labels = [_cut(str(s)) for s in d.labels] if d.labels else []
    size_px, sizes_px = _sizes(d.size_px)
    scale_m, scales_m = _sizes(d.scale_m)
    color, colors = _colours(d.color)
    return PointsLayer(
        d.name or name,
        np.asarray(d.lon, np.float64).reshape(-1),
        np.asarray(d.lat, np.float64).reshape(-1),
        labels,
        object_kind=d.kind,
        size_px=size_px,
        scale_m=scale_m,
        color=color,  # type: ignore[arg-type]
        labels=bool(labels),
        label_color=tuple(float(v) for v in [*d.label_color, 1.0][:4]),  # type: ignore[arg-type]
        point_sizes_px=sizes_px,
        point_scales_m=scales_m,
        point_colors=colors,
        legend_label=str(d.legend),
    )


def drape_layer(d: RasterDrape | RasterFile, name: str) -> ImageryOverlayLayer:
    """A drape; a `RasterFile` is opened here (`ImageryError`, one line, for a bad file)."""
    opacity = float(np.clip(float(d.opacity), 0.0, 1.0))
    if isinstance(d, RasterFile):
        raster = RasterImagery(d.path, ramp=d.ramp)
        label = d.name or name or Path(d.path).name
        kind = "thematic" if d.ramp is not None else "imagery"
        return ImageryOverlayLayer(ImageryLayer(raster, label, opacity), kind)
    rgba = d.rgba
    if rgba.shape[2] == 3:
        rgba = np.concatenate([rgba, np.full((*rgba.shape[:2], 1), 255, np.uint8)], axis=2)
    image = ArrayImagery(rgba, d.bounds, d.name or name)
    return ImageryOverlayLayer(ImageryLayer(image, d.name or name, opacity), "imagery")


def build_layer(items: list, name: str) -> Any:
    """The overlay layer of checked drawables: one part as itself, several as a
    `DrawnLayer`. Raises `GlobeviewError` for a raster file that cannot be read."""
    parts: list = []
    for d in items:
        if isinstance(d, Lines):
            parts.append(vector_layer(d, name))
        elif isinstance(d, Points):
            parts.append(points_layer(d, name))
        else:
            parts.append(drape_layer(d, name))
    if len(parts) == 1:
        return parts[0]
    return DrawnLayer(name, parts)


def host_layer(result: Any, name: str) -> tuple[Any, str | None]:
    """(layer, None) for a layer type's ``open()`` result, or (None, problem) when it is
    garbage (the caller fails the plugin with ``problem``). An attach/detach object (API 1.0
    layers) is kept as it is. ``name``: the default layer name (the file's)."""
    items = as_drawables(result)
    if items is None and callable(getattr(result, "drawables", None)):
        items = result.drawables()  # the caller runs this under the plugin's isolation
        if not isinstance(items, list | tuple):
            return None, f"drawables() returned {type(items).__name__}, not a list"
        items = list(items)
        name = str(getattr(result, "name", "") or name)
    if items is None:
        if all(callable(getattr(result, m, None)) for m in ("attach", "detach")):
            return result, None
        return None, f"open() returned {type(result).__name__}, not a layer or drawables"
    problem = drawables_problem(items)
    if problem is not None:
        return None, f"open() returned {problem}"
    return build_layer(items, name), None


def hillshade_layer(terrain, opacity: float = 0.5, azimuth_deg: float = 315.0):
    """A thematic drape computed from the DEM itself: its hillshade (sun from ``azimuth_deg``,
    45 degrees up), multiplied in at ``opacity``."""
    src = HillshadeImagery(terrain, azimuth_deg=azimuth_deg)
    return ImageryOverlayLayer(ImageryLayer(src, "hillshade", opacity), "thematic")
