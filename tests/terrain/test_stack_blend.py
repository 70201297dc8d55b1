"""Seamless layers (issue #16, item 4): a regional DEM over the global base feathers into it
across a border band, so the composed terrain has no cliff along the regional layer's edge, and
the LOD's recorded errors stay upper bounds on the blended surface."""

from __future__ import annotations

import numpy as np
import pytest

import globeview.terrain.compose.blend as blend_mod
import globeview.terrain.compose.metadata as metadata_mod
import globeview.terrain.interpolate as interpolate_mod
from globeview.terrain.compose.blend import blend_band
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.quadtree import tile_bounds_arrays, tiles_covering


@pytest.fixture(scope="module")
def stores():
    from globeview.terrain.embedded import embedded_stores

    return {s.path.name.split("-")[0]: s for s in embedded_stores()}


def mosaic(stack: TerrainStack, level: int, box: tuple[float, float, float, float], tile=None):
    """Composed heights (or ``tile(key)``) of every tile meeting ``box`` at ``level`` as one
    node grid (tiles share edge nodes), with node longitudes (cols) and latitudes (rows,
    north first)."""
    tile = tile or stack.heights
    xs, ys = tiles_covering(level, *box)
    x0, y0 = int(xs.min()), int(ys.min())
    cells = stack.tile_size - 1
    nx, ny = int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1
    grid = np.zeros((ny * cells + 1, nx * cells + 1), dtype=np.float64)
    for x, y in zip(xs, ys, strict=True):
        r, c = (int(y) - y0) * cells, (int(x) - x0) * cells
        grid[r : r + cells + 1, c : c + cells + 1] = tile((level, int(x), int(y)))
    w, _, _, n = (float(v[0]) for v in tile_bounds_arrays(level, [x0], [y0]))
    step = (180.0 / 2**level) / cells
    return grid, w + step * np.arange(grid.shape[1]), n - step * np.arange(grid.shape[0])


def edge_distance(bounds, lon, lat):
    west, south, east, north = bounds
    lo, la = np.meshgrid(lon, lat)
    inside = (lo >= west) & (lo <= east) & (la >= south) & (la <= north)
    d_in = np.minimum.reduce([lo - west, east - lo, la - south, north - la])
    return np.where(inside, d_in, -1.0)


def jumps(grid: np.ndarray, mask: np.ndarray) -> float:
    """Max |neighbour-to-neighbour difference| over node pairs with both nodes in ``mask``."""
    dc = np.abs(np.diff(grid, axis=1))[mask[:, 1:] & mask[:, :-1]]
    dr = np.abs(np.diff(grid, axis=0))[mask[1:, :] & mask[:-1, :]]
    return float(max(dc.max(initial=0.0), dr.max(initial=0.0)))


CASES = [
    ("craterlake", 11),
    ("craterlake", 12),
    ("N44W072", 10),
    ("N44W072", 12),
    ("topobathy_vancouver", 7),
]
# Where the unblended step exceeds the local relief (elsewhere the data's own relief near the
# border, e.g. the Coast Mountains at 2.4 km spacing, is larger than the step itself).
CLIFF_CASES = [("craterlake", 11), ("craterlake", 12), ("N44W072", 10), ("N44W072", 12)]


def _border_and_relief(stores, name, level, blend=True):
    regional = stores[name]
    stack = TerrainStack.from_stores([stores["etopo20"], regional])
    stack.blend = blend
    west, south, east, north = regional.bounds
    band = blend_band(regional.bounds)
    m = 2 * band
    grid, lon, lat = mosaic(stack, level, (west - m, south - m, east + m, north + m))
    d = edge_distance(regional.bounds, lon, lat)
    step = lon[1] - lon[0]
    # The border: a strip from a few nodes outside the footprint to the band's inner edge.
    border = (d > -1.0) & (d <= band + step)
    lo, la = np.meshgrid(lon, lat)
    border |= (
        (d < 0)
        & (lo > west - 3 * step)
        & (lo < east + 3 * step)
        & (la > south - 3 * step)
        & (la < north + 3 * step)
    )
    # The data's own local relief: the regional data just inside the band (its terrain near
    # the border, not e.g. Crater Lake's caldera walls in the middle) and the base around.
    # (a strip a tenth of the footprint wide just inside the band).
    strip = 0.1 * band / blend_mod.BLEND_FRACTION
    interior = (d > band + step) & (d <= band + step + strip)
    # ... where the regional layer itself has data (not the nodata wedges of a projected
    # source inside its lon/lat box, where the base shows through).
    size = stack.tile_size

    def own(key):
        h = stack._tiles.layer_heights(regional, key)
        return np.full((size, size), np.nan) if h is None else h

    rgrid, _, _ = mosaic(stack, level, (west - m, south - m, east + m, north + m), own)
    interior &= ~np.isnan(rgrid)
    base = TerrainStack.from_stores([stores["etopo20"]])
    bgrid, _, _ = mosaic(base, level, (west - m, south - m, east + m, north + m))
    relief = max(jumps(grid, interior), jumps(bgrid, np.ones_like(interior)))
    return jumps(grid, border), relief


