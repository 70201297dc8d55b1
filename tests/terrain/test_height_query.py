"""The point height query (`globeview.terrain.compose.height_query`) on real stores ingested from
rasters written here: it answers the surface the LOD converges to (the composed tile nodes at
the finest level, bilinear between them), vectorised over points, and names the layer that
answered."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from globeview.errors import GlobeviewError
from globeview.terrain.compose.height_query import (
    NO_LAYER,
    answering_layers,
    check_lonlat,
    composed_heights,
)
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.quadtree import key_for_lonlat, tile_bounds_arrays
from globeview.terrain.store.tile_store import TileStore


def _write(path: Path, arr: np.ndarray, west: float, north: float, d: float) -> Path:
    prof = {
        "driver": "GTiff",
        "width": arr.shape[1],
        "height": arr.shape[0],
        "count": 1,
        "dtype": "float32",
        "transform": from_origin(west, north, d, d),
        "crs": "EPSG:4326",
        "nodata": -9999.0,
    }
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(arr.astype(np.float32), 1)
    return path


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> TerrainStack:
    """A coarse base (10..11 E, 45..46 N, a bumpy surface) and a fine top layer
    (10.4..10.6 E, 45.4..45.6 N)."""
    tmp = tmp_path_factory.mktemp("hq")
    yy, xx = np.mgrid[0:60, 0:60]
    base = 300.0 + 40.0 * np.sin(xx / 7.0) + 25.0 * np.cos(yy / 5.0)
    top = 800.0 + 3.0 * np.mgrid[0:120, 0:120][1]
    stores = []
    for name, arr, w, n, d in (
        ("base", base, 10.0, 46.0, 1.0 / 60),
        ("top", top, 10.4, 45.6, 0.2 / 120),
    ):
        out = tmp / name
        ingest([_write(tmp / f"{name}.tif", arr, w, n, d)], out, tile_n=5)
        stores.append(TileStore.open(out))
    return TerrainStack.from_stores(stores, ["base", "top"])


@pytest.mark.slow
def test_equals_the_composed_tile_nodes_at_the_finest_level(stack: TerrainStack) -> None:
    # At the nodes of the finest-level tiles the query must return the node values the mesh
    # is built from, exactly (float32 -> float64): the surface the LOD converges to.
    level = stack.max_level
    kx, ky = key_for_lonlat(level, np.array([10.45, 10.2, 10.7]), np.array([45.45, 45.8, 45.3]))
    size = stack.tile_size
    for x, y in zip(kx, ky, strict=True):
        w, s, e, n = (float(v) for v in tile_bounds_arrays(level, x, y))
        grid = stack.heights((level, int(x), int(y)))
        r, c = np.mgrid[1 : size - 1 : 3, 1 : size - 1 : 3]
        lon = w + c.ravel() / (size - 1) * (e - w)
        lat = n - r.ravel() / (size - 1) * (n - s)
        got = composed_heights(stack, lon, lat)
        np.testing.assert_allclose(got, grid[r.ravel(), c.ravel()], atol=1e-6)


@pytest.mark.slow
def test_vectorised_query_matches_the_scalar_stack_lookup(stack: TerrainStack) -> None:
    rng = np.random.default_rng(16)
    lon = rng.uniform(10.0, 11.0, 300)
    lat = rng.uniform(45.0, 46.0, 300)
    got = composed_heights(stack, lon, lat)
    want = [stack.height_at(a, b, level=stack.max_level) for a, b in zip(lon, lat, strict=True)]
    np.testing.assert_allclose(got, want, atol=1e-6)
    # Between nodes the surface is bilinear, not the nearest node: the answers vary smoothly.
    assert len(np.unique(np.round(got, 3))) > 250


def test_layer_that_answered(stack: TerrainStack) -> None:
    # 10.39 E lies in a finest-level tile that the top layer covers only in part (its edge is
    # at 10.4 E): the top layer's nodes there are nodata, so the base answers. 45.42 N lies in
    # the top layer's border band (0.02 deg inside its southern edge), where it feathers into
    # the base: both are named, with the top layer's weight.
    lon = np.array([10.45, 10.39, 10.2, 12.0, 10.55])
    lat = np.array([45.45, 45.5, 45.8, 45.5, 45.42])
    names = answering_layers(stack, lon, lat)
    assert names[:4] == ["top", "base", "base", NO_LAYER]
    match = re.fullmatch(r"top over base \(blend (0\.\d\d)\)", names[4])
    assert match, names[4]
    w = float(match.group(1))
    assert 0.0 < w < 1.0
    h = composed_heights(stack, lon, lat)
    assert h[3] == 0.0  # off every layer: the ellipsoid
    # What a layer is said to answer is that layer's surface: hide the other and compare.
    alone = {}
    for hidden, shown in (("base", [0, 4]), ("top", [1, 2, 4])):
        stack.set_visible(hidden, False)
        try:
            alone[hidden] = composed_heights(stack, lon, lat)
        finally:
            stack.set_visible(hidden, True)
        unblended = [i for i in shown if i != 4]
        np.testing.assert_allclose(alone[hidden][unblended], h[unblended])
    # top's surface (a ramp from 800 m) differs from the base's (about 300 m) at its points
    assert np.all(h[[0]] > 700.0) and np.all(h[[1, 2]] < 400.0)
    # In the band the surface lies between the two layers', at about the stated weight
    # (the weight blends nodes; the point is interpolated between blended nodes).
    top_h, base_h = alone["base"][4], alone["top"][4]
    assert min(top_h, base_h) < h[4] < max(top_h, base_h)
    assert abs((h[4] - base_h) / (top_h - base_h) - w) < 0.05


@pytest.mark.parametrize(
    ("lon", "lat"),
    [(np.nan, 45.0), (10.0, np.inf), (10.0, 90.5), (10.0, -91.0)],
)
def test_bad_points_are_one_line_errors(lon: float, lat: float) -> None:
    with pytest.raises(GlobeviewError) as info:
        check_lonlat(np.array([lon]), np.array([lat]))
    assert "\n" not in str(info.value)


def test_longitude_wraps() -> None:
    lon, _ = check_lonlat(np.array([190.0, -190.0, 180.0]), np.array([0.0, 0.0, 0.0]))
    np.testing.assert_allclose(lon, [-170.0, 170.0, 180.0])
