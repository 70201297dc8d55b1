"""`layers`: the built-in layer types (imagery, thematic, vector, points).

A layer type's ``open(path)`` reads and checks the file on the CPU (no GL) and returns a
layer object; the host then calls ``layer.attach(renderer)`` to put it on the globe (the
renderer's `OverlaySet`, see render/overlay_imagery.py) and ``layer.detach(renderer)`` to
take it off. Bad input raises a `GlobeviewError` subclass with a one-line message.

`detect_layer_type(path)` decides a file's layer type by content (raster vs GeoJSON lines vs
GeoJSON points); `embedded_layers()` gives the embedded default (country borders and
coastlines, optionally Blue Marble imagery) and `hillshade_layer(terrain)` a thematic layer
computed from the DEM itself.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from globeview.errors import GlobeviewError
from globeview.terrain.dem import EMBEDDED_DATA_DIR
from globeview.terrain.imagery import (
    HillshadeImagery,
    ImageryError,
    ImageryLayer,
    RasterImagery,
)
from globeview.terrain.vectors import (
    Polylines,
    VectorError,
    densify,
    read_geojson_lines,
    read_geojson_points,
)

__all__ = [
    "ImageryLayerType",
    "ImageryOverlayLayer",
    "PointsLayer",
    "PointsLayerType",
    "ThematicLayerType",
    "VectorLayer",
    "VectorLayerType",
    "detect_layer_type",
    "embedded_layers",
    "hillshade_layer",
    "open_layer",
]

RASTER_EXTENSIONS = (".tif", ".tiff", ".png", ".jpg", ".jpeg", ".jp2", ".img", ".vrt", ".asc")
VECTOR_EXTENSIONS = (".geojson", ".json")
#: Default geodesic densification of vector lines (metres between vertices).
DENSIFY_M = 20_000.0


# -- layer objects ---------------------------------------------------------------------------
@dataclass
class ImageryOverlayLayer:
    """An imagery/thematic drape. ``opacity`` 0..1; call ``changed(renderer)`` after edits."""

    layer: ImageryLayer
    kind: str = "imagery"

    @property
    def name(self) -> str:
        return self.layer.name

    def attach(self, renderer) -> None:
        renderer.overlays.imagery.add(self.layer)

    def detach(self, renderer) -> None:
        # By identity: two drapes of the same file are two layers.
        stack = renderer.overlays.imagery
        stack.layers = [ly for ly in stack.layers if ly is not self.layer]
        stack.changed()

    def set_visible(self, renderer, visible: bool) -> None:
        self.layer.visible = bool(visible)
        renderer.overlays.imagery.changed()

    def set_opacity(self, renderer, opacity: float) -> None:
        self.layer.opacity = float(np.clip(opacity, 0.0, 1.0))
        renderer.overlays.imagery.changed()


class _GpuOverlayLayer:
    """What vector and point layers share: a GPU overlay object (``_overlay``) kept in one of
    the renderer's overlay lists (``_list``), shown or hidden, restyled live."""

    _list = ""  # "vectors" or "points": the renderer.overlays list the overlay lives in
    visible: bool
    _overlay: Any

    def _make_overlay(self, renderer) -> Any:
        raise NotImplementedError

    def attach(self, renderer) -> None:
        self._overlay = self._make_overlay(renderer)
        self._overlay.visible = self.visible
        getattr(renderer.overlays, self._list).append(self._overlay)

    def detach(self, renderer) -> None:
        if self._overlay is not None:
            getattr(renderer.overlays, self._list).remove(self._overlay)
            self._overlay.release()
            self._overlay = None

    def set_visible(self, renderer, visible: bool) -> None:
        self.visible = bool(visible)
        if self._overlay is not None:
            self._overlay.visible = self.visible

    def set_style(self, renderer, **style: Any) -> None:
        """Change style attributes (colour, width_px, size_px, ...); next frame."""
        _restyle(self, style)


