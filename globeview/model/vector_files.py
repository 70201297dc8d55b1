"""GIS vector files (any OGR source) as drawables, styled by attribute (plugin API 1.5).

`read_vector_file` reads one layer of a Shapefile, GeoPackage, KML/KMZ, GPX, FlatGeobuf,
GeoParquet (pyarrow where GDAL lacks the driver) or any file OGR opens
(`globeview.terrain.ogr_vectors`: reprojected to WGS84
lon/lat degrees) and returns the drawables the host draws:

- lines and polygon outlines as `Lines` (joined along geodesics), points as `Points`;
- with ``color_by=FIELD`` one `Lines`/`Points` per class of the field, each with its ``legend``
  text: a categorical palette (at most `MAX_CATEGORIES` values, the rest as "other"), or for
  numbers with more distinct values than ``classes`` a ramp over quantile classes
  ("lo – hi"); features without a value are "no value" (grey);
- with ``label=FIELD`` the field's text beside each point, and beside each line or polygon
  (at its middle vertex, a polygon at its outer ring's mean vertex); points are labelled by a
  ``name``/``Name`` field when there is one and no ``label`` is given.

`classify` is the colouring on its own (values -> class per feature and legend entries).
Broken geometries are skipped and counted in one warning line (logger ``globeview.vectors``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from globeview.model.drawables import Lines, Points
from globeview.model.overlay_layers import style_problem
from globeview.terrain.ogr_vectors import (
    VectorFeatures,
    VectorFileError,
    layer_fields,
    read_vector_features,
    vector_layers,
)

__all__ = [
    "CATEGORY_PALETTE",
    "MAX_CATEGORIES",
    "RAMP",
    "Classes",
    "VectorFileStyle",
    "classify",
    "read_vector_file",
    "vector_file_layers",
]

log = logging.getLogger("globeview.vectors")

RGBA = tuple[float, float, float, float]
#: Distinct colours of a categorical field (Tableau 10 less its grey), in order.
CATEGORY_PALETTE: tuple[RGBA, ...] = (
    (0.12, 0.47, 0.71, 1.0),
    (1.00, 0.50, 0.05, 1.0),
    (0.17, 0.63, 0.17, 1.0),
    (0.84, 0.15, 0.16, 1.0),
    (0.58, 0.40, 0.74, 1.0),
    (0.55, 0.34, 0.29, 1.0),
    (0.89, 0.47, 0.76, 1.0),
    (0.74, 0.74, 0.13, 1.0),
    (0.09, 0.75, 0.81, 1.0),
)
MAX_CATEGORIES = len(CATEGORY_PALETTE)
#: The numeric ramp (viridis' stops), low to high.
RAMP: tuple[RGBA, ...] = (
    (0.267, 0.005, 0.329, 1.0),
    (0.231, 0.322, 0.545, 1.0),
    (0.129, 0.569, 0.549, 1.0),
    (0.369, 0.788, 0.384, 1.0),
    (0.993, 0.906, 0.144, 1.0),
)
#: The colours without a ``color`` or ``color_by``: those of `Lines` and `Points`.
LINE_COLOR: RGBA = (1.0, 0.9, 0.2, 1.0)
POINT_COLOR: RGBA = (1.0, 0.25, 0.15, 1.0)
#: Features without a value, and categories past the palette.
GREY: RGBA = (0.6, 0.6, 0.6, 1.0)
#: Most points one layer draws (the host's limit on a `Points` drawable).
MAX_POINTS = 1_000_000
#: Most labels one layer draws (the label atlas's limit on distinct labels).
MAX_LABELS = 2_000
#: Default densification of GIS lines (metres): local data (roads, trails) drapes closely.
SEGMENT_M = 1_000.0


@dataclass(frozen=True)
class Classes:
    """A colouring by attribute: ``index`` (features,) the class of each feature, and per
    class its ``labels`` (legend text) and ``colors`` (RGBA 0..1)."""

    index: np.ndarray
    labels: tuple[str, ...]
    colors: tuple[RGBA | None, ...]


def _missing(values: np.ndarray) -> np.ndarray:
    if values.dtype.kind == "f":
        return np.isnan(values)
    if values.dtype.kind == "O":
        return np.array([v is None or (isinstance(v, float) and v != v) for v in values], bool)
    return np.zeros(len(values), bool)


def _text(v: object) -> str:
    if isinstance(v, float | np.floating):
        return f"{float(v):.4g}"
    return str(v)


def _ramp(t: np.ndarray) -> list[RGBA]:
    """Colours of the ramp at positions 0..1."""
    stops = np.asarray(RAMP)
    x = np.linspace(0.0, 1.0, len(stops))
    return [tuple(float(np.interp(v, x, stops[:, k])) for k in range(4)) for v in t]  # type: ignore[misc]


def classify(values: np.ndarray, classes: int = 5) -> Classes:
    """Colour classes of one attribute column (see the module docstring)."""
    values = np.asarray(values)
    missing = _missing(values)
    numeric = values.dtype.kind in "iuf"
    present = values[~missing]
    distinct = np.unique(present.astype(str) if not numeric else present)
    index = np.zeros(len(values), np.int64)
    if numeric and len(distinct) > max(classes, 1):
        breaks = np.unique(np.quantile(present.astype(np.float64), np.linspace(0, 1, classes + 1)))
        k = len(breaks) - 1
        index[~missing] = np.clip(
            np.searchsorted(breaks[1:-1], present.astype(np.float64), side="right"), 0, k - 1
        )
        labels = [f"{breaks[i]:.4g} – {breaks[i + 1]:.4g}" for i in range(k)]
        colors = _ramp(np.linspace(0.0, 1.0, k))
    else:
        keys = present if numeric else present.astype(str)
        uniq, counts = np.unique(keys, return_counts=True)
        if len(uniq) > MAX_CATEGORIES:  # the most frequent keep a colour, the rest "other"
            top = np.sort(np.argsort(-counts, kind="stable")[: MAX_CATEGORIES - 1])
            uniq = uniq[top]
        pos = np.searchsorted(uniq, keys)
        pos = np.minimum(pos, len(uniq) - 1)
        known = uniq[pos] == keys
        index[~missing] = np.where(known, pos, len(uniq))
        labels = [_text(u) for u in uniq]
        colors = list(CATEGORY_PALETTE[: len(uniq)])
        if not known.all():
            labels.append("other")
            colors.append(GREY)
    if missing.any():
        index[missing] = len(labels)
        labels.append("no value")
        colors.append(GREY)
    return Classes(index, tuple(labels), tuple(colors))


def vector_file_layers(path: str | Path) -> list[tuple[str, str]]:
    """(name, geometry type) of each layer of a vector file OGR reads; `GlobeviewError`
    (one line) for a file it does not read."""
    return vector_layers(path)


def _point_label_field(fields: Sequence[str], label: str | None) -> str | None:
    """The field points are labelled by: ``label``, else a ``name`` field if there is one."""
    if label is not None:
        return label
    return next((f for f in ("name", "Name", "NAME") if f in fields), None)


@dataclass(frozen=True)
class VectorFileStyle:
    """How `read_vector_file` draws a layer.

    Attributes:
        color_by: a field to colour by (None: one colour); label: a field to label features
            with (None: points by a ``name`` field, lines and polygons not at all).
        color: RGBA 0..1 of everything when not coloured by a field (None: the defaults,
            yellow lines and red points).
        width_px: line width (pixels); size_px: point size (pixels).
        classes: classes of a numeric ramp (2..12). segment_m: densification (metres).
        name: the layer's name in the overlay panel (default: the file's, ``FILE::LAYER``
            when a layer was named).
    """

    color_by: str | None = None
    label: str | None = None
    color: tuple[float, ...] | None = None
    width_px: float = 1.5
    size_px: float = 8.0
    classes: int = 5
    segment_m: float = SEGMENT_M
    name: str | None = None


def _style(style: dict[str, Any]) -> VectorFileStyle:
    known = VectorFileStyle.__dataclass_fields__
    unknown = [k for k in style if k not in known]
    if unknown:
        raise VectorFileError(f"no vector style {unknown[0]!r:.40} (styles: {', '.join(known)})")
    st = VectorFileStyle(**style)
    if isinstance(st.classes, bool) or not isinstance(st.classes, int) or not 2 <= st.classes <= 12:
        raise VectorFileError(f"classes {st.classes!r:.20} is not a whole number in 2..12")
    for key in ("color_by", "label", "name"):
        value = getattr(st, key)
        if value is not None and not isinstance(value, str):
            raise VectorFileError(f"{key} {value!r:.40} is not a field name")
    for key in ("width_px", "size_px", "segment_m"):
        if not _positive_finite(getattr(st, key)):
            raise VectorFileError(f"{key} {getattr(st, key)!r:.20} is not a positive number")
    for key in ("width_px", "size_px", "color"):  # the host's limits on drawables
        problem = None if getattr(st, key) is None else style_problem(key, getattr(st, key))
        if problem is not None:
            raise VectorFileError(problem)
    return st


def _positive_finite(value: object) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and value > 0
    )


def read_vector_file(
    path: str | Path, layer: str | None = None, **style: Any
) -> list[Lines | Points]:
    """The drawables of one layer of a GIS vector file (see the module docstring): ``layer``
    names the layer (default: the first with features), ``style`` is `VectorFileStyle`'s
    fields (``color_by``, ``label``, ``color``, ``width_px``, ``size_px``, ``classes``,
    ``segment_m``, ``name``). Raises `GlobeviewError` (one line) for bad input."""
    p = Path(path)
    st = _style(style)
    point_label = _point_label_field(layer_fields(p, layer), st.label)
    wanted = [f for f in (st.color_by, st.label, point_label) if f is not None]
    feats = read_vector_features(p, layer, wanted)
    g = feats.geometry
    if not len(g.line_starts) > 1 and not len(g.point_xy):
        raise VectorFileError(f"{p.name}: no point, line or polygon geometry to draw")
    if len(g.point_xy) > MAX_POINTS:  # the user's file, not the layer type's fault: one line
        raise VectorFileError(f"{p.name}: {len(g.point_xy):,} points (at most {MAX_POINTS:,})")
    drawn = np.zeros(feats.count, bool)
    drawn[g.line_feature] = True
    drawn[g.point_feature] = True
    if g.broken:
        log.warning(
            "%s: %d features with broken geometry skipped (%d drawn)",
            p.name,
            g.broken,
            int(drawn.sum()),
        )
    title = st.name or (f"{p.name}::{feats.name}" if layer is not None else p.name)
    cls = _classes(feats, drawn, st)
    labels = _point_labels(feats, point_label)
    out = _class_drawables(feats, cls, labels, st, title)
    if st.label is not None and len(g.line_starts) > 1:
        out.extend(_line_labels(feats, st.label, title))
    return out


def _classes(feats: VectorFeatures, drawn: np.ndarray, st: VectorFileStyle) -> Classes:
    """The colour classes: of the features drawn only (the legend lists those), or one."""
    if st.color_by is None:
        return Classes(np.zeros(feats.count, np.int64), ("",), (_rgba(st.color),))
    got = classify(feats.attributes[st.color_by][drawn], st.classes)
    index = np.zeros(feats.count, np.int64)
    index[drawn] = got.index
    return Classes(index, got.labels, got.colors)


def _rgba(color: Sequence[float] | None) -> RGBA | None:
    if color is None:
        return None
    c = [float(v) for v in color]
    return (c[0], c[1], c[2], c[3] if len(c) > 3 else 1.0) if len(c) >= 3 else None


def _class_drawables(
    feats: VectorFeatures,
    cls: Classes,
    labels: list[str] | None,
    st: VectorFileStyle,
    title: str,
) -> list[Lines | Points]:
    """One `Lines` and one `Points` (where the class has such features) per class."""
    g = feats.geometry
    xy = g.line_xy
    out: list[Lines | Points] = []
    part_class = cls.index[g.line_feature]
    point_class = cls.index[g.point_feature]
    for k, (text, rgba) in enumerate(zip(cls.labels, cls.colors, strict=True)):
        parts = np.nonzero(part_class == k)[0]
        if len(parts):
            paths = [xy[g.line_starts[i] : g.line_starts[i + 1]] for i in parts]
            out.append(
                Lines(
                    paths,
                    color=LINE_COLOR if rgba is None else rgba,
                    width_px=st.width_px,
                    segment_m=st.segment_m,
                    name=title,
                    legend=text,
                )
            )
        pts = np.nonzero(point_class == k)[0]
        if len(pts):
            names = [labels[i] for i in pts] if labels is not None else []
            out.append(
                Points(
                    g.point_xy[pts, 0],
                    g.point_xy[pts, 1],
                    names,
                    size_px=st.size_px,
                    color=POINT_COLOR if rgba is None else rgba,
                    name=title,
                    legend=text,
                )
            )
    return out


def _point_labels(feats: VectorFeatures, field: str | None) -> list[str] | None:
    """Each point's label from ``field`` (None: no labels); labels past the first
    `MAX_LABELS` distinct ones are left empty."""
    if field is None:
        return None
    values = feats.attributes[field][feats.geometry.point_feature]
    texts = ["" if _is_missing(v) else _text(v) for v in values]
    seen: set[str] = set()
    for i, t in enumerate(texts):
        if t in seen:
            continue
        if len(seen) >= MAX_LABELS:
            texts[i] = ""
        else:
            seen.add(t)
    return texts


def _is_missing(v: object) -> bool:
    return v is None or (isinstance(v, float | np.floating) and v != v)


def _line_labels(feats: VectorFeatures, field: str, title: str) -> list[Lines | Points]:
    """Labels beside lines and polygons: one per feature (the first `MAX_LABELS`), at its
    first outer part's middle vertex (a closed ring: its mean vertex)."""
    g = feats.geometry
    outer = np.nonzero(g.line_outer)[0]
    _, first = np.unique(g.line_feature[outer], return_index=True)
    parts = outer[first][:MAX_LABELS]
    lon, lat, texts = [], [], []
    values = feats.attributes[field]
    for i in parts:
        run = g.line_xy[g.line_starts[i] : g.line_starts[i + 1]]
        closed = len(run) > 3 and (run[0] == run[-1]).all()
        anchor = run[:-1].mean(axis=0) if closed else run[len(run) // 2]
        v = values[g.line_feature[i]]
        if _is_missing(v):
            continue
        lon.append(float(anchor[0]))
        lat.append(float(anchor[1]))
        texts.append(_text(v))
    if not lon:
        return []
    return [
        Points(
            np.array(lon),
            np.array(lat),
            texts,
            size_px=2.0,
            color=(1.0, 1.0, 1.0, 0.9),
            name=f"{title} labels",
        )
    ]
