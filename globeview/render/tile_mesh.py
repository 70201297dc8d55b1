"""CPU-side geometry of one terrain tile, built once when the tile is loaded.

A tile of ``size = 2^n + 1`` nodes per side becomes:

- vertices, float32 (V, 6): ``x, y, z`` = the node's point on the ellipsoid (height 0) in ECEF
  **relative to the tile centre** (relative-to-centre rendering: small numbers, so float32
  keeps centimetres), ``h`` = the node's height in metres (the vertex shader adds
  ``h * exaggeration`` along the geodetic normal, so exaggeration is a live uniform), and
  ``u, v`` texture coordinates of the node's texel centre. The grid nodes come first, row-major
  (row 0 at the north edge), then four skirts (north, south, west, east edges), whose vertices
  repeat the edge nodes ``skirt_depth`` metres lower and as far outward, to hide cracks between
  tiles drawn at different resolutions.
- normals, float32 (size, size, 3): unit ECEF normals averaged from the eight triangles
  around each node (Wang thesis §3.2.2: two triangles per surrounding cell), computed once
  and cached with the tile (§3.2.3). The fragment shader reads them from a texture, so a tile
  drawn with a coarse index stride still shades with full-resolution normals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from globeview.geodesy import enu_basis, lonlat_to_ecef

FLOATS_PER_VERTEX = 6


def vertices_per_tile(size: int) -> int:
    """Grid nodes plus four skirts of ``size`` vertices each."""
    return size * size + 4 * size


@dataclass(frozen=True)
class TileMesh:
    """Geometry of one tile ready for upload (see module docstring for the layout)."""

    center: np.ndarray  # (3,) ECEF float64, metres
    vertices: np.ndarray  # (V, 6) float32
    normals: np.ndarray  # (size, size, 3) float32, ECEF unit vectors
    heights: np.ndarray  # (size, size) float32, metres
    skirt_depth: float


def node_lonlat(
    bounds: tuple[float, float, float, float], size: int
) -> tuple[np.ndarray, np.ndarray]:
    """Longitudes (size,) west->east and latitudes (size,) north->south of a tile's nodes."""
    west, south, east, north = bounds
    return np.linspace(west, east, size), np.linspace(north, south, size)


def build_tile_mesh(
    bounds: tuple[float, float, float, float],
    heights: np.ndarray,
    skirt_depth: float,
    apron: np.ndarray | None = None,
) -> TileMesh:
    """Build a tile's vertices and normals.

    Args:
        bounds: (west, south, east, north) in degrees.
        heights: (size, size) float32 metres, row 0 at the north edge; no NaN.
        skirt_depth: how far (m) the skirts hang below the edge nodes.
        apron: optional (size + 2, size + 2) heights including one node beyond each edge, so
            edge normals average the neighbour's triangles too (no shading seams).
    """
    size = heights.shape[0]
    lon, lat = node_lonlat(bounds, size)
    lon_g, lat_g = np.meshgrid(lon, lat)
    base = lonlat_to_ecef(lon_g, lat_g, 0.0)  # (size, size, 3) float64
    mid_lon = 0.5 * (bounds[0] + bounds[2])
    mid_lat = 0.5 * (bounds[1] + bounds[3])
    center = np.asarray(lonlat_to_ecef(mid_lon, mid_lat, 0.0), dtype=np.float64).reshape(3)

    if apron is not None:
        normals = _vertex_normals_apron(bounds, apron)
    else:
        normals = _vertex_normals(lonlat_to_ecef(lon_g, lat_g, heights.astype(np.float64)))

    tex = (np.arange(size) + 0.5) / size
    u_g, v_g = np.meshgrid(tex, tex)
    grid = np.concatenate(
        [
            (base - center).reshape(-1, 3),
            heights.reshape(-1, 1),
            u_g.reshape(-1, 1),
            v_g.reshape(-1, 1),
        ],
        axis=1,
    )
    # Skirts: north, south, west, east edges (the order tile_indices.py expects).
    edges = [
        (slice(0, 1), slice(None)),
        (slice(size - 1, size), slice(None)),
        (slice(None), slice(0, 1)),
        (slice(None), slice(size - 1, size)),
    ]
    grid3 = grid.reshape(size, size, FLOATS_PER_VERTEX)
    # Skirts slant outward as well as down (45 degrees): a vertical skirt is edge-on when seen
    # from straight above, and there the curved edge of a finer neighbour and the straight
    # chord of a coarser one leave a sliver only an outward-leaning skirt can fill.
    basis = enu_basis(lon_g, lat_g)  # (size, size, 3, 3) rows E, N, U
    outward = [basis[0, :, 1], -basis[-1, :, 1], -basis[:, 0, 0], basis[:, -1, 0]]
    skirts = []
    for (rows, cols), out_dir in zip(edges, outward, strict=True):
        s = grid3[rows, cols].reshape(size, FLOATS_PER_VERTEX).copy()
        s[:, :3] += out_dir * skirt_depth
        s[:, 3] -= skirt_depth
        skirts.append(s)
    vertices = np.concatenate([grid, *skirts], axis=0).astype(np.float32)
    return TileMesh(
        center=center,
        vertices=vertices,
        normals=normals.astype(np.float32),
        heights=heights.astype(np.float32),
        skirt_depth=float(skirt_depth),
    )


def _vertex_normals(points: np.ndarray) -> np.ndarray:
    """Unit normals at each node of a (size, size, 3) ECEF grid, averaged from the eight
    triangles (two per cell) around it; edge nodes average the triangles they have."""
    p = points - points[points.shape[0] // 2, points.shape[1] // 2]
    a = p[:-1, :-1]  # (r, c)
    b = p[:-1, 1:]  # (r, c+1)   east
    c = p[1:, :-1]  # (r+1, c)   south
    d = p[1:, 1:]  # (r+1, c+1)
    # Rows run south and columns east, so cross(south, east) points up (outward).
    n1 = np.cross(c - a, b - a)  # triangle a, c, b
    n2 = np.cross(d - b, d - c)  # triangle b, c, d:  cross(south-ish, east-ish)
    n1 /= np.maximum(np.linalg.norm(n1, axis=2, keepdims=True), 1e-30)
    n2 /= np.maximum(np.linalg.norm(n2, axis=2, keepdims=True), 1e-30)
    cell = n1 + n2
    acc = np.zeros_like(p)
    acc[:-1, :-1] += cell
    acc[:-1, 1:] += cell
    acc[1:, :-1] += cell
    acc[1:, 1:] += cell
    norm = np.linalg.norm(acc, axis=2, keepdims=True)
    # A pole row collapses to one point: its cells are degenerate; fall back to the radial up.
    radial = points / np.linalg.norm(points, axis=2, keepdims=True)
    return np.where(norm > 1e-12, acc / np.maximum(norm, 1e-30), radial)


def _vertex_normals_apron(
    bounds: tuple[float, float, float, float], apron: np.ndarray
) -> np.ndarray:
    size = apron.shape[0] - 2
    west, south, east, north = bounds
    step_lon = (east - west) / (size - 1)
    step_lat = (north - south) / (size - 1)
    lon = west + step_lon * np.arange(-1, size + 1)
    lat = np.clip(north - step_lat * np.arange(-1, size + 1), -90.0, 90.0)
    lon_g, lat_g = np.meshgrid(lon, lat)
    pts = lonlat_to_ecef(lon_g, lat_g, apron.astype(np.float64))
    return _vertex_normals(pts)[1:-1, 1:-1]
