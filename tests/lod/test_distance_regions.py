"""The `distance-regions` LOD provider (Rishe et al.): its pure formulas, the edge-stride
stitching it relies on (`IndexVariant.edge_strides`), selection properties, and crack-free
renders through the plugin session."""

from __future__ import annotations

import math

import numpy as np
import pytest

from globeview.app.testing import make_view
from globeview.lod.stitching import neighbour_edge_strides
from globeview.lod.tile_indices import IndexVariant, grid_indices
from globeview.lod.traversal import traverse
from globeview.plugins.builtin.regions.provider import (
    RishePolicy,
    level_and_stride,
    mesh_resolution,
    node_spacing_m,
    region_factor,
    ring_of,
    ring_resolution,
    rishe_pitch_roll,
    speed_factor,
)

SIZE = 65
MAGENTA = (1.0, 0.0, 1.0)


# -- Rishe's formulas ------------------------------------------------------------------------------
def test_ring_geometry() -> None:
    r = 1000.0
    d = np.array([0.0, 1.9e3, 2.0e3, 5.0e3, 8.0e3, 15.0e3, 20.0e3, 20.1e3, 1e6])
    assert ring_of(d, r).tolist() == [1, 1, 1, 2, 2, 3, 3, 4, 4]
    r_m = 30.0
    # Table 2: ring 2 has half ring 1's detail (cells twice as big), ring 3 a quarter.
    res = ring_resolution(ring_of(np.array([5.0 * r, 15.0 * r]), r), r_m)
    assert res.tolist() == [2 * r_m, 4 * r_m]


def test_region_factor_and_resolution_formulas() -> None:
    # Looking straight down (Rishe pitch 0, roll 0): R = H tan(fovy / 2) max(1, ratio).
    assert region_factor(1000.0, 0.0, 0.0, 45.0, 1.5) == pytest.approx(
        1000.0 * math.tan(math.radians(22.5)) * 1.5
    )
    # A tilt larger than the field of view widens the regions.
    assert region_factor(1000.0, 60.0, 0.0, 45.0, 1.0) == pytest.approx(
        1000 * math.tan(math.pi / 6)
    )
    assert region_factor(1000.0, 10.0, -70.0, 45.0, 0.5) == pytest.approx(
        1000 * math.tan(math.radians(35.0))
    )
    assert speed_factor(0.0, 30.0) == 1.0
    assert speed_factor(1500.0, 30.0, 100.0) == pytest.approx(0.5)
    assert speed_factor(1e9, 30.0) == 0.5
    base = mesh_resolution(1000.0, 45.0, 400.0, 1.0)
    assert base == pytest.approx(1000.0 / (400.0 * math.tan(math.radians(22.5))))
    # Moving fast coarsens the mesh (twice divided by the speed factor).
    assert mesh_resolution(1000.0, 45.0, 400.0, 0.5) == pytest.approx(4 * base)


def test_level_for_a_resolution() -> None:
    lv, st = level_and_stride(np.array([1e9, 200.0, 60.0]), SIZE)
    assert lv[0] == 0 and np.all(st == 1)
    for level, res in zip(lv[1:], (200.0, 60.0), strict=True):
        assert node_spacing_m(level, SIZE) <= res < node_spacing_m(level - 1, SIZE)


def test_pitch_convention() -> None:
    down = make_view(10.0, 40.0, 5000.0, 0.0, -90.0)
    oblique = make_view(10.0, 40.0, 5000.0, 30.0, -30.0)
    assert rishe_pitch_roll(down)[0] == pytest.approx(0.0, abs=1e-6)  # Rishe: 0 = straight down
    assert rishe_pitch_roll(oblique)[0] == pytest.approx(60.0, abs=1e-6)
    assert rishe_pitch_roll(oblique)[1] == pytest.approx(0.0, abs=1e-6)


# -- edge-stride stitching ------------------------------------------------------------------------
def _tris(variant: IndexVariant, size: int = SIZE) -> np.ndarray:
    """(T, 3) surface triangles (skirts dropped) of a variant."""
    t = grid_indices(size, variant).reshape(-1, 3).astype(np.int64)
    return t[np.all(t < size * size, axis=1)]


