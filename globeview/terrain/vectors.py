"""Vector data for draping: GeoJSON reading, geodesic densification, heights on the LOD mesh.

- `read_geojson_lines`: LineString / MultiLineString / Polygon / MultiPolygon outlines as
  polylines of WGS84 lon/lat degrees (polygon rings closed). `read_geojson_points`: Point /
  MultiPoint features with a name.
- `densify`: inserts points along each segment's geodesic (pyproj.Geod, WGS84) so no piece is
  longer than ``max_segment_m``; vectorised over all segments. `densify_rhumb` does the same
  along rhumb lines (constant bearing; parallels stay parallels).
- `drape_heights`: each point's height **on the mesh actually drawn** (TREND §5.2): the drawn
  tile containing it (any level of the render set) and that tile's heights sampled at the
  drawn index stride, interpolated bilinearly on that stride's grid; points in no drawn tile
  are flagged. Vectorised over points; one `heights(key)` call per drawn tile that holds points.
- `thin`: drops vertices closer than a spacing along each polyline (the coarser line levels
  of far views: a layer of a million vertices 15 m apart need not draw them all from 150 km).
- `bin_by_tile`: the quadtree key of points at a level (object paging, TREND §5.1.2).

Pure numpy/pyproj: no GL.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from globeview.errors import GlobeviewError, StoreError
from globeview.terrain.quadtree import key_for_lonlat, tile_bounds_arrays

if TYPE_CHECKING:
    from pyproj import Geod


@functools.cache
def _geod() -> Geod:
    """pyproj's WGS84 Geod, made at the first densify (pyproj's import, ~0.07 CPU-s, is off
    the window's launch, issue #27; also ``GEOD``, the module attribute)."""
    from pyproj import Geod

    return Geod(ellps="WGS84")


def __getattr__(name: str) -> Any:
    if name == "GEOD":
        return _geod()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class VectorError(GlobeviewError):
    """A vector file cannot be used (unreadable, not GeoJSON, no usable geometry, ...)."""


@dataclass
class Polylines:
    """Polylines as flat arrays: points ``lon``, ``lat`` (degrees) and ``starts`` (P + 1,)
    offsets of each polyline's first point (the last entry = number of points)."""

    lon: np.ndarray
    lat: np.ndarray
    starts: np.ndarray

    def __len__(self) -> int:
        return len(self.starts) - 1

    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """Index pairs (a, b) of consecutive points within each polyline."""
        idx = np.arange(len(self.lon) - 1)
        last = np.zeros(len(self.lon), bool)
        last[self.starts[1:] - 1] = True
        keep = ~last[:-1]
        return idx[keep], idx[keep] + 1


def _load(path: str | Path) -> dict:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise VectorError(f"{p.name}: cannot read ({exc.strerror or exc})") from None
    if not text.strip():
        raise VectorError(f"{p.name}: the file is empty")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise VectorError(f"{p.name}: not valid GeoJSON ({exc.msg} at line {exc.lineno})") from None
    except RecursionError:  # [[[[...]]]] thousands deep: the parser's stack, not a bug here
        raise VectorError(f"{p.name}: not valid GeoJSON (nested too deeply)") from None
    if not isinstance(doc, dict) or "type" not in doc:
        raise VectorError(f"{p.name}: not a GeoJSON object (no 'type')")
    crs = doc.get("crs")
    if crs is not None:
        name = str((crs.get("properties") or {}).get("name", "")) if isinstance(crs, dict) else ""
        if not any(k in name.upper() for k in ("CRS84", "4326", "WGS84", "WGS 84")):
            raise VectorError(
                f"{p.name}: unsupported CRS {name or crs!r}; GeoJSON must be WGS84 lon/lat"
            )
    return doc


def _features(doc: dict) -> list[dict]:
    t = doc.get("type")
    if t == "FeatureCollection":
        return [f for f in doc.get("features") or [] if isinstance(f, dict)]
    if t == "Feature":
        return [doc]
    return [{"type": "Feature", "geometry": doc, "properties": {}}]


def _rings(geom: dict) -> list:
    t = geom.get("type")
    c: Any = geom.get("coordinates")  # parsed GeoJSON: nested lists, checked by the caller
    if t == "LineString":
        return [c]
    if t == "MultiLineString":
        return list(c)
    if t == "Polygon":
        return list(c)
    if t == "MultiPolygon":
        return [ring for poly in c for ring in poly]
    if t == "GeometryCollection":
        return [r for g in geom.get("geometries") or [] for r in _rings(g)]
    return []


