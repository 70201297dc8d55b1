"""A geoid undulation grid: N (metres, height of the geoid above the WGS84 ellipsoid) on a
regular lon/lat grid, interpolated bilinearly. Pure numpy; loading a grid file is terrain's job
(`globeview.terrain.dem.vdatum`).

Heights: h (ellipsoidal, above WGS84) = H (orthometric, above the geoid) + N.
"""

from __future__ import annotations

import numpy as np


class Geoid:
    """N on a regular grid of nodes, north row first.

    ``grid[i, j]`` is N (m) at the *node* lon = west + j*dlon, lat = north - i*dlat (degrees).
    The EGM96 15' GTX grid is node-registered (pixel-is-point): 1440 x 721 nodes at
    lon -180, -179.75, ..., 179.75 and lat 90, 89.75, ..., -90, so its first and last rows sit
    on the poles and its columns stop a step short of +180.

    Longitude wraps when the columns span 360 degrees: the cell between the last column
    (179.75) and +180 interpolates towards column 0 (-180 == +180), so there is no seam and any
    longitude (e.g. 190 or -540) is reduced modulo 360. Latitude is clamped to the grid's rows:
    at a pole the grid's pole row holds one value repeated, so N there is that value and
    latitudes past +-90 read the pole. A non-finite lon or lat gives NaN.
    """

    def __init__(
        self, grid: np.ndarray, west: float, north: float, dlon: float, dlat: float
    ) -> None:
        g = np.asarray(grid, dtype=np.float64)
        if g.ndim != 2 or g.shape[0] < 2 or g.shape[1] < 2:
            raise ValueError(f"a geoid grid needs at least 2 x 2 nodes, got shape {g.shape}")
        if not (dlon > 0 and dlat > 0):
            raise ValueError(f"grid steps must be positive, got dlon={dlon}, dlat={dlat}")
        self.grid = g
        self.west = float(west)
        self.north = float(north)
        self.dlon = float(dlon)
        self.dlat = float(dlat)
        self.rows, self.cols = g.shape
        self.wraps = abs(self.cols * self.dlon - 360.0) < 1e-9

    def _col_weights(self, lon: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Column pair (j0, j1) and the weight of j1 for each longitude (degrees)."""
        x = (lon - self.west) / self.dlon
        if self.wraps:
            x = np.mod(x, self.cols)
            j0 = np.floor(x).astype(np.int64)
            # mod can round up to exactly cols for tiny negative x: that is column 0.
            j0 = np.where(j0 >= self.cols, 0, j0)
            t = x - np.floor(x)
            j1 = (j0 + 1) % self.cols
        else:
            x = np.clip(x, 0.0, self.cols - 1)
            j0 = np.minimum(np.floor(x).astype(np.int64), self.cols - 2)
            t = x - j0
            j1 = j0 + 1
        return j0, j1, t

    def _row_weights(self, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Row pair (i0, i1) and the weight of i1 for each latitude (degrees), clamped."""
        y = np.clip((self.north - lat) / self.dlat, 0.0, self.rows - 1)
        i0 = np.minimum(np.floor(y).astype(np.int64), self.rows - 2)
        return i0, i0 + 1, y - i0

    def undulation(self, lon_deg: np.ndarray, lat_deg: np.ndarray) -> np.ndarray:
        """N (m) at points (degrees, broadcast together), bilinear between the four nodes
        around each point; exact at the nodes."""
        lon, lat = np.broadcast_arrays(
            np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64)
        )
        bad = ~(np.isfinite(lon) & np.isfinite(lat))
        lon = np.where(bad, 0.0, lon)
        lat = np.where(bad, 0.0, lat)
        j0, j1, u = self._col_weights(lon)
        i0, i1, v = self._row_weights(lat)
        g = self.grid
        top = g[i0, j0] * (1.0 - u) + g[i0, j1] * u
        bottom = g[i1, j0] * (1.0 - u) + g[i1, j1] * u
        n = top * (1.0 - v) + bottom * v
        return np.where(bad, np.nan, n)

    def undulation_grid(self, lons_deg: np.ndarray, lats_deg: np.ndarray) -> np.ndarray:
        """N (m) on the grid lats x lons (1-D arrays of node coordinates, degrees): shape
        (len(lats), len(lons)). Same values as `undulation` on the mesh, but the weights are
        computed once per row and per column (a DEM window's nodes are such a grid)."""
        lons = np.asarray(lons_deg, dtype=np.float64).reshape(-1)
        lats = np.asarray(lats_deg, dtype=np.float64).reshape(-1)
        if not (np.isfinite(lons).all() and np.isfinite(lats).all()):
            return self.undulation(lons[None, :], lats[:, None])
        j0, j1, u = self._col_weights(lons)
        i0, i1, v = self._row_weights(lats)
        # Bilinear is separable: interpolate along longitude on the few grid rows the window
        # touches (k x w), then along latitude with whole-row gathers (h x w): two cheap passes
        # instead of four scattered gathers of h x w.
        rows = np.unique(np.concatenate([i0, i1]))
        g = self.grid[rows]
        along = g[:, j0] * (1.0 - u) + g[:, j1] * u
        a0 = np.searchsorted(rows, i0)
        a1 = np.searchsorted(rows, i1)
        return along[a0] * (1.0 - v)[:, None] + along[a1] * v[:, None]