def _area_rc(tris: np.ndarray, size: int = SIZE) -> np.ndarray:
    r, c = tris // size, tris % size
    return 0.5 * np.abs(
        (r[:, 1] - r[:, 0]) * (c[:, 2] - c[:, 0]) - (r[:, 2] - r[:, 0]) * (c[:, 1] - c[:, 0])
    )


EDGE_CASES = [
    (1, (4, 1, 1, 1)),
    (1, (1, 2, 1, 1)),
    (2, (2, 2, 8, 2)),
    (1, (1, 1, 1, 64)),
    (1, (2, 2, 2, 2)),
    (1, (4, 1, 4, 1)),  # two stitched edges meeting in a corner
    # Corners where both stitched edges are much coarser than the tile (once overlapped).
    (2, (4, 8, 2, 4)),
    (4, (8, 16, 8, 32)),
    (8, (64, 64, 64, 64)),
    (16, (32, 64, 64, 32)),
]


@pytest.mark.parametrize(("stride", "edges"), EDGE_CASES)
def test_stitched_edges_have_no_t_junction_and_cover_the_tile(stride, edges) -> None:
    n = SIZE - 1
    tris = _tris(IndexVariant(stride, skirts=True, edge_strides=edges))
    area = _area_rc(tris)
    # Together the triangles tile the (row, col) square exactly once.
    assert area.sum() == pytest.approx(n * n)
    r, c = tris // SIZE, tris % SIZE
    # On a stitched edge every node used is a node of the coarser neighbour.
    for k, on_edge, along in ((0, r == 0, c), (1, r == n, c), (2, c == 0, r), (3, c == n, r)):
        used = along[on_edge]
        assert np.all(used % edges[k] == 0), (k, np.unique(used[used % edges[k] != 0]))
    # The skirts follow the stitched edges (same nodes).
    allt = grid_indices(SIZE, IndexVariant(stride, True, None, edges)).reshape(-1, 3)
    top = allt[allt < SIZE * SIZE]
    tr, tc = top // SIZE, top % SIZE
    assert np.all(tc[tr == 0] % edges[0] == 0) and np.all(tr[tc == 0] % edges[2] == 0)


