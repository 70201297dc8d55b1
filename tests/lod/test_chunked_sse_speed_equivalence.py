"""The optimised `chunked-sse` selection (per-tile caches, fewer numpy calls) returns exactly
what the original level-by-level walk returned.

The oracle is a frozen copy of the original `select_tiles` and of the culling helpers it used
(`_reference_*` below), computed at test time; the optimised one must return identical keys,
index variants and variant ids, and the same projected errors, for a set of views (global,
oblique, low-altitude, polar, antimeridian), with vertical exaggeration 1 and 3, with a CPU
displacement, and across a moving camera (per-tile cache hits and misses both exercised).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from globeview.geodesy import WGS84, lonlat_to_ecef
from globeview.lod import cached_culling, tile_cache
from globeview.lod.candidates import MAX_LEVEL
from globeview.lod.culling import LATTICE, chord_sag, displacement_chord_error_m, horizon_cap
from globeview.lod.render_set import RenderSet
from globeview.lod.sse_policy import ScreenSpaceErrorPolicy
from globeview.lod.tile_indices import IndexVariant
from globeview.lod.traversal import traverse
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera
from globeview.terrain.compose.metadata import N_STRIDES
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.quadtree import tile_bounds_arrays

#: (lon, lat, height, heading, pitch) of the compared views.
VIEWS = {
    "global": (0.0, 20.0, 2e7, 0.0, -90.0),
    "alps-oblique": (8.0, 44.0, 3e5, 20.0, -35.0),
    "white-mountains": (-71.3, 44.15, 9000.0, 0.0, -30.0),
    "crater-lake": (-122.1, 42.85, 6000.0, 200.0, -25.0),
    "pole": (0.0, 90.0, 2e6, 0.0, -90.0),
    "antimeridian": (180.0, 10.0, 3e5, 0.0, -90.0),
}


# -- the oracle: a frozen copy of the original algorithm ----
def _reference_tile_bounding_points(west, south, east, north, hmin, hmax, exaggeration=1.0):
    n = len(west)
    t = np.linspace(0.0, 1.0, LATTICE)
    lon = west[:, None] + (east - west)[:, None] * t[None, :]
    lat = north[:, None] + (south - north)[:, None] * t[None, :]
    lon_g = np.broadcast_to(lon[:, None, :], (n, LATTICE, LATTICE))
    lat_g = np.broadcast_to(lat[:, :, None], (n, LATTICE, LATTICE))
    lo = hmin * exaggeration
    hi = hmax * exaggeration
    shape = lon_g.shape
    h = np.stack(
        [np.broadcast_to(lo[:, None, None], shape), np.broadcast_to(hi[:, None, None], shape)],
        axis=1,
    )
    pts = lonlat_to_ecef(
        np.broadcast_to(lon_g[:, None], h.shape), np.broadcast_to(lat_g[:, None], h.shape), h
    )
    spacing = np.maximum(east - west, north - south) / (LATTICE - 1)
    margin = chord_sag(spacing) + 1.0
    return pts.reshape(n, -1, 3), margin


def _reference_frustum_visible(view, points, margin):
    planes = view.frustum_planes
    rel = points - view.eye
    d_eye = planes[:, :3] @ view.eye + planes[:, 3]
    dist = np.einsum("nkj,pj->npk", rel, planes[:, :3]) + d_eye[None, :, None]
    outside = np.all(dist < -margin[:, None, None], axis=2)
    return ~np.any(outside, axis=1)


def _reference_central_angle(lat1, lat2, dlon):
    c = math.sin(lat1) * np.sin(lat2) + math.cos(lat1) * np.cos(lat2) * np.cos(dlon)
    return np.arccos(np.clip(c, -1.0, 1.0))


def _reference_box_angular_distance(lon0, lat0, west, south, east, north):
    p0 = math.radians(lat0)
    dw = np.radians((lon0 - west + 180.0) % 360.0 - 180.0)
    de = np.radians((lon0 - east + 180.0) % 360.0 - 180.0)
    span = np.radians(east - west)
    inside = (dw >= 0.0) & (dw <= span) | (span >= 2 * math.pi - 1e-12)
    s_r, n_r = np.radians(south), np.radians(north)

    def to_meridian(dlon):
        lat_star = np.arctan2(math.tan(p0) if abs(p0) < math.pi / 2 else 1e12, np.cos(dlon))
        lat_c = np.clip(lat_star, s_r, n_r)
        return _reference_central_angle(p0, lat_c, dlon)

    same_meridian = np.abs(p0 - np.clip(p0, s_r, n_r))
    other = np.minimum(to_meridian(dw), to_meridian(de))
    return np.where(inside, same_meridian, other)


def _reference_horizon_visible(view, west, south, east, north, hmax, exaggeration=1.0):
    lon0, lat0, h0 = view.eye_lonlat_h
    r = WGS84.b
    if h0 <= 0.0:
        return np.ones(len(west), dtype=bool)
    cap = math.acos(r / (r + h0))
    peak = np.maximum(np.asarray(hmax, dtype=np.float64) * exaggeration, 0.0)
    cap_total = cap + np.arccos(r / (r + peak))
    return _reference_box_angular_distance(lon0, lat0, west, south, east, north) <= cap_total


def _reference_bounding_distance(view, points, margin):
    centre = points.mean(axis=1)
    radius = np.max(np.linalg.norm(points - centre[:, None, :], axis=2), axis=1) + margin
    d = np.linalg.norm(centre - view.eye, axis=1) - radius
    return np.maximum(d, 1.0)


def _reference_stride_errors_m(level, height_err, exaggeration, size):
    node_deg = 180.0 / 2**level / (size - 1)
    strides = 2 ** np.arange(N_STRIDES)
    sag = chord_sag(node_deg * strides)
    valid = strides <= size - 1
    total = height_err * exaggeration + sag[None, :]
    total[:, ~valid] = np.inf
    return total


def select_tiles(view: ViewState, terrain: TerrainStack, settings: dict | None = None) -> RenderSet:
    """chunked-sse's selection: the shared traversal with `ScreenSpaceErrorPolicy`, built
    from ``settings`` (its keyword arguments: tau_px, texel_px, max_tiles)."""
    return traverse(view, terrain, ScreenSpaceErrorPolicy(**(settings or {})))


@dataclasses.dataclass
class _Settings:
    """The original chunked-sse settings (the oracle's)."""

    tau_px: float | None = None
    texel_px: float = 1.5
    max_tiles: int = 600


def _reference_select_tiles(
    view: ViewState, terrain: TerrainStack, settings: dict | None = None
) -> RenderSet:
    """The original (pre-optimisation) chunked-sse selection, verbatim but for the helpers'
    names and its settings' type: the oracle the optimised `select_tiles` must match."""
    settings = _Settings(**(settings or {}))
    tau = settings.tau_px if settings.tau_px is not None else view.tau_px
    size = terrain.tile_size
    k_px = view.sse_factor
    exag = view.exaggeration

    x = np.array([0, 1], dtype=np.int64)
    y = np.array([0, 0], dtype=np.int64)
    out_keys, out_stride, out_err = [], [], []
    culled_f = culled_h = 0
    drawn = 0
    for level in range(MAX_LEVEL + 1):
        if len(x) == 0:
            break
        w, s, e, n = tile_bounds_arrays(level, x, y)
        meta = terrain.metadata(level, x, y)
        pts, margin = _reference_tile_bounding_points(w, s, e, n, meta.hmin, meta.hmax, exag)
        pts_true = pts
        if view.displace is not None:
            pts = np.asarray(view.displace(pts.reshape(-1, 3)), dtype=np.float64).reshape(pts.shape)
        vis_f = _reference_frustum_visible(view, pts, margin)
        vis_h = _reference_horizon_visible(view, w, s, e, n, meta.hmax, exag)
        culled_f += int(np.count_nonzero(~vis_f))
        culled_h += int(np.count_nonzero(vis_f & ~vis_h))
        keep = vis_f & vis_h
        x, y = x[keep], y[keep]
        if len(x) == 0:
            break
        err = _reference_stride_errors_m(level, meta.stride_error[keep], exag, size)
        if view.displace is not None:
            bend = displacement_chord_error_m(view.displace, pts_true[keep])
            frac = np.minimum(1.0, 2.0 ** np.arange(N_STRIDES) * (LATTICE - 1) / (size - 1))
            err = err + bend[:, None] * frac[None, :]
        dist = _reference_bounding_distance(view, pts[keep], margin[keep])
        px_per_m = k_px / dist
        sse = err * px_per_m[:, None]
        tile_m = math.radians(180.0 / 2**level) * 6.371e6
        texel = tile_m / (size - 1) * px_per_m
        finer = meta.has_finer[keep]
        refine = ((sse[:, 0] > tau) & (finer | (level < MAX_LEVEL))) | (
            (texel > settings.texel_px) & finer
        )
        if level == MAX_LEVEL:
            refine[:] = False
        n_ref = int(np.count_nonzero(refine))
        room = settings.max_tiles - drawn - int(np.count_nonzero(~refine))
        if n_ref * 4 > room and n_ref > 0:
            allowed = max(room // 4, 0)
            order = np.argsort(-sse[:, 0])
            ref_idx = order[refine[order]][:allowed]
            refine[:] = False
            refine[ref_idx] = True
        acc = ~refine
        if acc.any():
            ok = sse[acc] <= tau
            idx = np.where(ok.any(axis=1), N_STRIDES - 1 - np.argmax(ok[:, ::-1], axis=1), 0)
            out_keys.append(np.stack([np.full(int(acc.sum()), level), x[acc], y[acc]], axis=1))
            out_stride.append(idx)
            out_err.append(sse[acc][np.arange(len(idx)), idx])
            drawn += int(acc.sum())
        rx, ry = x[refine], y[refine]
        x = np.concatenate([2 * rx, 2 * rx + 1, 2 * rx, 2 * rx + 1])
        y = np.concatenate([2 * ry, 2 * ry, 2 * ry + 1, 2 * ry + 1])

    if not out_keys:
        rs = RenderSet.empty()
    else:
        keys = np.concatenate(out_keys)
        stride_idx = np.concatenate(out_stride)
        pole = (keys[:, 2] == 0).astype(np.int64) + 2 * (keys[:, 2] == (1 << keys[:, 0]) - 1)
        combo = stride_idx * 4 + pole
        uniq, ids = np.unique(combo, return_inverse=True)
        poles = (None, "north", "south", "both")
        variants = [IndexVariant(stride=int(2 ** (c // 4)), pole=poles[c % 4]) for c in uniq]
        rs = RenderSet(keys, ids, variants, error_px=np.concatenate(out_err))
    rs.stats.update({"tiles_culled_frustum": culled_f, "tiles_culled_horizon": culled_h})
    return rs


# -- fixtures and helpers ----
@pytest.fixture(scope="module")
def terrain(globeview_terrain: TerrainStack) -> TerrainStack:
    """The embedded terrain: the run's one stack (`globeview_terrain`, tests/conftest.py), not
    one of the module's own (each stack measures its layers' blend masks again: up to ~7 CPU-s)."""
    return globeview_terrain


def _view(lon, lat, h, heading=0.0, pitch=-90.0, exaggeration=1.0) -> ViewState:
    cam = Camera.from_lonlat(lon, lat, h, heading, pitch)
    return ViewState.from_camera(cam, (1280, 720), exaggeration=exaggeration)


def _rotate_z(points: np.ndarray, angle_rad: float = 2e-4) -> np.ndarray:
    """A small rotation of ECEF points about the z axis (a stand-in CPU displacement)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    p = np.asarray(points, dtype=np.float64)
    return np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]], axis=1)


def _fold(points: np.ndarray) -> np.ndarray:
    """A non-affine displacement: lowers points radially by an amount varying with x."""
    p = np.asarray(points, dtype=np.float64)
    r = np.linalg.norm(p, axis=1, keepdims=True)
    return p * (1.0 - 50.0 * np.abs(np.sin(p[:, :1] / 2e5)) / r)


def _assert_same(got: RenderSet, want: RenderSet, label: str) -> None:
    assert np.array_equal(got.keys, want.keys), f"{label}: keys differ"
    assert list(got.variants) == list(want.variants), f"{label}: variants differ"
    assert np.array_equal(got.variant_ids, want.variant_ids), f"{label}: variant ids differ"
    np.testing.assert_allclose(got.error_px, want.error_px, rtol=1e-12, err_msg=label)
    for k in ("tiles_culled_frustum", "tiles_culled_horizon"):
        assert got.stats.get(k) == want.stats.get(k), f"{label}: {k} differs"


# -- tests ----
@pytest.mark.slow
@pytest.mark.parametrize("exaggeration", [1.0, 3.0])
@pytest.mark.parametrize("name", sorted(VIEWS))
def test_views_match_reference(terrain, name, exaggeration) -> None:
    view = _view(*VIEWS[name], exaggeration=exaggeration)
    want = _reference_select_tiles(view, terrain)
    assert len(want.keys) > 0
    # Twice: the first call may fill the per-tile cache (misses), the second reads it (hits).
    for i in range(2):
        _assert_same(select_tiles(view, terrain), want, f"{name} x{exaggeration} call {i}")


@pytest.mark.slow
@pytest.mark.parametrize("displace", [_rotate_z, _fold], ids=["rotate-z", "fold"])
@pytest.mark.parametrize("name", ["alps-oblique", "white-mountains", "global", "antimeridian"])
def test_displaced_views_match_reference(terrain, name, displace) -> None:
    for exaggeration in (1.0, 3.0):
        view = dataclasses.replace(
            _view(*VIEWS[name], exaggeration=exaggeration), displace=displace
        )
        want = _reference_select_tiles(view, terrain)
        for i in range(2):
            _assert_same(select_tiles(view, terrain), want, f"{name} displaced call {i}")


def test_displacement_change_invalidates_displaced_cache(terrain) -> None:
    """Displaced lattices and bends are cached per displacement across frames: switching the
    displacement (or its bend measure) under a camera must recompute, not reuse them."""
    base = _view(*VIEWS["alps-oblique"])
    steps = [
        dict(displace=_fold),
        dict(displace=_rotate_z),
        dict(displace=lambda p: _rotate_z(p, 3e-4), displacement_key=("rot", 3e-4)),
        dict(displace=_fold),
        dict(
            displace=_fold,
            displacement_bend=lambda p, d: displacement_chord_error_m(_fold, p) + 50.0,
        ),
        dict(displace=_fold),
    ]
    for i, kw in enumerate(steps):
        view = dataclasses.replace(base, **kw)
        want = _reference_select_tiles(view, terrain)
        if "displacement_bend" in kw:  # the oracle knows the exact measure only
            got = select_tiles(view, terrain)
            same_keys = np.array_equal(got.keys, want.keys)
            assert not same_keys or not np.allclose(got.error_px, want.error_px), i
            continue
        for j in range(2):
            _assert_same(select_tiles(view, terrain), want, f"step {i} call {j}")


@pytest.mark.slow
def test_moving_camera_matches_reference(terrain) -> None:
    """A flight with changing exaggeration and settings: the caches see hits, misses,
    invalidation (exaggeration changes) and views revisited."""
    path = [
        (-71.3 + 0.01 * i, 44.15 + 0.004 * i, 9000.0 + 500.0 * i, 5.0 * i, -30.0 - i)
        for i in range(8)
    ]
    path += [(-122.1, 42.85, 6000.0 * (1 + i), 200.0, -25.0) for i in range(4)]
    path += [(179.5 + 0.25 * i, 10.0, 3e5, 0.0, -60.0) for i in range(4)]
    path += [(-71.3, 44.15, 9000.0, 0.0, -30.0)]
    settings = [None, {"texel_px": 3.0}, {"max_tiles": 64}]
    for i, cam in enumerate(path):
        exaggeration = 3.0 if i % 5 == 4 else 1.0
        view = _view(*cam, exaggeration=exaggeration)
        st = settings[i % len(settings)]
        _assert_same(
            select_tiles(view, terrain, st),
            _reference_select_tiles(view, terrain, st),
            f"step {i} {cam}",
        )


@pytest.mark.slow
def test_terrain_change_invalidates_cache(terrain) -> None:
    """Hiding a layer bumps TerrainStack.version: the selection follows the new terrain."""
    view = _view(*VIEWS["white-mountains"])
    select_tiles(view, terrain)
    name = terrain.layers[-1].name
    try:
        terrain.set_visible(name, False)
        _assert_same(select_tiles(view, terrain), _reference_select_tiles(view, terrain), "hidden")
    finally:
        terrain.set_visible(name, True)
    _assert_same(select_tiles(view, terrain), _reference_select_tiles(view, terrain), "shown")


def test_cache_is_bounded(terrain, monkeypatch) -> None:
    """With a tiny cap the per-tile cache starts afresh instead of growing (it holds at most
    the cap plus one frame's tiles), and the results still match."""
    monkeypatch.setattr(tile_cache, "TILE_CACHE_CAP", 64)

    def held() -> int:
        return tile_cache.tile_cache_for(terrain).held

    sizes = []
    for name in ("white-mountains", "global", "crater-lake", "global"):
        view = _view(*VIEWS[name])
        _assert_same(select_tiles(view, terrain), _reference_select_tiles(view, terrain), name)
        sizes.append(held())
    # The global view walks few tiles: after the White Mountains filled the cache past the
    # cap, it was dropped and holds only what the global view needed.
    assert sizes[1] < sizes[0]
    tile_cache.tile_cache_for(terrain).clear()  # a cold cache
    select_tiles(_view(*VIEWS["global"]), terrain)
    assert held() == sizes[1]


@pytest.mark.slow
def test_prefilters_agree_with_exact_tests(terrain) -> None:
    """The conservative frustum / horizon prefilters never contradict the exact tests, on
    random tiles of many levels seen from random eyes (low to very high, any direction)."""
    rng = np.random.default_rng(7)
    n_open = 0
    for level in (0, 1, 3, 6, 9, 12):
        n_side = 2**level
        x = rng.integers(0, 2 * n_side, 300)
        y = rng.integers(0, n_side, 300)
        codes = np.unique((x << 32) | y)
        x, y = codes >> 32, codes & 0xFFFFFFFF
        for _ in range(6):
            lon, lat = rng.uniform(-180, 180), rng.uniform(-90, 90)
            h = float(10 ** rng.uniform(2.5, 8.5))
            exaggeration = float(rng.choice([1.0, 3.0]))
            view = _view(
                lon, lat, h, rng.uniform(0, 360), rng.uniform(-90, 0), exaggeration=exaggeration
            )
            facts = tile_cache.tile_facts(terrain, level, x, y, exaggeration, 65)
            c, pts = facts["cols"], facts["pts"]
            w, s, e, n = tile_bounds_arrays(level, x, y)
            meta = terrain.metadata(level, x, y)
            # Frustum: decided tiles agree with the exact test.
            frame = cached_culling.FrustumFrame(view)
            vis, amb, open_planes = cached_culling.frustum_prefilter(
                frame,
                facts["centre"] - view.eye,
                c[tile_cache.COL_MARGIN],
                c[tile_cache.COL_SPHERE],
            )
            exact_f = _reference_frustum_visible(view, pts, c[tile_cache.COL_MARGIN])
            assert np.array_equal(vis[~amb], exact_f[~amb])
            assert np.array_equal(frame.exact(pts, c[tile_cache.COL_MARGIN]), exact_f)
            # ... and so does the exact test of only the planes the prefilter left open.
            ai = np.flatnonzero(amb)
            got = frame.exact_planes(pts[ai], c[tile_cache.COL_MARGIN][ai], open_planes[ai])
            assert np.array_equal(got, exact_f[ai])
            n_open += len(ai)
            # Horizon: the prefiltered test equals the reference.
            cap = horizon_cap(view)
            lon0, lat0 = np.radians(view.eye_lonlat_h[:2])
            u0 = np.array([np.cos(lat0) * np.cos(lon0), np.cos(lat0) * np.sin(lon0), np.sin(lat0)])
            want = _reference_horizon_visible(view, w, s, e, n, meta.hmax, exaggeration)
            assert np.array_equal(cached_culling.horizon_visible_cached(view, cap, c, u0), want)
    assert n_open > 20, n_open  # the plane-wise exact test met ambiguous tiles
