"""The flat, incremental selection (`globeview.lod.flat_walk`, issue #27 item 1): with a
selection state carried from frame to frame, `traverse` selects exactly what the
level-by-level walk selects - the same tiles in the same order, strides, errors (bits),
index variants and stats - over 200 random views, along the five benchmark flights, over tau
ladders, with exaggeration and tile budgets, for every built-in provider on the traversal;
and what it costs is counted (growth rounds, rows evaluated), never timed.

Also: the tile cache's new facts (levels past the data, pole codes, children across levels)
equal what the walk computes; the cut's budget search (many multipliers a pass, warm start)
draws the bisection's cut, tile counts never grow with the multiplier, and the sequential
fallback agrees.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from globeview.app.testing import make_view
from globeview.bench.flight import Flight, resolve_flight
from globeview.lod import cheapest_cut, tile_cache
from globeview.lod import sse_policy as sse
from globeview.lod.flat_walk import SelectionState
from globeview.lod.render_set import RenderSet
from globeview.lod.sse_policy import ScreenSpaceErrorPolicy
from globeview.lod.stitching import pole_codes
from globeview.lod.traversal import traverse
from globeview.plugins.builtin.chunked.provider import ChunkedSseProvider
from globeview.plugins.builtin.clod.provider import QuadtreeClodProvider
from globeview.plugins.builtin.regions.provider import DistanceRegionsProvider
from globeview.plugins.builtin.wavelet.provider import WaveletProvider

FLIGHTS = ("big_dem", "canyon_run", "fast_pan", "global_approach", "regional_oblique")
#: Stats the flat walk adds (the level walk has none) and the timing.
_OWN_STATS = {"lod_ms", "lod_rounds", "lod_rows_new", "lod_rows", "lod_cold"}
#: (lon, lat) boxes of the regional DEMs (as tests/lod/test_chunked_min_triangles.py).
REGIONS = (
    (-72.0, -71.0, 44.0, 45.0),
    (-122.17, -122.05, 42.9, 42.98),
    (-126.0, -122.0, 48.0, 50.0),
)


def random_poses(n: int = 200, seed: int = 17) -> list[tuple[float, ...]]:
    """test_chunked_min_triangles' views: half over the regional DEMs from 1.5 to 300 km,
    half anywhere from 300 to 20 000 km; any heading, pitch -90..-10 degrees."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        if i % 2 == 0:
            w, e, s, nn = REGIONS[(i // 2) % len(REGIONS)]
            lon, lat = rng.uniform(w, e), rng.uniform(s, nn) - 0.05
            height = float(np.exp(rng.uniform(np.log(1.5e3), np.log(3e5))))
        else:
            lon, lat = rng.uniform(-180.0, 180.0), np.degrees(np.arcsin(rng.uniform(-1, 1)))
            height = float(np.exp(rng.uniform(np.log(3e5), np.log(2e7))))
        out.append((lon, lat, height, rng.uniform(0.0, 360.0), rng.uniform(-90.0, -10.0)))
    return out


def flight_poses(name: str, windows: int = 3, frames: int = 12) -> list[list[tuple]]:
    """``windows`` runs of ``frames`` consecutive 60 fps poses spread over a flight."""
    fl = Flight.load(resolve_flight(name))
    times = fl.times(fps=60)
    starts = np.linspace(0, max(len(times) - frames, 0), windows).astype(int)
    return [[fl.pose(float(t)).as_tuple() for t in times[s : s + frames]] for s in starts]


def assert_same(a: RenderSet, b: RenderSet, what) -> None:
    """The same selection: keys in the same order, index variants, error bits, stats."""
    assert np.array_equal(a.keys, b.keys), what
    assert np.array_equal(a.variant_ids, b.variant_ids), what
    assert list(a.variants) == list(b.variants), what
    ea, eb = a.error_px, b.error_px  # None: an empty set
    assert (ea is None) == (eb is None), what
    assert ea is None or eb is None or ea.tobytes() == eb.tobytes(), what
    sa = {k: v for k, v in a.stats.items() if k not in _OWN_STATS}
    sb = {k: v for k, v in b.stats.items() if k not in _OWN_STATS}
    assert sa == sb, what


def case_of(rs: RenderSet) -> str:
    if "cut_over_budget" in rs.stats:
        return "over"
    return "traded" if "cut_traded" in rs.stats else "free"


def compare_along(terrain, poses, make_policy, state=None, **view_kw) -> dict[str, int]:
    """Select each pose with a state carried along and without one; assert the same
    selections; returns how many frames fell in each budget case."""
    state = SelectionState() if state is None else state
    cases = {"free": 0, "traded": 0, "over": 0}
    for i, pose in enumerate(poses):
        view = make_view(*pose, **view_kw)
        old = traverse(view, terrain, make_policy())
        new = traverse(view, terrain, make_policy(), state=state)
        assert_same(old, new, (i, pose, view_kw))
        cases[case_of(new)] += 1
    return cases


def _slow(*values: object) -> object:
    """A case ./test --fast leaves out (each takes 2-9 CPU-s here): --fast keeps the cheapest
    case of each identity test, ./test runs them all."""
    return pytest.param(*values, marks=pytest.mark.slow)


# -- identity ---------------------------------------------------------------------------------
@pytest.mark.parametrize("tau", [8.0])
def test_same_as_the_level_walk_over_random_views(globeview_terrain, tau) -> None:
    """200 random views in a row, one state carried through them all (each view a camera
    cut from the last: the tree grows and is pruned), chunked-sse's cut. Tau 0.5 and 2:
    test_chunked_min_triangles' random-views test (the same 200 views) holds its level-walk
    selections to the flat walk's, a state a tau carried through them in the same order."""
    poses = random_poses()
    cases = compare_along(
        globeview_terrain,
        poses,
        lambda: ScreenSpaceErrorPolicy(min_triangles=True),
        viewport=(1280, 720),
        tau_px=tau,
    )
    assert sum(cases.values()) == len(poses)


@pytest.mark.parametrize(
    ("exaggeration", "max_tiles"), [(1.0, 150), _slow(3.0, 600), _slow(10.0, 80)]
)
def test_same_with_exaggeration_and_budgets(globeview_terrain, exaggeration, max_tiles) -> None:
    """The cut's budget cases (free, traded, over: the plain walk with its own state) and
    the plain walk with a binding budget (quadtree-clod's tiles) agree too."""
    poses = random_poses(60, seed=5)
    seen = {"free": 0, "traded": 0, "over": 0}
    for min_tri in (True, False):
        cases = compare_along(
            globeview_terrain,
            poses,
            lambda m=min_tri: ScreenSpaceErrorPolicy(max_tiles=max_tiles, min_triangles=m),
            viewport=(1280, 720),
            exaggeration=exaggeration,
        )
        if min_tri:
            seen = cases
    assert seen["free"] > 0, seen
    if max_tiles <= 150:  # at 1280x720 these views draw up to ~400 tiles: some must trade
        assert seen["traded"] > 0, seen


@pytest.mark.parametrize("name", [n if n == "global_approach" else _slow(n) for n in FLIGHTS])
def test_same_along_the_flights(globeview_terrain, name) -> None:
    """Consecutive 60 fps frames of each benchmark flight, state carried, at three taus,
    tight budgets (trading with warm-started multipliers; over: the plain walk) and
    exaggeration."""
    for window in flight_poses(name):
        for tau in (1.0, 2.0, 4.0):
            compare_along(
                globeview_terrain,
                window,
                lambda: ScreenSpaceErrorPolicy(min_triangles=True),
                viewport=(1280, 720),
                tau_px=tau,
            )
        for max_tiles, viewport in ((400, (1280, 720)), (120, (3840, 2160))):
            compare_along(
                globeview_terrain,
                window,
                lambda b=max_tiles: ScreenSpaceErrorPolicy(max_tiles=b, min_triangles=True),
                viewport=viewport,
            )
        compare_along(
            globeview_terrain,
            window,
            lambda: ScreenSpaceErrorPolicy(min_triangles=False),
            viewport=(1280, 720),
            exaggeration=3.0,
        )


def _moving_camera_views(pose: tuple, viewport: tuple[int, int]) -> list:
    """bench_lod's moving camera at one benchmark view: its ``turn`` (+-0.01 degree yaw, 4
    frames), then its ``move`` (0.2 % of the height forward and 0.2 degree a frame, 6
    frames), each `ViewState.from_camera` with the speed of the motion at 30 fps."""
    from globeview.lod.view_state import ViewState
    from globeview.model.camera import Camera

    cam = Camera()
    cam.set_lonlat(*pose)
    views = [ViewState.from_camera(cam, viewport)]
    for i in range(1, 5):
        cam.fly_yaw(0.01 * (-1) ** i)
        views.append(ViewState.from_camera(cam, viewport))
    lon, lat, h, heading, pitch = pose
    for i in range(1, 7):
        step = 0.002 * h * i
        hd = np.radians(heading)
        la = lat + np.degrees(step * np.cos(hd) / 6.371e6)
        lo = lon + np.degrees(step * np.sin(hd) / (6.371e6 * np.cos(np.radians(lat))))
        prev = cam.eye.copy()
        cam.set_lonlat(lo, la, h, heading + 0.2 * i, pitch)
        speed = float(np.linalg.norm(cam.eye - prev)) * 30.0
        views.append(ViewState.from_camera(cam, viewport, speed_mps=speed))
    return views


@pytest.mark.parametrize("viewport", [(1280, 720), (3840, 2160)])
def test_same_at_the_benchmark_views_along_a_moving_camera(globeview_terrain, viewport) -> None:
    """The default provider (chunked-sse, its state kept as in the window) along
    bench_lod's moving camera at every benchmark view draws what the level walk draws
    from nothing each frame: tiles in the same order, strides, error bits, stats."""
    from globeview.bench.views import VIEWS

    for name, pose in VIEWS.items():
        provider = ChunkedSseProvider()
        for i, view in enumerate(_moving_camera_views(pose, viewport)):
            got = provider.select(view, globeview_terrain)
            want = traverse(view, globeview_terrain, ScreenSpaceErrorPolicy(**provider.values))
            assert_same(want, got, (name, i))
            assert len(got.keys) > 0, (name, i)
        assert provider._selection_state is not None and provider._selection_state.rows > 0


def test_a_view_over_every_budget_draws_the_plain_walk(globeview_terrain) -> None:
    """Exaggeration 30 at 5 km: the walk's budget passes (test_chunked_min_triangles); the
    flat walk stops at the same level and draws the same plain walk, twice in a row."""
    pose = (-71.3, 44.2, 5.0e3, 0.0, -20.0)
    cases = compare_along(
        globeview_terrain,
        [pose, pose],
        lambda: ScreenSpaceErrorPolicy(min_triangles=True),
        viewport=(1280, 720),
        exaggeration=30.0,
    )
    assert cases["over"] == 2


def _provider_frames(provider, terrain, poses, reference) -> None:
    for i, pose in enumerate(poses):
        view = make_view(*pose, viewport=(1280, 720))
        got = provider.select(view, terrain)
        want = reference(view)
        assert np.array_equal(got.keys, want.keys), (type(provider).__name__, i)
        assert np.array_equal(got.variant_ids, want.variant_ids), (type(provider).__name__, i)


@pytest.mark.parametrize("min_triangles", [True, False])
def test_chunked_sse_provider_keeps_a_state(globeview_terrain, min_triangles) -> None:
    provider = ChunkedSseProvider()
    provider.configure({"min_triangles": min_triangles})
    poses = flight_poses("canyon_run", 2, 8)[1] + random_poses(20, seed=3)

    def reference(view):
        return traverse(view, globeview_terrain, ScreenSpaceErrorPolicy(**provider.values))

    _provider_frames(provider, globeview_terrain, poses, reference)
    assert provider._selection_state is not None and provider._selection_state.rows > 0
    provider.reset()
    assert provider._selection_state.rows == 0


def test_quadtree_clod_base_traversal_keeps_a_state(globeview_terrain) -> None:
    provider = QuadtreeClodProvider()
    poses = flight_poses("fast_pan", 2, 6)[1]
    v = provider.values

    def reference(view):
        policy = ScreenSpaceErrorPolicy(
            tau_px=float(view.tau_px), texel_px=v["texel_px"], max_tiles=v["max_tiles"]
        )
        return traverse(view, globeview_terrain, policy)

    _provider_frames(provider, globeview_terrain, poses, reference)
    assert provider._lod_state.rows > 0


@pytest.mark.parametrize("cls", [DistanceRegionsProvider, WaveletProvider])
def test_level_walk_providers_are_unchanged(globeview_terrain, cls) -> None:
    """distance-regions and wavelet are not per tile (values cross levels): their state
    stays empty and they select as they did."""
    provider = cls()
    poses = flight_poses("regional_oblique", 1, 4)[0]

    def reference(view):
        return traverse(view, globeview_terrain, cls.policy(**provider.values))

    _provider_frames(provider, globeview_terrain, poses, reference)
    assert provider._selection_state is not None and provider._selection_state.rows == 0


# -- what a moving frame costs (counts) -------------------------------------------------------
@pytest.mark.parametrize("viewport", [(1280, 720), (3840, 2160)])
def test_a_turn_needs_no_growth_and_evaluates_only_the_tree(globeview_terrain, viewport) -> None:
    """A +-0.01 degree turn (bench_render's motion) at every benchmark view: after the first
    frame no growth round, no new row, and only the kept rows are evaluated."""
    from globeview.bench.views import VIEWS
    from globeview.lod.view_state import ViewState
    from globeview.model.camera import Camera

    for name, pose in VIEWS.items():
        cam = Camera()
        cam.set_lonlat(*pose)
        provider = ChunkedSseProvider()
        first = provider.select(ViewState.from_camera(cam, viewport), globeview_terrain)
        assert first.stats["lod_cold"] == 1  # an empty state: the level walk seeds the tree
        state = provider._selection_state
        for i in range(6):
            cam.fly_yaw(0.01 * (-1) ** i)
            rows = state.rows
            rs = provider.select(ViewState.from_camera(cam, viewport), globeview_terrain)
            assert rs.stats["lod_rounds"] == 0, (name, i)
            assert rs.stats["lod_rows_new"] == 0, (name, i)
            assert rs.stats["lod_rows"] == rows, (name, i)
            assert rs.stats["tiles_visited"] <= rows


@pytest.mark.parametrize("min_triangles", [True, False])
def test_a_cold_state_seeds_the_tree_the_flat_walk_grows(globeview_terrain, min_triangles) -> None:
    """From an empty state the frame is the level walk, whose record seeds the tree: the
    same rows (levels, slots, parents, walk keys, children held) as the flat walk grows
    from the roots, one level a round; the next frame at the same view grows nothing."""
    from globeview.lod.flat_walk import select_flat

    terrain = globeview_terrain
    view = make_view(-71.3, 44.15, 9000.0, 0.0, -30.0, viewport=(1280, 720))
    seeded = SelectionState()
    first = traverse(view, terrain, ScreenSpaceErrorPolicy(min_triangles=min_triangles), seeded)
    assert first.stats["lod_cold"] == 1 and first.stats["lod_rounds"] == 0
    assert first.stats["lod_rows_new"] == seeded.rows > 0
    grown = SelectionState()
    policy = ScreenSpaceErrorPolicy(min_triangles=min_triangles)
    policy.begin(view, terrain)
    cache = tile_cache.tile_cache_for(terrain)
    with cache.lock:
        cache.sync(terrain, view.exaggeration)
        select_flat(view, terrain, policy, cache, grown)
        want = grown.tree(cache, terrain, terrain.tile_size)
        got = seeded.tree(cache, terrain, terrain.tile_size)
    assert grown.stats["lod_rounds"] == int(want.level.max())  # one level a round
    for name in ("level", "slot", "parent", "wkey", "kids", "xy", "past", "pole"):
        assert np.array_equal(getattr(got, name), getattr(want, name)), name
    again = traverse(view, terrain, ScreenSpaceErrorPolicy(min_triangles=min_triangles), seeded)
    assert again.stats["lod_rounds"] == 0 and again.stats["lod_rows"] == got.n
    assert_same(first, again, "seeded")


def test_the_state_starts_afresh_with_the_tile_cache(globeview_terrain) -> None:
    """A new exaggeration (new tile facts) starts the tree from the roots again."""
    state = SelectionState()
    pose = (-71.3, 44.15, 9000.0, 0.0, -30.0)
    policy = lambda: ScreenSpaceErrorPolicy(min_triangles=True)  # noqa: E731
    traverse(make_view(*pose), globeview_terrain, policy(), state)
    again = traverse(make_view(*pose), globeview_terrain, policy(), state)
    assert again.stats["lod_rounds"] == 0
    other = traverse(make_view(*pose, exaggeration=2.0), globeview_terrain, policy(), state)
    assert other.stats["lod_cold"] == 1
    tile_cache.tile_cache_for(globeview_terrain).clear()
    cold = traverse(make_view(*pose, exaggeration=2.0), globeview_terrain, policy(), state)
    assert cold.stats["lod_cold"] == 1
    assert_same(other, cold, "cleared cache")


# -- tile facts -------------------------------------------------------------------------------
def test_cached_facts_equal_the_walks(globeview_terrain, monkeypatch) -> None:
    """Levels past the data and pole codes cached per tile equal what the level walk computes
    (`ScreenSpaceErrorPolicy._levels_past_data`, `pole_codes`), and `children_across` gives
    the children and facts `children` and `facts_of` give, level by level."""
    seen = []
    original = ScreenSpaceErrorPolicy._levels_past_data

    def spy(self, keys, has_finer):
        past = original(self, keys, has_finer)
        seen.append((keys.copy(), past.copy()))
        return past

    monkeypatch.setattr(ScreenSpaceErrorPolicy, "_levels_past_data", spy)
    terrain = globeview_terrain
    for pose in random_poses(40, seed=11):
        traverse(make_view(*pose), terrain, ScreenSpaceErrorPolicy(min_triangles=True))
    cache = tile_cache.tile_cache_for(terrain)
    assert seen and any(p.max() > 0 for _, p in seen)  # some tiles lie past the data
    for keys, past in seen:
        lv = cache.levels[int(keys[0, 0])]
        slots = lv.find((keys[:, 1] << 32) | keys[:, 2])
        assert (slots >= 0).all()
        assert np.array_equal(lv.past.take(slots), past)
        assert np.array_equal(lv.pole.take(slots), pole_codes(keys))
    # Children of tiles of three levels at once = level by level.
    parents = [(lv, np.flatnonzero(cache.levels[lv].child[: cache.levels[lv].n, 0] >= 0)[:5])
               for lv in (3, 6, 9) if lv in cache.levels]  # fmt: skip
    levels = np.concatenate([np.full(len(s), lv) for lv, s in parents])
    slots = np.concatenate([s for _, s in parents])
    cl, cs, pi, c, facts = cache.children_across(terrain, levels, slots, terrain.tile_size)
    for lv, s in parents:
        want = cache.children(terrain, lv, s, terrain.tile_size)
        got = cs[cl == lv + 1]
        assert np.array_equal(got, want)
        ref = cache.facts_of(lv + 1, want)
        for k, v in ref.items():
            mine = facts[k][:, cl == lv + 1] if k == "cols" else facts[k][cl == lv + 1]
            assert np.array_equal(mine, v), k
    assert np.array_equal(np.bincount(pi, minlength=len(slots)), np.full(len(slots), 4))
    assert set(c.tolist()) == {0, 1, 2, 3}


# -- the cut's budget search --------------------------------------------------------------------
#: Tile budgets under which canyon_run's frames at 1280x720 trade (the cheapest cut draws
#: more, the fewest-tiles cut not; tighter ones stop the walk: the plain walk, no cut).
TRADING_BUDGETS = (300, 500)


def _trading_trees(terrain) -> list[tuple[cheapest_cut.CutTree, int]]:
    """(the flat walk's tree, the budget) of canyon_run frames that trade under one of
    `TRADING_BUDGETS`."""
    trees = []
    original = cheapest_cut.cut_within_budget_flat

    def capture(tree, budget, memo):
        trees.append((tree, budget))
        return original(tree, budget, memo)

    sse.cut_within_budget_flat = capture
    try:
        for max_tiles in TRADING_BUDGETS:
            state = SelectionState()
            for window in flight_poses("canyon_run", 3, 6):
                for pose in window:
                    view = make_view(*pose, viewport=(1280, 720))
                    policy = ScreenSpaceErrorPolicy(max_tiles=max_tiles, min_triangles=True)
                    traverse(view, terrain, policy, state)
    finally:
        sse.cut_within_budget_flat = original
    ends = np.array([0.0, cheapest_cut.FEWEST_TILES])
    # Those that trade: the cheapest cut draws too many, the fewest-tiles cut not.
    return [
        (t, b)
        for t, b in trees
        if (lambda n: n[0] > b >= n[1])(cheapest_cut.cut_costs(t, ends, True)[1])
    ]


def test_tile_counts_never_grow_with_the_multiplier(globeview_terrain) -> None:
    """The property the vectorised search rests on: for every tree, the cut's tile count is
    non-increasing in the per-tile cost, over the powers of 8 and dense grids inside each
    bracket (the exact Lagrangian minimiser's property; the sums are exact)."""
    trees = _trading_trees(globeview_terrain)
    assert len(trees) >= 10
    rng = np.random.default_rng(2)
    ends = [0.0, *cheapest_cut._POWERS, cheapest_cut.FEWEST_TILES]
    lams = list(ends)
    for lo, hi in itertools.pairwise(ends):
        lams += list(lo + (hi - lo) * np.sort(rng.integers(1, 4096, 40)) / 4096)
    lams = np.sort(np.array(lams))
    for tree, _ in trees:
        _, tiles = cheapest_cut.cut_costs(tree, lams, True)
        assert np.all(np.diff(tiles) <= 0), tiles
        assert tiles[0] > tiles[-1]  # these views trade: the multiplier matters


def test_search_warm_start_and_fallback_agree_with_the_bisection(globeview_terrain) -> None:
    """On each trading tree: the vectorised search, the warm start from its own answer and
    the sequential fallback draw the cut the old bisection (`cut_within_budget` on the same
    tree, one `cut_costs` pass per step) draws."""
    trees = _trading_trees(globeview_terrain)
    assert len(trees) >= 10
    for tree, budget in trees:
        memo: dict = {}
        cut, how = cheapest_cut.cut_within_budget_flat(tree, budget, memo)
        assert how == "traded" and len(cut[0]) <= budget
        split, value, _ = cheapest_cut._bisect(tree, budget, cheapest_cut.cut_costs(
            tree, np.array([cheapest_cut.FEWEST_TILES]), False)[0][:, 0])  # fmt: skip
        ref = cheapest_cut.cut_of(tree, split)
        for a, b in zip(cut, ref, strict=True):
            assert np.array_equal(a, b)
        if "cut_multiplier" in memo:  # not the fewest-tiles cut
            assert memo["cut_multiplier"][0] == value
        # Warm: the same tree answers from the memo in the first pass.
        again, how = cheapest_cut.cut_within_budget_flat(tree, budget, memo)
        assert how == "traded"
        for a, b in zip(again, ref, strict=True):
            assert np.array_equal(a, b)


def test_a_non_monotone_pass_falls_back_to_the_bisection(globeview_terrain, monkeypatch) -> None:
    trees = _trading_trees(globeview_terrain)[:3]
    want = [cheapest_cut.cut_within_budget_flat(t, b, {})[0] for t, b in trees]
    calls = []
    real = cheapest_cut._bisect

    def spy(*a):
        calls.append(1)
        return real(*a)

    monkeypatch.setattr(cheapest_cut, "_first_fit", lambda *a: None)  # "counts grew"
    monkeypatch.setattr(cheapest_cut, "_bisect", spy)
    for (tree, budget), w in zip(trees, want, strict=True):
        got, how = cheapest_cut.cut_within_budget_flat(tree, budget, {})
        assert how == "traded"
        for a, b in zip(got, w, strict=True):
            assert np.array_equal(a, b)
    assert len(calls) == len(trees)