@pytest.mark.slow
def test_point_coverage_of_stitched_tile() -> None:
    """Each cell centre lies in exactly one triangle (no overlaps, no holes)."""
    tris = _tris(IndexVariant(1, skirts=False, edge_strides=(4, 2, 8, 1)))
    r, c = (tris // SIZE).astype(float), (tris % SIZE).astype(float)
    g = np.arange(SIZE - 1) + 0.37  # off-diagonal sample points, one per cell
    pr, pc = np.meshgrid(g, g + 0.21, indexing="ij")
    p = np.stack([pr.ravel(), pc.ravel()], axis=1)

    def side(i: int, j: int) -> np.ndarray:  # (P, T) cross product sign of edge i -> j
        return (r[None, :, j] - r[None, :, i]) * (p[:, 1, None] - c[None, :, i]) - (
            c[None, :, j] - c[None, :, i]
        ) * (p[:, 0, None] - r[None, :, i])

    s0, s1, s2 = side(0, 1), side(1, 2), side(2, 0)
    inside = ((s0 >= 0) & (s1 >= 0) & (s2 >= 0)) | ((s0 <= 0) & (s1 <= 0) & (s2 <= 0))
    assert np.all(inside.sum(axis=1) == 1)


def test_neighbour_edge_strides() -> None:
    # Three tiles in a row at level 2 and one below the middle one, plus a tile at level 3.
    keys = np.array([[2, 3, 1], [2, 4, 1], [2, 5, 1], [2, 4, 2], [3, 0, 0], [2, 0, 1], [2, 7, 1]])
    strides = np.array([1, 2, 8, 4, 1, 1, 4])
    e = neighbour_edge_strides(keys, strides)  # (north, south, west, east)
    assert e[0].tolist() == [1, 1, 1, 2]
    assert e[1].tolist() == [2, 4, 2, 8]
    assert e[2].tolist() == [8, 8, 8, 8]
    assert e[3].tolist() == [4, 4, 4, 4]
    assert e[4].tolist() == [1, 1, 1, 1]  # level-3 tile: different level, no stitching
    assert e[5].tolist() == [1, 1, 4, 1]  # x = 0 and x = 7 are neighbours across lon 180


# -- selection -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def terrain(globeview_terrain):
    """The embedded terrain: the run's one stack (`globeview_terrain`, tests/conftest.py), not
    one of the module's own (each stack measures its layers' blend masks again: up to ~7 CPU-s)."""
    return globeview_terrain


def _triangles(rs) -> int:
    per = [len(grid_indices(SIZE, v)) // 3 for v in rs.variants]
    return int(sum(per[i] for i in rs.variant_ids))


@pytest.mark.slow
def test_rings_cut_off_and_stats(terrain) -> None:
    v = make_view(-71.3, 44.15, 9000.0, 0.0, -30.0, viewport=(320, 240))
    rs = traverse(v, terrain, RishePolicy())
    st = rs.stats
    assert st["tiles_ring1"] > 0 and st["tiles_ring2"] > 0
    assert len(rs) == st["tiles_ring1"] + st["tiles_ring2"] + st["tiles_ring3"]
    assert rs.error_px is not None and len(rs.error_px) == len(rs)
    assert st["lod_ms"] > 0 and st["tiles_culled_frustum"] > 0
    # Some same-level neighbours differ in stride: stitched variants appear.
    assert any(var.edge_strides is not None for var in rs.variants)
    # Ring 1 is drawn finer than the far rings.
    lv = rs.keys[:, 0]
    assert lv.max() > lv.min()
    # Without the cut-off nothing is cut and no fewer tiles are drawn.
    rs2 = traverse(v, terrain, RishePolicy(cutoff=False))
    assert rs2.stats["tiles_culled_cutoff"] == 0 and len(rs2) >= len(rs)
    # Looking straight down everything visible is ring 1 (Rishe §3.2).
    down = traverse(make_view(-71.3, 44.15, 9000.0, viewport=(320, 240)), terrain, RishePolicy())
    assert down.stats["tiles_ring2"] == 0 and down.stats["tiles_ring3"] == 0


@pytest.mark.slow
def test_larger_hr_ratio_refines_monotonically(terrain) -> None:
    v = make_view(-71.3, 44.15, 9000.0, 0.0, -30.0, viewport=(320, 240))
    counts = [
        _triangles(traverse(v, terrain, RishePolicy(hr_ratio=h))) for h in (50.0, 200.0, 400.0)
    ]
    assert counts[0] <= counts[1] <= counts[2] and counts[0] < counts[2]


# -- crack-free renders ----------------------------------------------------------------------------
VIEWS = {
    "global": (0.0, 20.0, 2.0e7, 0.0, -90.0),
    "white-mountains-oblique": (-71.3, 44.15, 9000.0, 0.0, -30.0),
    "corner-0-0": (0.0, 0.0, 3.0e5, 0.0, -90.0),
    "corner-m90-45": (-90.0, 45.0, 1.0e6, 0.0, -90.0),
}


@pytest.fixture(scope="module")
def gl_session(terrain, tmp_path_factory):
    from globeview.app.session import GlobeSession
    from globeview.model.camera import Camera
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import JsonFileSettings
    from globeview.render.offscreen import OffscreenTarget, RenderError, create_headless_context

    try:
        ctx = create_headless_context()
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")
    cfg = tmp_path_factory.mktemp("gv-config")
    reg = PluginRegistry(JsonFileSettings(cfg / "settings.json")).discover()
    session = GlobeSession(
        ctx, terrain, Camera.from_lonlat(0, 20, 2e7), reg, lod="distance-regions"
    )
    session.settings.background = MAGENTA
    target = OffscreenTarget(ctx, (320, 240))
    return session, target


def magenta_mask(rgb: np.ndarray) -> np.ndarray:
    return np.all(np.abs(rgb.astype(int) - np.array([255, 0, 255])) <= 2, axis=-1)


def ellipsoid_mask(view) -> np.ndarray:
    """(h, w) bool: pixels whose central ray meets the WGS84 ellipsoid (float64, from scratch)."""
    from globeview.geodesy import WGS84

    w, h = view.viewport
    t = math.tan(math.radians(view.fovy_deg) / 2.0)
    xs = ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * t * view.aspect
    ys = (1.0 - (np.arange(h) + 0.5) / h * 2.0) * t
    nx, ny = np.meshgrid(xs, ys)
    d = np.stack([nx, ny, -np.ones_like(nx)], axis=-1) @ view.rotation
    semi = np.array([WGS84.a, WGS84.a, WGS84.b])
    d, o = d / semi, view.eye / semi
    qa, qb, qc = np.sum(d * d, axis=-1), np.sum(d * o, axis=-1), float(o @ o) - 1.0
    return (qb * qb - qa * qc > 0.0) & (qb < 0.0)


def erode(mask: np.ndarray, k: int) -> np.ndarray:
    out = mask.copy()
    for axis in (0, 1):
        for sh in range(1, k + 1):
            for sgn in (1, -1):
                rolled = np.roll(mask, sgn * sh, axis=axis)
                edge = [slice(None)] * 2
                edge[axis] = slice(0, sh) if sgn > 0 else slice(-sh, None)
                rolled[tuple(edge)] = False
                out &= rolled
    return out


def sandwiched(bg: np.ndarray) -> np.ndarray:
    """Background pixels with surface above and below, or left and right: holes."""
    fg = ~bg
    above = np.maximum.accumulate(fg, axis=0)
    below = np.maximum.accumulate(fg[::-1], axis=0)[::-1]
    left = np.maximum.accumulate(fg, axis=1)
    right = np.maximum.accumulate(fg[:, ::-1], axis=1)[:, ::-1]
    return bg & ((above & below) | (left & right))


def assert_crack_free(session, target, cam) -> object:
    """Render ``cam``; no background pixel inside the globe, no hole in the surface."""
    session.camera = cam
    result = session.render(target.fbo, target.size)
    bg = magenta_mask(target.read_rgb())
    inside = erode(ellipsoid_mask(result.view), 2)
    assert inside.any()
    holes = (bg & inside) | sandwiched(bg)
    assert not holes.any(), f"{holes.sum()} holes, e.g. {np.argwhere(holes)[:5].tolist()}"
    return result


@pytest.mark.gl
@pytest.mark.parametrize("name", list(VIEWS))
def test_renders_without_cracks(gl_session, name: str) -> None:
    from globeview.model.camera import Camera

    session, target = gl_session
    result = assert_crack_free(session, target, Camera.from_lonlat(*VIEWS[name]))
    assert session.lod_name == "distance-regions"  # the provider did not fail over
    assert result.stats.triangles > 0


def test_the_finest_settings_stay_within_the_render_set_limit(terrain) -> None:
    """HR_RATIO and rings at their largest and the largest tile budget the provider offers
    (`MAX_TILES`): the selection passes its soft budget but never the render set's limit
    (it drew 22839 tiles, and failed, before the traversal held that limit)."""
    from globeview.plugins.api import MAX_TILES
    from globeview.plugins.builtin.regions.provider import DistanceRegionsProvider

    provider = DistanceRegionsProvider()
    assert {s.name: s.max for s in provider.settings}["max_tiles"] == MAX_TILES
    provider.configure(
        {"max_tiles": MAX_TILES, "hr_ratio": 10000.0, "ring1": 100.0, "ring2": 1000.0,
         "ring3": 10000.0}
    )  # fmt: skip
    rs = provider.select(make_view(-71.3, 44.15, 3.0e5, 0.0, -30.0), terrain)
    assert MAX_TILES // 2 < len(rs) <= MAX_TILES
    rs.validate(SIZE)
