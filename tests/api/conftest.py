"""Fixtures for the Python API's tests: the White Mountains DEM (SRTM N44W072, shipped in
data/) as a numpy array with its transform and CRS, and one headless `globeview.Globe` on it
for the module (rendering on llvmpipe is slow), with a cache folder
of the process's own (`api_cache`)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

#: Every n-th post of the 1201 x 1201 SRTM3 tile: a 401 x 401 grid (~270 m), quick to ingest.
STEP = 3


@pytest.fixture(scope="session")
def white_mountains() -> tuple[np.ndarray, object, str]:
    """(heights (rows, cols) int16 metres, affine transform, CRS text) of N44W072.hgt
    (44..45 N, 72..71 W), thinned to every `STEP`-th post."""
    import rasterio
    from affine import Affine

    from globeview.terrain.dem.data import EMBEDDED_DATA_DIR

    with rasterio.open(EMBEDDED_DATA_DIR / "N44W072.hgt") as src:
        heights = src.read(1)[::STEP, ::STEP].copy()
        transform = src.transform @ Affine.scale(STEP)
        crs = src.crs.to_string()
    return heights, transform, crs


@pytest.fixture(scope="module")
def api_cache(tmp_path_factory) -> Iterator[str]:
    """The cache folder (GLOBEVIEW_CACHE_DIR, set for the module) for arrays and stores: one
    for the API modules of this pytest process, never the user's. Arrays are cached by
    content, so the White Mountains array `wm_globe` adds is ingested once a process, not once
    a module (~2 CPU-s each); a test about what a call adds to the cache compares the folder
    before and after."""
    cache = tmp_path_factory.getbasetemp() / "api-cache"
    cache.mkdir(exist_ok=True)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GLOBEVIEW_CACHE_DIR", str(cache))
        yield str(cache)


@pytest.fixture(scope="module")
def registry():
    """The installed plugins with settings in memory (nothing read or written)."""
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    return PluginRegistry(MemorySettings()).discover()


@pytest.fixture(scope="module")
def wm_globe(api_cache, white_mountains, registry):
    """A `globeview.Globe` with the White Mountains added as an array, looking at Mount
    Washington from the south-west; closed after the module."""
    import globeview

    heights, transform, crs = white_mountains
    globe = globeview.Globe(registry=registry)
    globe.add_dem(heights, transform=transform, crs=crs, name="white_mountains")
    globe.fly_to(-71.45, 44.12, 9000.0, heading=40.0, pitch=-30.0)
    yield globe
    globe.close()
