"""The `quadtree-clod` LOD provider: the thesis' vertex-dependency invariant on real tiles,
shared tile edges enabled identically, fans that tile each tile exactly, monotonic
triangle counts in tau, frame reuse, and crack-free renders through the plugin session."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from globeview.app.testing import make_view
from globeview.plugins.builtin.clod.provider import QuadtreeClodProvider

MAGENTA = (1.0, 0.0, 1.0)
VIEWS = {
    "global": (0.0, 20.0, 2.0e7, 0.0, -90.0),
    "white_mountains": (-71.3, 44.15, 9000.0, 0.0, -30.0),
    "border_0_0": (0.0, 0.0, 3.0e5, 0.0, -90.0),
    "border_-90_45": (-90.0, 45.0, 1.0e6, 0.0, -90.0),
}


@pytest.fixture(scope="module")
def terrain(globeview_terrain):
    """The embedded terrain: the run's one stack (`globeview_terrain`, tests/conftest.py), not
    one of the module's own (each stack measures its layers' blend masks again: up to ~7 CPU-s)."""
    return globeview_terrain


def provider(**values) -> QuadtreeClodProvider:
    p = QuadtreeClodProvider(None)
    p.configure(values)
    return p


@pytest.fixture(scope="module")
def wm_frame(terrain):
    """The White Mountains oblique view's render set and CLOD state (many tiles, 3 levels)."""
    p = provider()
    rs = p.select(make_view(*VIEWS["white_mountains"], viewport=(640, 360)), terrain)
    return rs, p.last_frame


