"""Drawable primitives: data a layer plugin returns and the host draws (plugin API).

A `LayerType.open(path)` may return, instead of an object with ``attach``/``detach``:

- one drawable (`Lines`, `Points`, `RasterDrape`, `RasterFile`),
- a list or tuple of drawables (drawn as one overlay layer, listed once), or
- an object with a ``drawables()`` method returning such a list (and optionally ``name``).

The host checks what comes back (garbage fails the plugin, one line), turns it into GPU
overlays and lists it in the window's overlay panel; the plugin never touches GL or the
renderer. The built-in layer types (imagery, thematic, vector, points) return these too.

Frames and units: WGS84 longitude/latitude in degrees, heights from the terrain actually
drawn (lines and points are draped on the LOD mesh), colours RGBA in 0..1, sizes in screen
pixels. Everything here is plain data (numpy arrays, tuples): no GL, no Qt. It lives in
`globeview.model` beside the layer models it becomes (`globeview.model.overlay_layers`);
plugins get it from the facade, `globeview.plugins.api`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from globeview.errors import GlobeviewError

__all__ = [
    "Drawable",
    "Lines",
    "Points",
    "RasterDrape",
    "RasterFile",
    "RasterInfo",
    "raster_info",
]

RGBA = tuple[float, float, float, float]
Interpolation = Literal["geodesic", "rhumb"]
#: How the host joins consecutive vertices of `Lines`.
INTERPOLATIONS: tuple[str, ...] = ("geodesic", "rhumb")
POINT_KINDS: tuple[str, ...] = ("placemark", "box", "cone")


@dataclass(frozen=True)
class Lines:
    """Polylines draped on the terrain, one style for all of them.

    Attributes:
        paths: the polylines, each an (N, 2) array-like of (lon, lat) degrees (N >= 2); a
            single (N, 2) array is one polyline.
        interpolation: how vertices are joined: ``"geodesic"`` (the shortest path on the
            WGS84 ellipsoid) or ``"rhumb"`` (constant bearing; a segment between two points
            of the same latitude stays on that parallel, as graticules and zone borders need).
            The host inserts vertices along the chosen curve, so sparse input draws curved.
        color: RGBA 0..1. width_px: line width in screen pixels. dash_px: dash length in
            pixels (0: solid).
        closed: join each polyline's last vertex to its first.
        segment_m: the longest piece (metres) between vertices the host inserts along the
            curve (coarser versions are made for far views).
        name: shown in the overlay panel (default: the file name).
        legend: this drawable's entry in its layer's legend (API 1.5; "": none), e.g. the
            value of the field a layer is coloured by.
    """

    paths: Any
    interpolation: Interpolation = "geodesic"
    color: RGBA = (1.0, 0.9, 0.2, 1.0)
    width_px: float = 1.5
    dash_px: float = 0.0
    closed: bool = False
    segment_m: float = 20_000.0
    name: str = ""
    legend: str = ""

    def path_list(self) -> list[np.ndarray]:
        """The polylines as a list of (N, 2) float64 arrays (a single array: one path)."""
        p = self.paths
        if isinstance(p, np.ndarray) and p.ndim == 2:
            return [np.asarray(p, np.float64)]
        return [np.asarray(q, np.float64) for q in p]

    @classmethod
    def from_geojson(cls, path: str | Path, **style: Any) -> Lines:
        """LineString / MultiLineString / Polygon / MultiPolygon outlines of a GeoJSON file
        (WGS84), polygon rings closed as stored; ``style`` as the fields above. Raises
        `GlobeviewError` (one line) for a file without usable line geometry."""
        # Deferred: the plugin API imports this module when a manifest is read, which must
        # not load the terrain package (nor rasterio, below).
        from globeview.terrain.vectors import read_geojson_lines

        pl = read_geojson_lines(path)
        xy = np.stack([pl.lon, pl.lat], axis=1)
        paths = [xy[a:b] for a, b in zip(pl.starts[:-1], pl.starts[1:], strict=True)]
        style.setdefault("name", Path(path).name)
        return cls(paths, **style)


@dataclass(frozen=True)
class Points:
    """Point objects on the terrain with optional text labels.

    Attributes:
        lon, lat: (N,) degrees.
        labels: N strings drawn beside the points (empty: no labels).
        kind: ``"placemark"`` (a screen-facing dot of ``size_px``), ``"box"`` or ``"cone"``
            (3-D objects ``scale_m`` metres tall).
        size_px, scale_m: one number for every point, or (API 1.2) an (N,) array, one per
            point; each in (0, 500] pixels / (0, 1e7] metres.
        color: RGBA 0..1 for every point, or (API 1.2) an (N, 3 or 4) array, one per point;
            label_color: the labels' RGBA.
        name: shown in the overlay panel (default: the file name).
        legend: this drawable's entry in its layer's legend (API 1.5; "": none).

    Per-point arrays of the wrong length or with NaN fail the layer type that returned them
    (one line). The overlay panel shows the first point's size and colour; setting one
    there gives every point that value.
    """

    lon: Any
    lat: Any
    labels: Sequence[str] = ()
    kind: str = "placemark"
    size_px: float = 10.0
    scale_m: float = 1000.0
    color: RGBA = (1.0, 0.25, 0.15, 1.0)
    label_color: RGBA = (1.0, 1.0, 1.0, 1.0)
    name: str = ""
    legend: str = ""

    @classmethod
    def from_geojson(cls, path: str | Path, **style: Any) -> Points:
        """Point / MultiPoint features of a GeoJSON file, labelled by their ``name``
        property. Raises `GlobeviewError` (one line) for a file without points."""
        from globeview.terrain.vectors import read_geojson_points  # deferred, as above

        lon, lat, names = read_geojson_points(path)
        style.setdefault("name", Path(path).name)
        return cls(lon, lat, names, **style)


@dataclass(frozen=True)
class RasterDrape:
    """An RGBA image draped on the terrain over a lon/lat box.

    Attributes:
        rgba: (H, W, 4) or (H, W, 3) uint8 array, row 0 at the north edge; alpha 0 is
            transparent.
        bounds: (west, south, east, north) degrees of the image's outer edges (pixels are
            equal steps of longitude and latitude: plate carree).
        opacity: 0..1, multiplied with the image's alpha.
        name: shown in the overlay panel (default: the file name).
    """

    rgba: Any
    bounds: tuple[float, float, float, float]
    opacity: float = 1.0
    name: str = ""


@dataclass(frozen=True)
class RasterFile:
    """A raster file GDAL reads (any CRS), draped at full resolution: the host warps only
    the window each terrain tile needs, so rasters larger than memory drape too.

    Attributes:
        path: the raster. RGB(A) or paletted bands are drawn as they are; a single band
            without a colour table is coloured by ``ramp``.
        ramp: colour stops ``[(value, (r, g, b)), ...]`` (0..255) for a single band; None:
            grey from the band's minimum to maximum. A layer with a ramp is listed as
            'thematic', one without as 'imagery'.
        opacity: 0..1.
        name: shown in the overlay panel (default: the file name).
    """

    path: str | Path
    ramp: Sequence[tuple[float, tuple[int, int, int]]] | None = None
    opacity: float = 1.0
    name: str = ""


Drawable = Lines | Points | RasterDrape | RasterFile


@dataclass(frozen=True)
class RasterInfo:
    """What `raster_info` found in a raster file: ``bands``, whether band 1 has a colour
    table (``palette``), and band 1's approximate ``minimum``/``maximum`` (NaN unless asked)."""

    bands: int
    palette: bool
    minimum: float = float("nan")
    maximum: float = float("nan")


def raster_info(path: str | Path, stats: bool = False) -> RasterInfo:
    """Read a raster file's header (GDAL): band count, colour table, and with ``stats``
    band 1's approximate range. Raises `GlobeviewError` (one line) when GDAL cannot read
    it, so a layer type can sniff and describe rasters without importing GDAL itself."""
    import rasterio  # deferred (heavy: GDAL), as the terrain in `Lines.from_geojson`

    p = Path(path)
    try:
        # PAM off: GDAL would save the statistics asked for below as NAME.aux.xml beside the
        # user's file.
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(p) as ds:
            count = int(ds.count)
            try:
                palette = count == 1 and bool(ds.colormap(1))
            except ValueError:
                palette = False
            lo = hi = float("nan")
            if stats and count >= 1:
                st = ds.statistics(1, approx=True)
                lo, hi = float(st.min), float(st.max)
    except Exception as exc:  # noqa: BLE001  GDAL/rasterio raise many types: the file's one-line error
        first = (str(exc).splitlines() or ["unreadable"])[0]
        raise GlobeviewError(f"{p.name}: cannot read as a raster ({first:.120})") from None
    return RasterInfo(count, palette, lo, hi)