def read_geojson_lines(path: str | Path) -> Polylines:
    """Line and polygon-outline geometry of a GeoJSON file as `Polylines` (lon/lat degrees)."""
    name = Path(path).name
    doc = _load(path)
    parts: list[np.ndarray] = []
    for f in _features(doc):
        geom = f.get("geometry")
        if not isinstance(geom, dict):
            continue
        for ring in _rings(geom):
            try:
                a = np.asarray(ring, dtype=np.float64)
            except (TypeError, ValueError):
                raise VectorError(
                    f"{name}: malformed coordinates in a {geom.get('type')}"
                ) from None
            if a.ndim != 2 or a.shape[1] < 2:
                raise VectorError(f"{name}: malformed coordinates in a {geom.get('type')}")
            if len(a) >= 2:
                parts.append(a[:, :2])
    if not parts:
        raise VectorError(f"{name}: no LineString or Polygon geometry to draw")
    pts = np.concatenate(parts)
    if not (np.all(np.abs(pts[:, 0]) <= 540.0) and np.all(np.abs(pts[:, 1]) <= 90.0)):
        raise VectorError(f"{name}: coordinates are not WGS84 lon/lat degrees")
    starts = np.concatenate([[0], np.cumsum([len(p) for p in parts])]).astype(np.int64)
    return Polylines(pts[:, 0].copy(), pts[:, 1].copy(), starts)