# -- conftest_clod helpers: independent checks of the CLOD state ----------------------------
def dependency_violations(frame) -> int:
    """Count broken dependencies (thesis §4.4, restricted quadtree), written independently of
    the provider's closure: for each block level, with explicit node coordinates."""
    en = frame.enabled
    _t_n, size, _ = en.shape
    n = size - 1
    bad = 0
    for j, on in enumerate(frame.on):
        hh = n >> (j + 1)
        nb = 1 << j
        t, bi, bj = np.nonzero(on)
        rc, cc = (2 * bi + 1) * hh, (2 * bj + 1) * hh
        # a refined block: centre and four corners enabled, parent refined
        bad += int(np.count_nonzero(~en[t, rc, cc]))
        for dr in (-hh, hh):
            for dc in (-hh, hh):
                bad += int(np.count_nonzero(~en[t, rc + dr, cc + dc]))
        if j > 0:
            bad += int(np.count_nonzero(~frame.on[j - 1][t, bi // 2, bj // 2]))
        # an enabled centre belongs to a refined block
        tc, rr, ccc = np.nonzero(en[:, hh :: 2 * hh, hh :: 2 * hh])
        bad += int(np.count_nonzero(~on[tc, rr, ccc]))
        # an enabled edge midpoint: the blocks on both sides (inside the tile) are refined
        th, r, c = np.nonzero(en[:, 0 :: 2 * hh, hh :: 2 * hh])
        above, below = r - 1, r
        ok_a = above < 0
        ok_a[~ok_a] = on[th[~ok_a], above[~ok_a], c[~ok_a]]
        ok_b = below >= nb
        ok_b[~ok_b] = on[th[~ok_b], below[~ok_b], c[~ok_b]]
        bad += int(np.count_nonzero(~(ok_a & ok_b)))
        tv, r, c = np.nonzero(en[:, hh :: 2 * hh, 0 :: 2 * hh])
        left, right = c - 1, c
        ok_l = left < 0
        ok_l[~ok_l] = on[tv[~ok_l], r[~ok_l], left[~ok_l]]
        ok_r = right >= nb
        ok_r[~ok_r] = on[tv[~ok_r], r[~ok_r], right[~ok_r]]
        bad += int(np.count_nonzero(~(ok_l & ok_r)))
    return bad


def grid_triangles(indices: np.ndarray, size: int) -> np.ndarray:
    """(M, 3) triangles of a tile's list that use grid nodes only (no skirt vertices)."""
    tri = indices.reshape(-1, 3).astype(np.int64)
    return tri[np.all(tri < size * size, axis=1)]


# -- the thesis' invariants on real tiles ----------------------------------------------------
@pytest.mark.slow
def test_every_enabled_vertex_has_its_dependencies(wm_frame) -> None:
    rs, frame = wm_frame
    assert len(rs) > 20 and frame.enabled.sum() > 1000
    # Refinement is adaptive: neither everything nor only the roots. Each vertex level below
    # the roots is enabled in part, and less of it the finer it is (over the SRTM tile's
    # border band, where it feathers into the 20' base, even the finest level can be off).
    share = [float(on.mean()) for on in frame.on]
    assert all(0.0 < s < 1.0 for s in share[1:4]), share
    assert all(a >= b for a, b in itertools.pairwise(share)), share
    assert dependency_violations(frame) == 0


def test_dependency_checker_catches_a_broken_mesh(wm_frame) -> None:
    _, frame = wm_frame
    from copy import deepcopy

    broken = deepcopy(frame)
    t, bi, bj = (a[0] for a in np.nonzero(broken.on[3]))
    hh = (broken.enabled.shape[1] - 1) >> 4
    broken.enabled[t, 2 * bi * hh, 2 * bj * hh] = False  # a corner of a refined block
    assert dependency_violations(broken) > 0


def test_shared_tile_edges_are_enabled_identically(wm_frame) -> None:
    rs, frame = wm_frame
    keys = rs.keys
    lookup = {tuple(k): i for i, k in enumerate(keys.tolist())}
    pairs = 0
    for i, (lv, x, y) in enumerate(keys.tolist()):
        east = lookup.get((lv, (x + 1) % (2 << lv), y))
        south = lookup.get((lv, x, y + 1))
        if east is not None:
            assert np.array_equal(frame.enabled[i, :, -1], frame.enabled[east, :, 0])
            pairs += 1
        if south is not None:
            assert np.array_equal(frame.enabled[i, -1, :], frame.enabled[south, 0, :])
            pairs += 1
    assert pairs > 20


def test_fans_tile_every_tile_exactly(wm_frame, terrain) -> None:
    """The fans cover each tile's (row, col) square once: all counter-clockwise from above,
    areas summing to n^2, and only enabled vertices used."""
    rs, frame = wm_frame
    size = terrain.tile_size
    n = size - 1
    for row, idx in rs.custom_indices.items():
        tri = grid_triangles(idx, size)
        r, c = np.divmod(tri, size)
        x, y = c.astype(float), -r.astype(float)  # map coordinates: east, north
        area = 0.5 * (
            (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
        )
        assert np.all(area > 0), row
        assert area.sum() == pytest.approx(n * n), row
        assert frame.enabled[row].reshape(-1)[tri].all()
        # No T-junction: no enabled vertex lies inside an edge of a triangle.
        en_r, _en_c = np.nonzero(frame.enabled[row])
        for a, b in ((0, 1), (1, 2), (2, 0)):
            ra, ca, rb, cb = r[:, a], c[:, a], r[:, b], c[:, b]
            axis = (ra == rb) | (ca == cb)
            if not axis.any():
                continue
            # axis-aligned edges only hold grid nodes between their ends
            mid_r, mid_c = (ra + rb)[axis] // 2, (ca + cb)[axis] // 2
            span = np.maximum(np.abs(ra - rb), np.abs(ca - cb))[axis]
            inner = span >= 2
            assert not frame.enabled[row][mid_r[inner], mid_c[inner]].any()
        assert len(en_r) > 0


@pytest.mark.slow
def test_triangle_count_is_monotonic_in_tau(terrain) -> None:
    counts = []
    for tau in (0.5, 1.0, 2.0, 4.0, 8.0, 16.0):
        rs = provider(tau_px=tau).select(
            make_view(*VIEWS["white_mountains"], viewport=(640, 360)), terrain
        )
        counts.append(rs.stats["clod_triangles"])
        assert sum(len(i) // 3 for i in rs.custom_indices.values()) == counts[-1]
        assert rs.error_px.max() <= tau * 1.0001
    assert all(a >= b for a, b in itertools.pairwise(counts)), counts
    assert counts[0] > 2 * counts[-1]


@pytest.mark.slow
def test_exaggeration_multiplies_errors(terrain) -> None:
    view1 = make_view(*VIEWS["white_mountains"], viewport=(640, 360))
    view3 = make_view(*VIEWS["white_mountains"], viewport=(640, 360), exaggeration=3.0)
    a = provider().select(view1, terrain).stats["clod_triangles"]
    b = provider().select(view3, terrain).stats["clod_triangles"]
    assert b > a


def test_unchanged_view_reuses_the_meshes(terrain) -> None:
    p = provider()
    view = make_view(*VIEWS["border_-90_45"], viewport=(320, 240))
    first = p.select(view, terrain)
    again = p.select(make_view(*VIEWS["border_-90_45"], viewport=(320, 240)), terrain)
    assert again.stats["clod_reused"] == 1 and p.cache_hits == 1
    assert all(again.custom_indices[r] is first.custom_indices[r] for r in first.custom_indices)
    moved = p.select(make_view(-90.0, 45.0, 0.5e6, 0.0, -90.0, viewport=(320, 240)), terrain)
    assert moved.stats["clod_reused"] == 0 and p.cache_hits == 1
    p.configure({"tau_px": 8.0})  # settings changed: no reuse
    assert p.select(view, terrain).stats["clod_reused"] == 0


@pytest.mark.slow
def test_registry_loads_and_runs_it(globeview_registry) -> None:
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores

    prov = globeview_registry.lod_providers()["quadtree-clod"]
    rs = globeview_registry.select(
        prov, make_view(*VIEWS["global"]), TerrainStack.from_stores(embedded_stores())
    )
    assert len(rs) > 0 and len(rs.custom_indices) == len(rs)
    assert globeview_registry.get("quadtree-clod").status == "ok"


# -- crack-free renders through the plugin session ------------------------------------------
@pytest.fixture(scope="module")
def session(terrain, tmp_path_factory):
    from globeview.app.session import GlobeSession
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import JsonFileSettings
    from globeview.render.offscreen import RenderError, create_headless_context

    try:
        ctx = create_headless_context()
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")
    cfg = tmp_path_factory.mktemp("clod-config")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GLOBEVIEW_CONFIG_DIR", str(cfg))
        reg = PluginRegistry(JsonFileSettings(cfg / "settings.json")).discover()
        yield GlobeSession(ctx, terrain, registry=reg, lod="quadtree-clod")


def ground_mask(view, inflate_m: float) -> np.ndarray:
    """(h, w) bool: pixels whose ray meets the WGS84 ellipsoid shrunk by -inflate_m."""
    from globeview.geodesy import WGS84

    w, h = view.viewport
    t = np.tan(np.radians(view.fovy_deg) / 2.0)
    xs = ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * t * view.aspect
    ys = (1.0 - (np.arange(h) + 0.5) / h * 2.0) * t
    nx, ny = np.meshgrid(xs, ys)
    d = np.stack([nx, ny, -np.ones_like(nx)], axis=-1) @ view.rotation
    semi = np.array([WGS84.a, WGS84.a, WGS84.b]) + inflate_m
    d = d / semi
    o = view.eye / semi
    qa, qb, qc = np.sum(d * d, -1), np.sum(d * o, -1), float(o @ o) - 1.0
    return (qb * qb - qa * qc > 0.0) & (qb < 0.0)


def erode(mask: np.ndarray, k: int) -> np.ndarray:
    out = mask.copy()
    for ax in (0, 1):
        for s in range(1, k + 1):
            out &= np.roll(mask, s, ax) & np.roll(mask, -s, ax)
    return out


@pytest.mark.slow
@pytest.mark.gl
@pytest.mark.parametrize(
    ("view_name", "exaggeration"),
    [
        ("global", 1.0),
        ("white_mountains", 1.0),
        ("border_0_0", 1.0),
        ("border_-90_45", 1.0),
        ("white_mountains", 3.0),
    ],
)
def test_render_has_no_cracks(session, terrain, view_name, exaggeration) -> None:
    from globeview.model.camera import Camera
    from globeview.render.offscreen import OffscreenTarget

    size = (256, 192)
    session.settings.background = MAGENTA
    session.settings.exaggeration = exaggeration
    session.camera = Camera.from_lonlat(*VIEWS[view_name])
    target = OffscreenTarget(session.ctx, size)
    try:
        result = session.render(target.fbo, size)
        rgb = target.read_rgb()
    finally:
        target.release()
    assert session.lod_name == "quadtree-clod"
    assert session.registry.get("quadtree-clod").status == "ok"
    assert result.render_set.custom_indices and result.stats.triangles > 0
    magenta = np.all(np.abs(rgb.astype(int) - [255, 0, 255]) <= 2, axis=-1)
    # Below the horizon (rays meeting the ellipsoid 500 m down, away from its outline) no
    # background may show through.
    ground = erode(ground_mask(result.view, -500.0), 2)
    assert ground.sum() > 0.1 * ground.size
    assert not magenta[ground].any(), int(magenta[ground].sum())
