"""Small real tiles named as users get them (issue #25): SRTM 3" .hgt files (1201^2
big-endian int16, the real size, so the name path applies), Copernicus GLO-90-named COGs
(1200^2 float32, DEFLATE) and low-resolution GeoTIFFs; a CF netCDF grid with or without
lat/lon axes. Shared by the footprint, plan and CLI tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio
import rasterio.shutil
from affine import Affine
from rasterio.io import MemoryFile


def srtm_name(lat: int, lon: int) -> str:
    """N44W072.hgt for the cell whose south-west corner is (lat, lon)."""
    ns, ew = ("N" if lat >= 0 else "S"), ("E" if lon >= 0 else "W")
    return f"{ns}{abs(lat):02d}{ew}{abs(lon):03d}.hgt"


def copernicus_name(lat: int, lon: int, arcsec: int = 30) -> str:
    ns, ew = ("N" if lat >= 0 else "S"), ("E" if lon >= 0 else "W")
    return f"Copernicus_DSM_COG_{arcsec}_{ns}{abs(lat):02d}_00_{ew}{abs(lon):03d}_00_DEM.tif"


def hills(n: int, seed: int) -> np.ndarray:
    """A smooth n x n height field (m), 100..1500."""
    y, x = np.mgrid[0:n, 0:n] / n
    ph = seed * 0.7
    return 800 + 700 * np.sin(6 * x + ph) * np.cos(5 * y - ph)


def write_hgt(folder: Path, lat: int, lon: int) -> Path:
    """An SRTM 3" tile: 1201^2 big-endian int16 samples, named for its cell."""
    p = folder / srtm_name(lat, lon)
    hills(1201, lat * 1000 + lon).astype(">i2").tofile(p)
    return p


def write_geotiff(path: Path, west: float, north: float, res: float, n: int, **extra) -> Path:
    """An n x n float32 lon/lat GeoTIFF (EPSG:4326) with its north-west corner at (west,
    north) and ``res``-degree pixels."""
    prof = {
        "driver": "GTiff",
        "width": n,
        "height": n,
        "count": 1,
        "dtype": "float32",
        "crs": "EPSG:4326",
        "transform": Affine(res, 0.0, west, 0.0, -res, north),
        "compress": "deflate",
        **extra,
    }
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(hills(n, int(west * 7 + north)).astype(np.float32), 1)
    return path


def write_copernicus(folder: Path, lat: int, lon: int) -> Path:
    """A Copernicus GLO-90-named COG-shaped tile: 1200^2 at 3", north-west corner at (lon,
    lat + 1)."""
    return write_geotiff(
        folder / copernicus_name(lat, lon), lon, lat + 1, 3 / 3600, 1200, tiled=True
    )


def write_netcdf(path: Path, *, cf_axes: bool, n: int = 90) -> Path:
    """A global netCDF grid (2n x n at 180/n degrees) written by GDAL's netCDF driver with
    no CRS: with ``cf_axes`` its axes are CF lat/lon in degrees (GEBCO's shape, read as
    WGS84); without, the georeferencing is in metres (x/y axes): nothing says lon/lat."""
    res = 180.0 / n
    scale = 1.0 if cf_axes else 111_000.0
    with MemoryFile() as mf:
        with mf.open(
            driver="GTiff",
            width=2 * n,
            height=n,
            count=1,
            dtype="float32",
            transform=Affine(res * scale, 0.0, -180.0 * scale, 0.0, -res * scale, 90.0 * scale),
        ) as ds:
            ds.write(hills(n, 3)[:, np.arange(2 * n) % n].astype(np.float32), 1)
        with mf.open() as src:
            rasterio.shutil.copy(src, path, driver="netCDF")
    return path


def geoid_n(lons: np.ndarray, lats: np.ndarray) -> np.ndarray:
    """The synthetic geoid of `write_geoid_grid` at nodes (degrees, broadcast): a tilt and a
    wave, -40..60 m, nothing like EGM96 (so a source converted with the wrong geoid shows)."""
    lons, lats = np.asarray(lons, dtype=np.float64), np.asarray(lats, dtype=np.float64)
    wave = np.sin(np.radians(lons * 7.0)) * np.cos(np.radians(lats * 5.0))
    return 10.0 + 0.05 * lons - 0.3 * lats + 3.0 * wave


def write_geoid_grid(path: Path, step: float = 1.0, *, closed: bool = True) -> Path:
    """A global node-registered geoid grid GeoTIFF as PROJ's us_nga_egm08_25.tif is laid out
    (float32, nodes from -180 to +180 and +90 to -90, pixel-is-point, EPSG:4326), holding
    `geoid_n` at ``step``-degree nodes: (360/step + 1) x (180/step + 1) samples. Not
    ``closed``: the +180 column left out (the columns wrap, as the shipped EGM96 grid's)."""
    lons = -180.0 + step * np.arange(round(360 / step) + (1 if closed else 0))
    lats = 90.0 - step * np.arange(round(180 / step) + 1)
    prof = {
        "driver": "GTiff",
        "width": lons.size,
        "height": lats.size,
        "count": 1,
        "dtype": "float32",
        "crs": "EPSG:4326",
        "transform": Affine(step, 0.0, -180.0 - step / 2, 0.0, -step, 90.0 + step / 2),
    }
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(geoid_n(lons[None, :], lats[:, None]).astype(np.float32), 1)
        ds.update_tags(AREA_OR_POINT="Point")
    return path