@dataclass
class VectorLayer(_GpuOverlayLayer):
    """Polylines (densified along geodesics) with a line style: colour RGBA 0..1, width and
    dash length in pixels."""

    name: str
    lines: Polylines
    color: tuple[float, float, float, float] = (1.0, 0.9, 0.2, 1.0)
    width_px: float = 1.5
    dash_px: float = 0.0
    kind: str = "vector"
    coarser: list = field(default_factory=list)  # (max segment m, Polylines), for far views
    visible: bool = True
    _overlay: Any = field(default=None, repr=False)
    _list = "vectors"

    def _make_overlay(self, renderer) -> Any:
        from globeview.render.overlay_vectors import LineStyle, VectorOverlay

        style = LineStyle(self.color, self.width_px, self.dash_px)
        return VectorOverlay(renderer.ctx, self.lines, style, self.name, coarser=self.coarser)


@dataclass
class PointsLayer(_GpuOverlayLayer):
    """Point objects: placemarks with labels, or boxes/cones (kind in overlay_points.KINDS);
    size in pixels for placemarks, scale in metres for objects."""

    name: str
    lon: np.ndarray
    lat: np.ndarray
    names: list[str]
    object_kind: str = "placemark"
    size_px: float = 10.0
    scale_m: float = 1000.0
    color: tuple[float, float, float, float] = (1.0, 0.25, 0.15, 1.0)
    labels: bool = True
    kind: str = "points"
    visible: bool = True
    _overlay: Any = field(default=None, repr=False)
    _list = "points"

    def _make_overlay(self, renderer) -> Any:
        from globeview.render.overlay_points import PointOverlay, PointStyle

        style = PointStyle(
            self.object_kind, self.size_px, self.scale_m, self.color, labels=self.labels
        )
        return PointOverlay(renderer.ctx, self.lon, self.lat, self.names, style, name=self.name)


def _restyle(layer: Any, style: dict[str, Any]) -> None:
    for k, v in style.items():
        if not hasattr(layer, k):
            raise ValueError(f"{type(layer).__name__} has no style {k!r}")
        setattr(layer, k, v)
    ov = layer._overlay
    if ov is not None:
        for k, v in style.items():
            if hasattr(ov.style, k):
                setattr(ov.style, k, v)
        ov._sig = None  # instance data baked from the style: rebuild on the next frame


# -- layer types (the plugin's contributions) --------------------------------------------------
class _LayerTypeBase:
    name = ""
    label = ""
    extensions: tuple[str, ...] = ()

    def __init__(self, context: Any = None) -> None:
        self.context = context

    def configure(self, values: dict) -> None:  # layer types have no settings yet
        pass


class ImageryLayerType(_LayerTypeBase):
    """RGB(A) imagery, or a single band with a colour table, draped on the terrain."""

    name = "imagery"
    label = "Imagery (RGB/RGBA raster)"
    extensions = RASTER_EXTENSIONS

    def open(self, path: str, opacity: float = 1.0) -> ImageryOverlayLayer:
        src = RasterImagery(path)
        return ImageryOverlayLayer(ImageryLayer(src, Path(path).name, opacity))


class ThematicLayerType(_LayerTypeBase):
    """A single-band raster coloured by its colour table or by a ramp (default: a
    blue-green-yellow-red ramp over the band's range), draped half-transparent."""

    name = "thematic"
    label = "Thematic raster (single band)"
    extensions = RASTER_EXTENSIONS

    def open(
        self, path: str, ramp: list | None = None, opacity: float = 0.6
    ) -> ImageryOverlayLayer:
        import rasterio

        if ramp is None:
            try:
                with rasterio.open(path) as ds:
                    st = ds.statistics(1, approx=True)
                    lo, hi = float(st.min), float(st.max)
            except Exception as exc:
                raise ImageryError(
                    f"{Path(path).name}: cannot read as a raster ({str(exc).splitlines()[0]})"
                ) from None
            span = hi - lo or 1.0
            ramp = [
                (lo, (40, 60, 200)),
                (lo + span / 3, (40, 180, 90)),
                (lo + 2 * span / 3, (240, 220, 40)),
                (hi, (220, 40, 30)),
            ]
        src = RasterImagery(path, ramp=ramp)
        return ImageryOverlayLayer(ImageryLayer(src, Path(path).name, opacity), "thematic")