def read_geojson_points(path: str | Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Point / MultiPoint features: lon, lat (degrees) and each point's ``name`` property."""
    name = Path(path).name
    doc = _load(path)
    lon: list[float] = []
    lat: list[float] = []
    names: list[str] = []
    for f in _features(doc):
        geom = f.get("geometry") or {}
        props = f.get("properties") or {}
        t = geom.get("type")
        coords = [geom.get("coordinates")] if t == "Point" else geom.get("coordinates") or []
        if t not in ("Point", "MultiPoint"):
            continue
        for c in coords:
            if not isinstance(c, list | tuple) or len(c) < 2:
                raise VectorError(f"{name}: malformed Point coordinates")
            lon.append(float(c[0]))
            lat.append(float(c[1]))
            names.append(str(props.get("name", "")))
    if not lon:
        raise VectorError(f"{name}: no Point geometry")
    lon_a, lat_a = np.array(lon), np.array(lat)
    # NaN fails both comparisons: non-finite coordinates (1e400 parses as inf) are refused.
    if not (np.all(np.abs(lon_a) <= 540.0) and np.all(np.abs(lat_a) <= 90.0)):
        raise VectorError(f"{name}: coordinates are not WGS84 lon/lat degrees")
    return lon_a, lat_a, names


def _subdivide(
    lines: Polylines,
    lon: np.ndarray,
    lat: np.ndarray,
    a: np.ndarray,
    n_sub: np.ndarray,
    inner: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
) -> Polylines:
    """Polylines with ``n_sub[i] - 1`` points inserted after segment i's start ``a[i]``:
    ``inner(seg, frac)`` gives their (lon, lat) for segment indices and fractions 0 < f < 1.
    ``lon``/``lat`` are the vertices (as the caller wants them kept, e.g. unwrapped)."""
    # Output: for every point, itself; after every segment's start, n_sub - 1 extra points.
    extra = np.zeros(len(lon), np.int64)
    extra[a] = n_sub - 1
    out_starts = np.concatenate([[0], np.cumsum(extra + 1)])
    total = int(out_starts[-1])
    new_lon = np.empty(total)
    new_lat = np.empty(total)
    new_lon[out_starts[:-1]] = lon
    new_lat[out_starts[:-1]] = lat
    seg_of = np.repeat(np.arange(len(a)), n_sub - 1)
    if len(seg_of):
        k = np.arange(len(seg_of)) - np.repeat(np.cumsum(n_sub - 1) - (n_sub - 1), n_sub - 1) + 1
        pos = out_starts[a][seg_of] + k
        new_lon[pos], new_lat[pos] = inner(seg_of, k / n_sub[seg_of])
    return Polylines(new_lon, new_lat, out_starts[lines.starts])


def densify(lines: Polylines, max_segment_m: float) -> Polylines:
    """Insert points along geodesics so no segment is longer than ``max_segment_m`` metres."""
    a, b = lines.segments()
    lon, lat = lines.lon, lines.lat
    az, _, dist = _geod().inv(lon[a], lat[a], lon[b], lat[b])
    az, dist = np.asarray(az), np.asarray(dist)
    n_sub = np.maximum(np.ceil(dist / max_segment_m).astype(np.int64), 1)

    def along(seg: np.ndarray, frac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        flon, flat, _ = _geod().fwd(lon[a][seg], lat[a][seg], az[seg], dist[seg] * frac)
        # Keep longitudes continuous with the segment start (no jump across +-180).
        flon = np.asarray(flon)
        return flon + 360.0 * np.round((lon[a][seg] - flon) / 360.0), np.asarray(flat)

    return _subdivide(lines, lon, lat, a, n_sub, along)


#: Rhumb lines stop this close to a pole (degrees): the loxodrome spirals into it forever.
RHUMB_MAX_LAT = 89.9


def _isometric_lat(lat_deg: np.ndarray) -> np.ndarray:
    """Isometric latitude psi (radians) on WGS84: the Mercator ordinate, in which rhumb lines
    are straight."""
    e = float(np.sqrt(_geod().es))
    s = np.sin(np.radians(lat_deg))
    return np.arctanh(s) - e * np.arctanh(e * s)


def _lat_from_isometric(psi: np.ndarray) -> np.ndarray:
    """Inverse of `_isometric_lat` (degrees), by fixed-point iteration (converges to 1e-15
    rad in under 10 steps: the correction is scaled by e^2)."""
    e = float(np.sqrt(_geod().es))
    phi = np.arcsin(np.tanh(psi))
    for _ in range(12):
        phi = np.arcsin(np.tanh(psi + e * np.arctanh(e * np.sin(phi))))
    return np.degrees(phi)


def densify_rhumb(lines: Polylines, max_segment_m: float) -> Polylines:
    """Insert points along rhumb lines (constant bearing: straight in Mercator) so no piece
    is longer than about ``max_segment_m`` metres; a segment between two points of the same
    latitude stays on that parallel exactly. Longitudes go the short way round (a segment
    from 170 to -170 crosses the antimeridian) and stay continuous; latitudes are kept
    within `RHUMB_MAX_LAT` of the equator."""
    a, b = lines.segments()
    lat = np.clip(lines.lat, -RHUMB_MAX_LAT, RHUMB_MAX_LAT)
    dlon = (lines.lon[b] - lines.lon[a] + 180.0) % 360.0 - 180.0
    # Unwrapped longitudes: each polyline continues from its first vertex by short steps.
    step = np.zeros(len(lat))
    step[b] = dlon
    cum = np.cumsum(step)
    first = np.repeat(lines.starts[:-1], np.diff(lines.starts))
    lon = lines.lon[first] + cum - cum[first]
    psi = _isometric_lat(lat)
    dpsi = psi[b] - psi[a]
    dphi = np.radians(lat[b] - lat[a])
    # Length on the mean sphere: q = dphi / dpsi (cos lat along a parallel).
    q = np.where(
        np.abs(dpsi) > 1e-12, dphi / np.where(dpsi == 0, 1.0, dpsi), np.cos(np.radians(lat[a]))
    )
    dist = 6_371_008.8 * np.hypot(dphi, q * np.radians(dlon))
    n_sub = np.maximum(np.ceil(dist / max_segment_m).astype(np.int64), 1)

    def along(seg: np.ndarray, frac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        same_lat = lat[a][seg] == lat[b][seg]
        inner = _lat_from_isometric(psi[a][seg] + frac * dpsi[seg])
        return lon[a][seg] + frac * dlon[seg], np.where(same_lat, lat[a][seg], inner)

    return _subdivide(lines, lon, lat, a, n_sub, along)


def segment_lengths_m(lines: Polylines) -> np.ndarray:
    """Approximate length (m) of every segment (`Polylines.segments` order): the chord on
    the mean sphere, from the equirectangular approximation (good to ~1 % below 100 km)."""
    a, b = lines.segments()
    lat_mid = np.radians(0.5 * (lines.lat[a] + lines.lat[b]))
    dlon = (lines.lon[b] - lines.lon[a] + 180.0) % 360.0 - 180.0
    dx = np.radians(dlon) * np.cos(lat_mid)
    dy = np.radians(lines.lat[b] - lines.lat[a])
    return 6_371_008.8 * np.hypot(dx, dy)


def thin(lines: Polylines, spacing_m: float, lengths: np.ndarray | None = None) -> Polylines:
    """``lines`` keeping, along each polyline, its first and last vertex and the first vertex
    past each multiple of ``spacing_m`` metres of length from its start (vectorised). A
    dropped vertex lies within about ``spacing_m`` of the thinned line. ``lengths``: the
    segments' `segment_lengths_m`, when the caller has them."""
    _, b = lines.segments()
    along = np.zeros(len(lines.lon))
    along[b] = segment_lengths_m(lines) if lengths is None else lengths
    along = np.cumsum(along)
    counts = np.diff(lines.starts)
    along -= np.repeat(along[lines.starts[:-1]], counts)
    bucket = np.floor(along / float(spacing_m)).astype(np.int64)
    keep = np.ones(len(along), bool)
    keep[1:] = bucket[1:] != bucket[:-1]
    keep[lines.starts[:-1]] = True
    keep[lines.starts[1:] - 1] = True
    kept = np.add.reduceat(keep.astype(np.int64), lines.starts[:-1]) if len(counts) else counts
    starts = np.concatenate([[0], np.cumsum(kept)]).astype(np.int64)
    return Polylines(lines.lon[keep], lines.lat[keep], starts)


def bin_by_tile(level: int, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """(N, 3) int64 keys (level, x, y) of the tiles at ``level`` containing the points."""
    x, y = key_for_lonlat(level, lon, lat)
    x = np.asarray(x, np.int64).reshape(-1)
    y = np.asarray(y, np.int64).reshape(-1)
    return np.stack([np.full_like(x, level), x, y], axis=1)


def _codes(level: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return (np.asarray(level, np.int64) << 58) | (np.asarray(y, np.int64) << 29) | x


def drape_heights(
    heights: Callable[[tuple[int, int, int]], np.ndarray],
    keys: np.ndarray,
    strides: np.ndarray,
    lon: np.ndarray,
    lat: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heights (m) of points on the drawn LOD mesh.

    Args:
        heights: tile key -> (size, size) node heights (`TerrainStack.heights`).
        keys: (T, 3) drawn tiles; strides: (T,) their index strides (1 = every node).
        lon, lat: (N,) points, degrees.

    Returns:
        h (N,) metres (0 where not drawn), drawn (N,) bool, tile (N,) row into ``keys`` (-1).
    """
    lon = np.asarray(lon, np.float64)
    lat = np.asarray(lat, np.float64)
    n = len(lon)
    h = np.zeros(n)
    tile = np.full(n, -1, np.int64)
    keys = np.asarray(keys, np.int64).reshape(-1, 3)
    if len(keys) == 0 or n == 0:
        return h, np.zeros(n, bool), tile
    codes = _codes(keys[:, 0], keys[:, 1], keys[:, 2])
    order = np.argsort(codes)
    sorted_codes = codes[order]
    wrapped = (lon + 180.0) % 360.0 - 180.0
    wrapped = np.where(lon == 180.0, 180.0, wrapped)
    for level in np.unique(keys[:, 0]):
        todo = tile < 0
        if not todo.any():
            break
        x, y = key_for_lonlat(int(level), wrapped[todo], lat[todo])
        c = _codes(np.full(len(x), level), np.asarray(x), np.asarray(y))
        pos = np.minimum(np.searchsorted(sorted_codes, c), len(sorted_codes) - 1)
        hit = sorted_codes[pos] == c
        idx = np.nonzero(todo)[0]
        tile[idx[hit]] = order[pos[hit]]
    drawn = tile >= 0
    for t in np.unique(tile[drawn]):
        sel = tile == t
        t_level, t_x, t_y = (int(v) for v in keys[t])
        s = max(int(strides[t]), 1)
        try:
            grid = heights((t_level, t_x, t_y))[::s, ::s].astype(np.float64)
        except StoreError:
            # A remote tile that cannot be read now (not fetched yet on the window's UI
            # thread, which never waits for the network, or failed): its points are left
            # undrawn this time rather than failing the frame.
            drawn[sel] = False
            tile[sel] = -1
            continue
        w, so, e, no = (float(v) for v in tile_bounds_arrays(t_level, t_x, t_y))
        m = grid.shape[0] - 1
        cc = np.clip((wrapped[sel] - w) / (e - w) * m, 0.0, m)
        rr = np.clip((no - lat[sel]) / (no - so) * m, 0.0, m)
        c0 = np.minimum(np.floor(cc).astype(np.int64), m - 1)
        r0 = np.minimum(np.floor(rr).astype(np.int64), m - 1)
        fc, fr = cc - c0, rr - r0
        top = grid[r0, c0] * (1 - fc) + grid[r0, c0 + 1] * fc
        bot = grid[r0 + 1, c0] * (1 - fc) + grid[r0 + 1, c0 + 1] * fc
        h[sel] = top * (1 - fr) + bot * fr
    return h, drawn, tile
