"""Tile building made cheaper (issue #17, item 3) without changing what is built:

- `build_tile_mesh` (separable ECEF grid, component-wise normals) gives the same vertices and
  normals as the straightforward per-node formulation it replaced (kept here as the
  reference), to float32 rounding;
- the renderer's batched skirt depths (one metadata call per level) equal the per-tile ones;
- the store's padded windows hold the neighbours' nodes, and the stack's apron ring, composed
  on the ring alone, matches the neighbours' composed heights.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from globeview.geodesy import WGS84, enu_basis, lonlat_to_ecef
from globeview.lod.tile_indices import node_lonlat
from globeview.render.renderer import tile_bounds_tuple
from globeview.render.tile_mesh import FLOATS_PER_VERTEX, build_tile_mesh
from globeview.terrain.quadtree import key_for_lonlat


@pytest.fixture(scope="module")
def stack(globeview_terrain):
    """The embedded terrain: the run's one stack (`globeview_terrain`, tests/conftest.py), not
    one of the module's own (each stack measures its layers' blend masks again: up to ~7 CPU-s)."""
    return globeview_terrain


# -- the reference: the mesh builder as it was before issue #17 ------------------------------
def _ref_normals(points: np.ndarray) -> np.ndarray:
    p = points - points[points.shape[0] // 2, points.shape[1] // 2]
    a, b, c, d = p[:-1, :-1], p[:-1, 1:], p[1:, :-1], p[1:, 1:]
    n1 = np.cross(c - a, b - a)
    n2 = np.cross(d - b, d - c)
    n1 /= np.maximum(np.linalg.norm(n1, axis=2, keepdims=True), 1e-30)
    n2 /= np.maximum(np.linalg.norm(n2, axis=2, keepdims=True), 1e-30)
    cell = n1 + n2
    acc = np.zeros_like(p)
    acc[:-1, :-1] += cell
    acc[:-1, 1:] += cell
    acc[1:, :-1] += cell
    acc[1:, 1:] += cell
    norm = np.linalg.norm(acc, axis=2, keepdims=True)
    radial = points / np.linalg.norm(points, axis=2, keepdims=True)
    return np.where(norm > 1e-12, acc / np.maximum(norm, 1e-30), radial)


def _ref_mesh(bounds, heights, skirt_depth, apron=None):
    size = heights.shape[0]
    lon, lat = node_lonlat(bounds, size)
    lon_g, lat_g = np.meshgrid(lon, lat)
    base = lonlat_to_ecef(lon_g, lat_g, 0.0)
    center = lonlat_to_ecef(0.5 * (bounds[0] + bounds[2]), 0.5 * (bounds[1] + bounds[3]), 0.0)
    if apron is not None:
        west, south, east, north = bounds
        lon_a = west + (east - west) / (size - 1) * np.arange(-1, size + 1)
        lat_a = np.clip(north - (north - south) / (size - 1) * np.arange(-1, size + 1), -90, 90)
        la, pa = np.meshgrid(lon_a, lat_a)
        normals = _ref_normals(lonlat_to_ecef(la, pa, apron.astype(np.float64)))[1:-1, 1:-1]
    else:
        normals = _ref_normals(lonlat_to_ecef(lon_g, lat_g, heights.astype(np.float64)))
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
    grid3 = grid.reshape(size, size, FLOATS_PER_VERTEX)
    basis = enu_basis(lon_g, lat_g)
    outward = [basis[0, :, 1], -basis[-1, :, 1], -basis[:, 0, 0], basis[:, -1, 0]]
    edges = [(0, slice(None)), (size - 1, slice(None)), (slice(None), 0), (slice(None), size - 1)]
    skirts = []
    for idx, out_dir in zip(edges, outward, strict=True):
        s = grid3[idx].copy()
        s[:, :3] += out_dir * skirt_depth
        s[:, 3] -= skirt_depth
        skirts.append(s)
    return np.concatenate([grid, *skirts]).astype(np.float32), normals.astype(np.float32)


def _key(level: int, lon: float, lat: float) -> tuple[int, int, int]:
    kx, ky = key_for_lonlat(level, np.array([lon]), np.array([lat]))
    return level, int(np.ravel(kx)[0]), int(np.ravel(ky)[0])


MESH_KEYS = [
    (0, 0, 0),  # a pole row and a 90-degree tile
    (0, 3, 0),
    (3, 15, 7),  # touches +180 and the south pole
    _key(9, -71.3, 44.15),  # White Mountains, rough
    _key(12, -71.3, 44.15),
    _key(13, -122.1, 42.94),  # Crater Lake
    _key(7, -123.1, 49.3),  # Vancouver topobathy (below sea level)
]


@pytest.mark.slow
@pytest.mark.parametrize("key", MESH_KEYS)
@pytest.mark.parametrize("apron", [False, True])
def test_mesh_matches_the_reference_builder(stack, key, apron):
    h = stack.heights(key)
    a = stack.heights_apron(key) if apron else None
    bounds = tile_bounds_tuple(key)
    mesh = build_tile_mesh(bounds, h, 37.5, apron=a)
    ref_v, ref_n = _ref_mesh(bounds, h, 37.5, apron=a)
    assert mesh.vertices.shape == ref_v.shape and mesh.vertices.dtype == np.float32
    assert mesh.normals.shape == ref_n.shape and mesh.normals.dtype == np.float32
    # The same float64 operations node by node: equal to float32 rounding (bit-identical on
    # the development machine; 2 ulp allows a libm that rounds sin/cos differently by shape).
    np.testing.assert_array_max_ulp(mesh.vertices, ref_v, maxulp=2)
    np.testing.assert_allclose(mesh.normals, ref_n, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(mesh.heights, h)


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a).tobytes()


# Tiles where every path of the build runs: poles, the antimeridian, rough relief with its
# apron, tiles finer than their data (data-level normals), below sea level.
BATCH_KEYS = [
    *MESH_KEYS,
    _key(14, -122.1, 42.94),  # finer than Crater Lake's data: data-level normals
    _key(13, -71.3, 44.15),  # finer than N44W072's: data-level normals
    (1, 3, 1),
]


@pytest.mark.parametrize("apron", [False, True])
def test_a_batch_builds_each_tile_bit_for_bit_as_alone(stack, apron):
    """Issue #27: the batch (one numpy pass over B tiles) performs each tile's operations;
    vertices, normals, centres and heights are the same bits as the tile built alone, with
    given normals on some tiles and not on others."""
    from globeview.render.tile_mesh import build_tile_meshes

    keys = BATCH_KEYS
    heights = np.stack([stack.heights(k) for k in keys])
    aprons = np.stack([stack.heights_apron(k) for k in keys]) if apron else None
    bounds = np.array([tile_bounds_tuple(k) for k in keys])
    skirts = np.linspace(12.5, 700.0, len(keys))
    given = [None] * len(keys)
    given[2] = build_tile_mesh(tuple(bounds[5]), heights[5], 1.0).normals  # any unit normals
    batch = build_tile_meshes(bounds, heights, skirts, apron=aprons, normals=given)
    for i, mesh in enumerate(batch):
        one = build_tile_mesh(
            tuple(bounds[i]),
            heights[i],
            float(skirts[i]),
            apron=None if aprons is None else aprons[i],
            normals=given[i],
        )
        for name in ("center", "vertices", "normals", "heights"):
            assert _bits(getattr(mesh, name)) == _bits(getattr(one, name)), (keys[i], name)
        assert mesh.skirt_depth == one.skirt_depth


def test_the_builder_bakes_what_an_upload_of_the_mesh_bakes(stack):
    """`TileBuilder.ready` (the loader's batch: meshes and texels of the whole batch) gives
    each tile the bits of its mesh built alone and baked alone (`tile_texels`), and the
    renderer's one-tile and batch builds are the builder's."""
    from globeview.render.colour_ramp import tile_texels
    from globeview.render.tile_build import ReadyTile, TileBuilder

    builder = TileBuilder(stack)
    keys = np.array(BATCH_KEYS, dtype=np.int64)
    ready = builder.ready(keys)
    assert list(ready) == [tuple(int(v) for v in k) for k in keys]
    for key, tile in ready.items():
        mesh = builder.mesh(key)
        alone = ReadyTile.from_mesh(mesh)
        albedo, coast, scale = tile_texels(mesh.heights)
        assert _bits(tile.albedo) == _bits(alone.albedo) == _bits(albedo)
        assert _bits(tile.normal[..., 3]) == _bits(coast)
        assert _bits(tile.normal) == _bits(alone.normal)
        assert tile.coast_scale == alone.coast_scale == scale
        assert _bits(tile.vertices) == _bits(mesh.vertices)
        assert _bits(tile.center) == _bits(mesh.center)


def test_batched_texels_equal_per_tile_at_coasts() -> None:
    """Coast scales per tile in a batch: a tile without a coast, one with a low and one with a
    cliff coast, one under water."""
    from globeview.render.colour_ramp import tile_texels, tile_texels_batch

    rng = np.random.default_rng(7)
    base = rng.normal(0.0, 1.0, (65, 65)).cumsum(axis=1).astype(np.float32)
    tiles = np.stack([base + 500.0, base * 3.0, base * 80.0 - 40.0, base - 3000.0])
    albedo, coast, scale = tile_texels_batch(tiles)
    for i, h in enumerate(tiles):
        a, c, s = tile_texels(h)
        assert _bits(albedo[i]) == _bits(a) and _bits(coast[i]) == _bits(c)
        assert scale[i] == s


@pytest.mark.slow
def test_batched_skirt_depths_equal_per_tile(stack):
    from globeview.render.offscreen import create_headless_context
    from globeview.render.renderer import GlobeRenderer

    ctx = create_headless_context()
    try:
        r = GlobeRenderer(ctx, stack, capacity=16)
        lv, x, y = _key(11, -71.3, 44.15)
        keys = np.array(
            [(lv, x + i, y + j) for i in range(-2, 3) for j in range(-2, 3)]
            + [(4, 9, 5), (4, 10, 5), (0, 0, 0)],
            dtype=np.int64,
        )
        got = r.skirt_depths(keys)
        for k, depth in zip(keys, got, strict=True):
            bounds = tile_bounds_tuple(tuple(k))
            meta = stack.metadata(int(k[0]), np.array([k[1]]), np.array([k[2]]))
            edge_m = math.radians(bounds[2] - bounds[0]) * WGS84.a
            want = 3.0 * float(np.nanmax(meta.stride_error)) + 0.01 * edge_m + 10.0
            # Deeper over data: down to the ellipsoid (issue #25, test_data_edge_walls).
            assert depth >= want
            assert depth == r.builder.skirt_depth((int(k[0]), int(k[1]), int(k[2])))
        # One tile alone (the loader's path) and in a batch: the same mesh.
        batch = r.build_meshes(keys)
        assert list(batch) == [tuple(int(v) for v in k) for k in keys]
        one = r.build_mesh((lv, x, y))
        np.testing.assert_array_equal(one.vertices, batch[(lv, x, y)].vertices)
        np.testing.assert_array_equal(one.normals, batch[(lv, x, y)].normals)
        # The loader's one-tile builds take skirt depths computed per 4 x 4 block and cached:
        # the same numbers, at the grid's edges too, and none kept across a layer change.
        for k in [(0, 0, 0), (0, 3, 0), (1, 3, 1), (lv, x + 3, y - 5), (lv, x, y)]:
            assert r.builder.skirt_depth(k) == r.skirt_depths(np.array([k]))[0]
        name = next(ly.name for ly in stack.layers[1:] if ly.store.has_tile(lv, x, y))
        before = r.builder.skirt_depth((lv, x, y))
        stack.set_visible(name, False)
        try:
            assert r.builder.skirt_depth((lv, x, y)) == r.skirt_depths(np.array([(lv, x, y)]))[0]
            assert r.builder.skirt_depth((lv, x, y)) != before  # the detail layer's errors are gone
        finally:
            stack.set_visible(name, True)
        r.release()
    finally:
        ctx.release()


def _ring_vs_neighbours(get_padded, get_tile, key, nrows):
    """Max |padded ring - the neighbours' nodes next to the edge| (NaN-aware: NaN must match)."""
    level, x, y = key
    ncols = 2 << level
    p = get_padded(key)
    size = p.shape[0] - 2
    src = {-1: slice(size - 2, size - 1), 0: slice(0, size), 1: slice(1, 2)}
    dst = {-1: slice(0, 1), 0: slice(1, size + 1), 1: slice(size + 1, size + 2)}
    worst = 0.0
    for dy in (-1, 0, 1):
        if not 0 <= y + dy < nrows:
            continue
        for dx in (-1, 0, 1):
            a = p[dst[dy], dst[dx]].astype(np.float64)
            b = get_tile((level, (x + dx) % ncols, y + dy))[src[dy], src[dx]].astype(np.float64)
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
            d = np.abs(a - b)[~np.isnan(a)]
            worst = max(worst, float(d.max(initial=0.0)))
    return worst


def _plain_read(st, key):
    """A tile's nodes read straight from its level file with rasterio (one window, no block
    cache, no padding): the store's read path as it was before issue #17, for reference."""
    import rasterio
    from rasterio.windows import Window

    level, x, y = key
    g = st.level_grid(level)
    size = st.tile_size
    ix, iy = (x - g.x0) % g.ncols, y - g.y0
    if not (0 <= ix < g.nx and 0 <= iy < g.ny):
        return np.full((size, size), np.nan, dtype=np.float32)
    n = g.tile_nodes
    with rasterio.open(st.path / st.manifest.levels[level].file) as ds:
        return ds.read(1, window=Window(ix * n, iy * n, size, size)).astype(np.float32)


@pytest.mark.slow
def test_store_padded_window_is_the_neighbours_nodes(stack):
    """Exact, NaN included: inside, at a regional layer's extent edges (tiles just outside
    it serve NaN), and across the antimeridian on the global base."""
    for layer in stack.layers:
        st = layer.store
        for level in sorted({0, 1, st.max_level // 2, st.max_level}):
            g = st.level_grid(level)
            for y in range(max(g.y0 - 1, 0), min(g.y0 + 3, g.nrows)):
                for x in [g.x0 - 1, g.x0, g.x0 + 1, g.x0 + g.nx - 1, g.x0 + g.nx]:
                    key = (level, x % g.ncols, y)
                    worst = _ring_vs_neighbours(st.heights_padded, st.heights, key, g.nrows)
                    assert worst == 0.0, (layer.name, key)
                    np.testing.assert_array_equal(
                        st.heights_padded(key)[1:-1, 1:-1], _plain_read(st, key)
                    )
                    assert st.has_tile(*key) == bool(st.has_data(level, key[1], key[2]))


@pytest.mark.parametrize(
    ("lon", "lat", "levels"),
    [
        (-71.3, 44.15, (8, 10, 12, 13)),  # N44W072 over the base (blend band, upsampled)
        (-72.0, 44.5, (9, 11, 12)),  # N44W072's west edge: its border band
        (-122.1, 42.94, (10, 12, 14)),  # Crater Lake, finer than its data at 14
        (179.99, 0.0, (2, 5)),  # the antimeridian
    ],
)
def test_apron_ring_matches_the_neighbours_heights(stack, lon, lat, levels):
    """The ring composed on its own equals the neighbours' composed heights up to float
    rounding (a bilinear gather in place of their separable products): <= 1 mm here."""
    for level in levels:
        lv, x, y = _key(level, lon, lat)
        for dx in (-1, 0, 1):
            key = (lv, (x + dx) % (2 << lv), y)
            worst = _ring_vs_neighbours(stack.heights_apron, stack.heights, key, 1 << lv)
            assert worst <= 1e-3, (key, worst)


def _apron_matches_around(stack, keys):
    """Every key and its 8 neighbours: ring vs the neighbours' heights, <= 1 mm."""
    for lv, x, y in keys:
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if not 0 <= y + dy < 1 << lv:
                    continue
                key = (lv, (x + dx) % (2 << lv), y + dy)
                worst = _ring_vs_neighbours(stack.heights_apron, stack.heights, key, 1 << lv)
                assert worst <= 1e-3, (key, worst)


@pytest.fixture(scope="module")
def unblended_stack():
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores

    st = TerrainStack.from_stores(embedded_stores())
    st.blend = False
    return st


@pytest.mark.slow
@pytest.mark.parametrize("blend", [True, False])
@pytest.mark.parametrize(
    "keys",
    [
        # N44W072's north edge (45 N) on a tile edge, finer than its data (max level 12): the
        # tile north of it upsamples an ancestor outside the layer's extent (the store serves
        # NaN on the shared edge there), its neighbour one inside (review of #17: 0.17 m).
        [(13, 4947, 2047), _key(14, -71.3, 44.999)],
        [_key(13, -71.7, 44.001), _key(14, -72.0, 44.5)],  # its south and west edges
        # Vancouver's ragged nodata edge finer than its data (max level 7): NaN corners of
        # weight 0 count as the neighbour's bilinear upsampling counts them.
        [(8, 80, 59), _key(9, -123.1, 49.3)],
    ],
)
def test_apron_ring_at_layer_edges_finer_than_the_data(stack, unblended_stack, blend, keys):
    _apron_matches_around(stack if blend else unblended_stack, keys)


@pytest.fixture(scope="module")
def antimeridian_stack(tmp_path_factory):
    """The embedded terrain under two small DEMs ending at the antimeridian: 179..180 E at
    10..11 N and -180..-179 E at 20..21 N (1/240 degree: finest level 9)."""
    import rasterio
    from rasterio.transform import Affine

    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores
    from globeview.terrain.ingest.driver import ingest
    from globeview.terrain.store.tile_store import TileStore

    tmp = tmp_path_factory.mktemp("am")
    stores = list(embedded_stores())
    for name, west, north in (("east", 179.0, 11.0), ("west", -180.0, 21.0)):
        yy, xx = np.mgrid[0:240, 0:240]
        data = (500 + 300 * np.sin(xx / 17.0) * np.cos(yy / 23.0) + 2 * xx).astype(np.float32)
        tif = tmp / f"{name}.tif"
        prof = dict(driver="GTiff", width=240, height=240, count=1, dtype="float32")
        prof.update(crs="EPSG:4326", transform=Affine(1 / 240, 0, west, 0, -1 / 240, north))
        with rasterio.open(tif, "w", **prof) as ds:
            ds.write(data, 1)
        ingest([tif], tmp / name, tile_n=6, vdatum="ellipsoid")
        stores.append(TileStore.open(tmp / name))
    return TerrainStack.from_stores(stores)


@pytest.mark.slow
@pytest.mark.parametrize("level", [10, 11])
@pytest.mark.parametrize("lat", [10.5, 20.5])
def test_apron_ring_at_a_layer_edge_on_the_antimeridian(antimeridian_stack, level, lat):
    """Tiles on both sides of +-180, finer than the layers' data (max level 9): on each
    side one tile's ancestor lies inside a DEM and its neighbour's across the antimeridian
    outside it (column 0 wraps to the last column)."""
    assert antimeridian_stack.layers[-1].store.max_level == 9
    last = (2 << level) - 1
    keys = [_key(level, 179.999, lat), _key(level, -179.999, lat)]
    assert {k[1] for k in keys} == {0, last}
    _apron_matches_around(antimeridian_stack, keys)