class VectorLayerType(_LayerTypeBase):
    """GeoJSON LineString/MultiLineString/Polygon/MultiPolygon outlines."""

    name = "vector"
    label = "Vector lines/polygons (GeoJSON)"
    extensions = VECTOR_EXTENSIONS

    def open(self, path: str, densify_m: float = DENSIFY_M, **style: Any) -> VectorLayer:
        raw = read_geojson_lines(path)
        # Finest level at densify_m; coarser ones (x4 each, up to ~1000 km) for far views.
        steps = [densify_m * 4.0**k for k in range(1, 6) if densify_m * 4.0**k <= 1.3e6]
        coarser = [(m, densify(raw, m)) for m in steps]
        return VectorLayer(Path(path).name, densify(raw, densify_m), coarser=coarser, **style)


class PointsLayerType(_LayerTypeBase):
    """GeoJSON Point/MultiPoint features as labelled placemarks (``name`` property)."""

    name = "points"
    label = "Point objects (GeoJSON)"
    extensions = VECTOR_EXTENSIONS

    def open(self, path: str, **style: Any) -> PointsLayer:
        lon, lat, names = read_geojson_points(path)
        return PointsLayer(Path(path).name, lon, lat, names, **style)


def detect_layer_type(path: str | Path) -> str:
    """'imagery', 'thematic', 'vector' or 'points' for a file, decided by its content."""
    p = Path(path)
    if not p.is_file():
        raise GlobeviewError(f"{p.name}: no such file")
    with open(p, "rb") as fh:
        head = fh.read(64).lstrip()
    if head[:1] in (b"{", b"["):
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise VectorError(f"{p.name}: not valid GeoJSON ({exc})") from None
        except RecursionError:  # [[[[...]]]] thousands deep
            raise VectorError(f"{p.name}: not valid GeoJSON (nested too deeply)") from None
        types = set()
        feats = doc.get("features", [doc]) if isinstance(doc, dict) else []
        for f in feats:
            g = (f or {}).get("geometry", f) if isinstance(f, dict) else None
            if isinstance(g, dict):
                types.add(g.get("type"))
        if types & {"LineString", "MultiLineString", "Polygon", "MultiPolygon"}:
            return "vector"
        if types & {"Point", "MultiPoint"}:
            return "points"
        raise VectorError(f"{p.name}: GeoJSON without Point, LineString or Polygon geometry")
    import rasterio

    try:
        with rasterio.open(p) as ds:
            count = ds.count
            try:
                has_cmap = count == 1 and bool(ds.colormap(1))
            except ValueError:
                has_cmap = False
    except Exception:
        raise GlobeviewError(f"{p.name}: neither a raster GDAL reads nor GeoJSON") from None
    return "imagery" if count in (3, 4) or has_cmap else "thematic"


_TYPES = {
    "imagery": ImageryLayerType,
    "thematic": ThematicLayerType,
    "vector": VectorLayerType,
    "points": PointsLayerType,
}


def open_layer(path: str | Path, **kwargs: Any):
    """Open a file with the layer type `detect_layer_type` picks."""
    return _TYPES[detect_layer_type(path)]().open(str(path), **kwargs)


def hillshade_layer(terrain, opacity: float = 0.5, azimuth_deg: float = 315.0):
    """A thematic drape computed from the DEM itself: its hillshade (sun from ``azimuth_deg``,
    45 degrees up), multiplied in at ``opacity``."""
    src = HillshadeImagery(terrain, azimuth_deg=azimuth_deg)
    return ImageryOverlayLayer(ImageryLayer(src, "hillshade", opacity), "thematic")


def embedded_layers(imagery: bool = True) -> list:
    """The embedded default overlays, bottom first: Blue Marble imagery (if ``imagery``) and
    the country borders and coastlines of Natural Earth 1:110m."""
    out: list = []
    if imagery:
        out.append(ImageryLayerType().open(str(EMBEDDED_DATA_DIR / "bluemarble_2048x1024.tif")))
    out.append(
        VectorLayerType().open(
            str(EMBEDDED_DATA_DIR / "ne_110m_countries.geojson"),
            color=(1.0, 0.92, 0.35, 1.0),
            width_px=1.5,
        )
    )
    return out