@pytest.mark.slow
@pytest.mark.parametrize(("name", "level"), CASES)
def test_no_cliff_at_the_regional_layer_border(stores, name, level):
    jump, relief = _border_and_relief(stores, name, level)
    assert jump <= relief, f"{name}: {jump:.1f} m jump at the border > {relief:.1f} m relief"


@pytest.mark.slow
@pytest.mark.parametrize(("name", "level"), CLIFF_CASES)
def test_without_the_band_the_border_is_a_cliff(stores, name, level):
    # The same measurement with the blend switched off (the composition before issue #16):
    # the cliff the blend removes is really there, so the test above can fail.
    jump, relief = _border_and_relief(stores, name, level, blend=False)
    assert jump > relief


ERROR_CASES = [
    ("craterlake", 9),  # tiles starting west of the layer's mask raster (once left unblended)
    ("craterlake", 10),
    ("craterlake", 12),
    ("craterlake", 13),  # its finest level
    ("craterlake", 14),  # finer than its data: the band is upsampled
    ("N44W072", 8),
    ("N44W072", 9),
    ("N44W072", 11),
    ("topobathy_vancouver", 5),
    ("topobathy_vancouver", 7),  # its finest level
    ("topobathy_vancouver", 8),
]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "level"), ERROR_CASES)
def test_recorded_errors_bound_the_blended_surface(stores, name, level):
    """Measured max |tile surface at stride s - finest composed surface| <= recorded error at
    every stride, for up to 12 tiles of the border band (checked at the finest composed nodes
    inside each tile: both surfaces are bilinear between those, so that is the max)."""
    regional = stores[name]
    stack = TerrainStack.from_stores([stores["etopo20"], regional])
    # Tiles along the layer's edges, chosen by footprint (not by the code under test).
    west, south, east, north = regional.bounds
    inset = 0.02 * min(east - west, north - south)
    strips = [
        (west, south, west + inset, north),
        (east - inset, south, east, north),
        (west, south, east, south + inset),
        (west, north - inset, east, north),
    ]
    keys = {
        (int(x), int(y)) for b in strips for x, y in zip(*tiles_covering(level, *b), strict=True)
    }
    xs, ys = (np.array(v, dtype=np.int64) for v in zip(*sorted(keys), strict=True))
    covered = stack.metadata(level, xs, ys).covered
    xs, ys = xs[covered], ys[covered]
    pick = np.unique(np.linspace(0, len(xs) - 1, min(12, len(xs))).astype(int))
    xs, ys = xs[pick], ys[pick]
    meta = stack.metadata(level, xs, ys)
    size = stack.tile_size
    cells = size - 1
    fine = max(regional.max_level, level)
    sub = 2 ** (fine - level)
    pos = np.linspace(0.0, cells, sub * cells + 1)
    for i, (x, y) in enumerate(zip(xs, ys, strict=True)):
        # The finest composed surface over this tile, and this tile's drawn surface at each
        # stride interpolated to the same nodes.
        big = np.zeros((sub * cells + 1, sub * cells + 1))
        for j in range(sub):
            for k in range(sub):
                t = stack.heights((fine, int(x) * sub + k, int(y) * sub + j))
                big[j * cells : (j + 1) * cells + 1, k * cells : (k + 1) * cells + 1] = t
        h = stack.heights((level, int(x), int(y))).astype(np.float64)
        for si in range(metadata_mod.N_STRIDES):
            s = 2**si
            p = pos / s
            rr, cc = np.meshgrid(p, p, indexing="ij")
            drawn = interpolate_mod.bilinear(h[::s, ::s], rr.ravel(), cc.ravel()).reshape(big.shape)
            err = float(np.abs(drawn - big).max())
            assert err <= meta.stride_error[i, si] + 1e-3, (x, y, s, err, meta.stride_error[i])
    assert len(xs) > 0


@pytest.mark.slow
def test_the_blend_adds_error_only_in_the_band(stores):
    # Deep inside the regional layer (and outside it) the recorded errors are the layers'
    # own: the blend costs triangles only along the border.
    regional = stores["N44W072"]
    stack = TerrainStack.from_stores([stores["etopo20"], regional])
    own = TerrainStack.from_stores([stores["etopo20"], regional])
    own.blend = False
    xs, ys = tiles_covering(11, -71.6, 44.4, -71.4, 44.6)  # the middle of the 1-deg tile
    np.testing.assert_array_equal(
        stack.metadata(11, xs, ys).stride_error, own.metadata(11, xs, ys).stride_error
    )
    xs, ys = tiles_covering(11, -72.0, 44.3, -71.99, 44.7)  # its western band
    assert np.all(
        stack.metadata(11, xs, ys).stride_error[:, 1:]
        >= own.metadata(11, xs, ys).stride_error[:, 1:]
    )


