"""The `wavelet` LOD provider (Zhang et al. §V): M-band level ladders, static vs dynamic error,
monotonicity in tau, and crack-free renders through the plugin session."""

from __future__ import annotations

import importlib.util
import itertools
from pathlib import Path

import numpy as np
import pytest

from globeview.app.testing import make_view
from globeview.lod.tile_indices import grid_indices
from globeview.lod.traversal import traverse
from globeview.plugins.builtin.wavelet.provider import ZhangWaveletPolicy, stop_levels

MAGENTA = (1.0, 0.0, 1.0)


@pytest.fixture(scope="module")
def terrain(globeview_terrain):
    """The embedded terrain: the run's one stack (`globeview_terrain`, tests/conftest.py), not
    one of the module's own (each stack measures its layers' blend masks again: up to ~7 CPU-s)."""
    return globeview_terrain


def test_m_band_ladders() -> None:
    assert stop_levels(2, 8).all()
    assert np.nonzero(stop_levels(4, 8))[0].tolist() == [0, 2, 4, 6, 8]
    # ceil(k log2 3): each step at least 3x finer than the last.
    assert np.nonzero(stop_levels(3, 10))[0].tolist() == [0, 2, 4, 5, 7, 8, 10]


def _triangles(rs, size: int = 65) -> int:
    per = [len(grid_indices(size, v)) // 3 for v in rs.variants]
    return int(sum(per[i] for i in rs.variant_ids))


WM = (-71.3, 44.15, 9000.0, 0.0, -30.0)


@pytest.mark.slow
@pytest.mark.parametrize("m", [2, 3, 4])
def test_larger_tau_draws_no_more_triangles(terrain, m: int) -> None:
    v = make_view(*WM, viewport=(320, 240))
    counts = [
        _triangles(traverse(v, terrain, ZhangWaveletPolicy(m=m, tau_px=t)))
        for t in (1.0, 2.0, 4.0, 8.0)
    ]
    assert all(a >= b for a, b in itertools.pairwise(counts)), counts
    assert counts[0] > counts[-1]
    rs = traverse(v, terrain, ZhangWaveletPolicy(m=m))
    stops = stop_levels(m)
    assert stops[rs.keys[:, 0]].all()  # tiles stop only on the M-band ladder
    assert rs.error_px is not None and len(rs.error_px) == len(rs)
    assert {"lod_ms", "tiles_culled_frustum", "tiles_culled_horizon"} <= set(rs.stats)


@pytest.mark.slow
def test_flat_tile_is_coarser_than_a_rough_one(terrain) -> None:
    """Same altitude and view, over the flat Atlantic vs the White Mountains: the flat tile
    under the camera is drawn at a coarser level or stride."""

    def nadir_tile(lon: float, lat: float):
        v = make_view(lon, lat, 2.0e4, viewport=(320, 240))
        rs = traverse(v, terrain, ZhangWaveletPolicy(static_m=5.0))
        from globeview.terrain.quadtree import tile_bounds_arrays

        hits = [
            i
            for i, (lv, x, y) in enumerate(rs.keys.tolist())
            if (lambda b: b[0] <= lon <= b[2] and b[1] <= lat <= b[3])(
                [float(np.asarray(t).reshape(-1)[0]) for t in tile_bounds_arrays(lv, x, y)]
            )
        ]
        hit = hits[0]
        stride = rs.variants[rs.variant_ids[hit]].stride
        return int(rs.keys[hit, 0]), stride, rs.stats["tiles_flat"]

    rough_level, rough_stride, _ = nadir_tile(-71.3, 44.27)  # Mt Washington area
    flat_level, flat_stride, flat_count = nadir_tile(-40.0, 30.0)  # mid-Atlantic
    assert flat_count > 0
    # A cell of the flat tile covers more ground: coarser level and/or stride.
    assert flat_stride * 2.0**-flat_level > rough_stride * 2.0**-rough_level


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
    session = GlobeSession(ctx, terrain, Camera.from_lonlat(0, 20, 2e7), reg, lod="wavelet")
    session.settings.background = MAGENTA
    return session, OffscreenTarget(ctx, (320, 240))


VIEWS = {
    "global": (0.0, 20.0, 2.0e7, 0.0, -90.0),
    "white-mountains-oblique": WM,
    "corner-0-0": (0.0, 0.0, 3.0e5, 0.0, -90.0),
    "corner-m90-45": (-90.0, 45.0, 1.0e6, 0.0, -90.0),
}


@pytest.mark.slow
@pytest.mark.gl
@pytest.mark.parametrize("name", list(VIEWS))
def test_renders_without_cracks(gl_session, name: str) -> None:
    from globeview.model.camera import Camera

    # The crack oracle lives in the sibling module (no conftest in tests/lod/).
    spec = importlib.util.spec_from_file_location(
        "_dr_tests", Path(__file__).with_name("test_distance_regions.py")
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert_crack_free = mod.assert_crack_free

    session, target = gl_session
    result = assert_crack_free(session, target, Camera.from_lonlat(*VIEWS[name]))
    assert session.lod_name == "wavelet"  # the provider did not fail over
    assert result.stats.triangles > 0
