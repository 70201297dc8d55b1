"""Polar stereographic DEMs around a pole (EPSG:3413 north, EPSG:3031 south) ingest at any
resolution with their heights. Two faults of coarse ones (20 km pixels: the finest level's
chunk windows span a hemisphere): nodes on the pole row among the data-edge candidates had
neighbours past the pole (latitude beyond +-90) that PROJ refused ("stere: Invalid
latitude": a valid DEM was an error line), and the source read of such a window was
decimated by the spread of the whole window in the source's frame (the far latitudes map
to huge distances), one averaged pixel: every node got the DEM's mean height."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from pyproj import Transformer

from globeview.terrain.compose.height_query import composed_heights
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.interpolate import bilinear
from globeview.terrain.store.tile_store import TileStore

N, PIXEL_M = 50, 20_000.0  # a 1 000 km square of 20 km pixels, centred on the pole


def _polar_dem(path: Path, crs: str) -> tuple[Path, np.ndarray, Affine]:
    """A gently varying plateau (2 200..2 800 m, ellipsoidal) on a north-up grid centred on
    the pole of the polar stereographic ``crs``; returns the file, heights and transform."""
    r, c = np.mgrid[0:N, 0:N].astype(np.float64)
    heights = (2500.0 + 300.0 * np.sin(r / N * 6.0) * np.cos(c / N * 5.0)).astype(np.float32)
    half = N * PIXEL_M / 2.0
    transform = Affine(PIXEL_M, 0.0, -half, 0.0, -PIXEL_M, half)  # the pole is at (0, 0)
    profile = dict(driver="GTiff", width=N, height=N, count=1, dtype="float32")
    with rasterio.open(path, "w", crs=crs, transform=transform, **profile) as ds:
        ds.write(heights, 1)
    return path, heights, transform


def _source_heights(heights: np.ndarray, transform: Affine, x, y) -> np.ndarray:
    """The source's heights bilinear between its pixel centres at projected (x, y) metres."""
    col, row = ~transform @ (np.asarray(x), np.asarray(y))
    return bilinear(heights, np.asarray(row) - 0.5, np.asarray(col) - 0.5)


@pytest.mark.parametrize(("crs", "pole"), [("EPSG:3413", 90.0), ("EPSG:3031", -90.0)])
def test_a_coarse_polar_dem_ingests_with_its_heights(tmp_path: Path, crs: str, pole: float) -> None:
    src, heights, transform = _polar_dem(tmp_path / "pole.tif", crs)
    ingest([src], tmp_path / "store", vdatum="ellipsoid", progress=False)
    store = TileStore.open(tmp_path / "store")
    try:
        stack = TerrainStack.from_stores([store])
        # The pole and rings 100 and 300 km from it (inside the square's 500 km half-width).
        lon = np.concatenate([[0.0], np.tile(np.arange(-180.0, 180.0, 45.0), 2)])
        colat = np.concatenate([[0.0], np.full(8, 0.9), np.full(8, 2.7)])  # degrees
        lat = pole - np.copysign(colat, pole)
        got = composed_heights(stack, lon, lat)
        x, y = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
        want = _source_heights(heights, transform, x, y)
    finally:
        store.close()
    assert np.isfinite(got).all()
    # Bilinear of bilinear on nodes ~20 km apart: the plateau's slope is at most ~40 m a
    # pixel, so the two surfaces differ by tens of metres, not by the plateau's 600 m range
    # (the averaged read gave 2 499.5 m everywhere: up to 280 m off).
    assert np.abs(got - want).max() < 30.0, np.c_[lon, lat, got, want]