def test_a_global_layer_has_no_band_at_the_antimeridian_or_the_poles(stores):
    # A global layer over another (e.g. the base moved up) must not feather along +-180 or
    # at the poles: those are not edges of its data.
    mask = blend_mod.BlendMask(stores["etopo20"])
    lon = np.array([-180.0, -179.99, 179.99, 180.0, 0.0, 0.0])
    lat = np.array([0.0, 10.0, -10.0, 0.0, 89.99, -89.99])
    np.testing.assert_array_equal(mask.sample(lon, lat), 1.0)
    # ... while a regional layer's weight falls to ~0 on its edge.
    srtm = blend_mod.BlendMask(stores["N44W072"])
    assert srtm.sample(np.array([-71.0, -71.5]), np.array([44.5, 44.0])).max() < 0.01


@pytest.mark.parametrize("m", [1, 2, 8, 64])
def test_weight_interpolation_error_is_its_max_between_nodes(stores, m):
    """`interpolation_error` (measured at the mask's raster nodes) bounds |interp(w) - w|
    everywhere, here checked on points a quarter raster step apart across the SRTM band."""
    mask = blend_mod.BlendMask(stores["N44W072"])
    cell = m * mask.step
    w_err = blend_mod.interpolation_error(mask, cell)
    # Quadtree-aligned cells over the western band: corners at multiples of `cell` degrees.
    c0 = np.floor((-72.02 + 180.0) / cell) * cell - 180.0
    n0 = 90.0 - np.floor((90.0 - 44.9) / cell) * cell
    lon = -72.02 + np.arange(0.0, 0.12, mask.step / 4)
    lat = np.full_like(lon, 44.5 + mask.step / 3)
    i = np.floor((lon - c0) / cell)
    j = np.floor((n0 - lat) / cell)
    fx = (lon - (c0 + i * cell)) / cell
    fy = (n0 - lat - j * cell) / cell
    wl, wr = c0 + i * cell, c0 + (i + 1) * cell
    nt, nb = n0 - j * cell, n0 - (j + 1) * cell
    corner = [mask.sample(a, b) for a, b in ((wl, nt), (wr, nt), (wl, nb), (wr, nb))]
    interp = (corner[0] * (1 - fx) + corner[1] * fx) * (1 - fy) + (
        corner[2] * (1 - fx) + corner[3] * fx
    ) * fy
    actual = float(np.abs(interp - mask.sample(lon, lat)).max())
    assert actual <= w_err + 1e-9, (actual, w_err)
    if m == 1:
        assert w_err == 0.0  # a cell inside one raster cell reproduces w exactly
    else:
        assert w_err > 0.0


@pytest.mark.slow
def test_a_layer_across_the_antimeridian_feathers_on_both_sides(tmp_path):
    """A regional layer over 179.5 E .. 179.5 W: its band lies inside both its edges (east of
    +-180 too), so neither edge is a cliff and the weight is symmetric."""
    import rasterio
    from rasterio.transform import from_origin

    from globeview.terrain.ingest.driver import ingest
    from globeview.terrain.store.tile_store import TileStore

    def write(name, arr, west, north, d):
        path = tmp_path / f"{name}.tif"
        prof = {"driver": "GTiff", "width": arr.shape[1], "height": arr.shape[0], "count": 1}
        prof.update(dtype="float32", crs="EPSG:4326", transform=from_origin(west, north, d, d))
        with rasterio.open(path, "w", **prof) as ds:
            ds.write(arr.astype(np.float32), 1)
        ingest([path], tmp_path / name, tile_n=5)
        return TileStore.open(tmp_path / name)

    base = write("base", np.zeros((120, 80)), 178.0, -14.0, 0.05)  # 178 E .. 178 W, 14..20 S
    top = write("top", np.full((100, 100), 1000.0), 179.5, -16.5, 0.01)
    stack = TerrainStack.from_stores([base, top], ["base", "top"])
    lat = np.full(4, -17.0)
    inside = np.array([179.55, -179.55, 179.9, -179.9])  # 0.05 deg inside either edge; deep
    w = stack.blend_weight(1, inside, lat)
    assert 0.1 < w[0] < 0.9 and w[1] == pytest.approx(w[0], abs=0.02)
    assert w[2] == w[3] == pytest.approx(1.0)
    # No cliff: just inside each edge the surface is near the base, deep inside it is the
    # layer (both are converted to ellipsoidal heights: + the same geoid undulation N).
    level = top.max_level
    lons = (179.45, 179.501, -179.501, -179.45, 179.9, -179.9)
    h = np.array([stack.height_at(lon, -17.0, level) for lon in lons])
    stack.set_visible("top", False)
    n = np.array([stack.height_at(lon, -17.0, level) for lon in lons])  # the base: 0 m + N
    stack.set_visible("top", True)
    np.testing.assert_allclose(h[[0, 3]], n[[0, 3]])  # outside the layer: the base
    # 0.001 deg inside either edge: w < 0.025 (w is 0 on the edge of the layer's nodes, which
    # since issue #29 reach one of its 0.011 deg nodes past its data: the corners its last
    # cells need; before, w < 0.01 there).
    assert np.all(np.abs(h[1:3] - n[1:3]) < 25.0), h
    np.testing.assert_allclose(h[4:], n[4:] + 1000.0, atol=0.5)
