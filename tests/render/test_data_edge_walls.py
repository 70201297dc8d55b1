"""No hole where a DEM's data-edge wall meets another tile (issue #25).

Past a DEM's data edge the surface drops to the bare ellipsoid within one node spacing: a
wall hundreds of metres high. A tile beside it drawn at another level, or a tile without
data, meets the tile's edge up to that whole wall lower, and the skirts (3 x the tile's own
stride error deep) did not reach down there: seen from above, a triangle of the background
showed between the raised land and the ground. Here a 2 x 2 km hill ~450 m high with a lobed,
ragged nodata outline is rendered over an all-ground frame with a magenta background: no
pixel may be magenta.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from inprocess_cli import run_globeview
from PIL import Image

#: UTM 19N (EPSG:32619) metres of the raster's centre: about 71.40 W 44.35 N.
CENTRE_EN = (308_700.0, 4_913_550.0)
CENTRE_LONLAT = (-71.40, 44.35)
PIXELS, PIXEL_M = 512, 4.0
MAGENTA = "1,0,1"


def _lobed_hill() -> np.ndarray:
    """(PIXELS, PIXELS) float32 heights (m): a ~450 m hill, nodata (-9999) outside a lobed
    outline with a pixel-scale ragged edge."""
    rows, cols = np.mgrid[0:PIXELS, 0:PIXELS].astype(np.float64)
    dx, dy = (cols - PIXELS / 2) * PIXEL_M, (PIXELS / 2 - rows) * PIXEL_M
    theta = np.arctan2(dy, dx)
    radius = 750.0 * (1.0 + 0.2 * np.sin(3 * theta) + 0.12 * np.sin(7 * theta + 1.0))
    radius += 6.0 * np.sin(rows * 1.7) * np.cos(cols * 2.3)  # ragged, a pixel or two
    z = 420.0 + 60.0 * np.cos(dx / 400.0) * np.sin(dy / 350.0 + 0.5)
    return np.where(np.hypot(dx, dy) <= radius, z, -9999.0).astype(np.float32)


@pytest.fixture(scope="module")
def hill(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("wall") / "lobed_hill.tif"
    west = CENTRE_EN[0] - PIXELS * PIXEL_M / 2
    north = CENTRE_EN[1] + PIXELS * PIXEL_M / 2
    prof = {
        "driver": "GTiff",
        "width": PIXELS,
        "height": PIXELS,
        "count": 1,
        "dtype": "float32",
        "transform": Affine(PIXEL_M, 0.0, west, 0.0, -PIXEL_M, north),
        "crs": "EPSG:32619",
        "nodata": -9999.0,
    }
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(_lobed_hill(), 1)
    return path


def _camera(heading_deg: float, dist_m: float, height_m: float, pitch_deg: float) -> str:
    """--camera value ``dist_m`` from the hill's centre, looking along ``heading_deg``."""
    a = math.radians(heading_deg)
    lat = CENTRE_LONLAT[1] - dist_m * math.cos(a) / 111_000.0
    lon = CENTRE_LONLAT[0] - dist_m * math.sin(a) / (111_000.0 * math.cos(math.radians(lat)))
    return f"--camera={lon:.5f},{lat:.5f},{height_m},{heading_deg},{pitch_deg}"


def test_no_background_between_the_walls_and_the_ground(hill: Path, tmp_path: Path) -> None:
    # Looking south-west: before the fix, 232 background pixels in slivers beside
    # the hill.
    out = tmp_path / "wall.png"
    res = run_globeview(
        [
            "render",
            str(hill),
            _camera(225.0, 4000.0, 2500.0, -35.0),
            "--size",
            "480x270",
            "--background",
            MAGENTA,
            "--out",
            str(out),
        ],
        env={"GLOBEVIEW_CACHE_DIR": str(hill.parent / "cache")},  # never the user's cache
    )
    assert res.returncode == 0, res.stderr
    rgb = np.asarray(Image.open(out).convert("RGB")).astype(np.int64)
    magenta = (rgb[..., 0] > 240) & (rgb[..., 1] < 20) & (rgb[..., 2] > 240)
    # The frame is all ground (the horizon lies above it), so any magenta pixel is a hole.
    assert not magenta.any(), f"{int(magenta.sum())} background pixels, first at " + str(
        np.argwhere(magenta)[:3].tolist()
    )
