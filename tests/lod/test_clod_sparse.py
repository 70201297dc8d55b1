"""quadtree-clod's fast paths agree with the plain algorithms they replace: the incremental,
sparse dependency closure (`mesh._close`) with a sweep over every node of every tile, and the
packed per-tile cache (`tile_data.ClodTiles`) with data built afresh, through eviction,
generations and frames larger than its capacity."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.plugins.builtin.clod.mesh import (
    _close,
    _node_levels,
    clod_frame,
    n_block_levels,
    tile_clod,
)
from globeview.plugins.builtin.clod.tile_data import ClodTiles


def dense_close(on: list[np.ndarray], enabled: np.ndarray) -> None:
    """The restricted-quadtree closure as a sweep over every block of every tile, finest
    level first (the provider's algorithm before it went sparse), in place."""
    t_n, size, _ = enabled.shape
    n = size - 1
    for j in range(len(on) - 1, -1, -1):
        hh = n >> (j + 1)
        s2 = 2 * hh
        nb = 1 << j
        blk = on[j]
        blk |= enabled[:, hh::s2, hh::s2]
        hm = enabled[:, 0::s2, hh::s2]
        blk |= hm[:, :-1, :] | hm[:, 1:, :]
        vm = enabled[:, hh::s2, 0::s2]
        blk |= vm[:, :, :-1] | vm[:, :, 1:]
        if j + 1 < len(on):
            blk |= on[j + 1].reshape(t_n, nb, 2, nb, 2).any(axis=(2, 4))
        enabled[:, hh::s2, hh::s2] |= blk
        corners = enabled[:, 0::s2, 0::s2]
        corners[:, :-1, :-1] |= blk
        corners[:, :-1, 1:] |= blk
        corners[:, 1:, :-1] |= blk
        corners[:, 1:, 1:] |= blk


def test_node_levels_name_each_node_once() -> None:
    size = 17
    lev = _node_levels(size)
    n = size - 1
    assert lev[0, 0] == lev[0, n] == lev[n, 0] == lev[n, n] == -1
    for j in range(n_block_levels(size)):
        hh = n >> (j + 1)
        s2 = 2 * hh
        assert (lev[hh::s2, hh::s2] == j).all()  # centres
        assert (lev[0::s2, hh::s2] == j).all()  # horizontal edge midpoints
        assert (lev[hh::s2, 0::s2] == j).all()  # vertical edge midpoints
    assert np.count_nonzero(lev == -1) == 4


@pytest.mark.parametrize("seed", range(12))
def test_sparse_closure_equals_the_full_sweep(seed: int) -> None:
    """Random refined blocks and enabled nodes on a few 33 x 33 tiles: closing them, then
    adding more nodes and closing only the additions, gives the full sweep's result."""
    rng = np.random.default_rng(seed)
    size, t_n = 33, 4
    n_levels = n_block_levels(size)
    lev = _node_levels(size).reshape(-1)
    on = [np.zeros((t_n, 1 << j, 1 << j), dtype=bool) for j in range(n_levels)]
    enabled = np.zeros((t_n, size, size), dtype=bool)
    on[0][:] = True
    for j in range(1, n_levels):  # refined blocks with refined parents (the update's shape)
        parent = np.repeat(np.repeat(on[j - 1], 2, axis=1), 2, axis=2)
        on[j] |= parent & (rng.random(parent.shape) < 0.3)
    density = rng.choice([0.002, 0.01, 0.05])
    enabled |= rng.random(enabled.shape) < density
    ref_on, ref_en = [o.copy() for o in on], enabled.copy()
    dense_close(ref_on, ref_en)

    nodes = np.flatnonzero(enabled)
    blocks = [np.flatnonzero(o) for o in on]
    added: list[list[np.ndarray]] = [[] for _ in range(n_levels)]
    en_f = enabled.reshape(-1)
    _close(on, en_f, lev, size, nodes, blocks, added)
    assert all((a == b).all() for a, b in zip(on, ref_on, strict=True))
    assert (enabled == ref_en).all()
    for j in range(n_levels):  # what it reports as added is what it refined
        got = np.concatenate([np.empty(0, np.int64), *added[j]])
        assert on[j].reshape(-1)[got].all()

    # Incremental: a few more nodes (as the tile-edge exchange adds), closed from them only.
    more = rng.choice(t_n * size * size, size=int(rng.integers(1, 20)), replace=False)
    ref_en.reshape(-1)[more] = True
    dense_close(ref_on, ref_en)
    fresh = more[~en_f[more]]
    en_f[fresh] = True
    _close(on, en_f, lev, size, fresh, [np.empty(0, np.int64)] * n_levels, added)
    assert all((a == b).all() for a, b in zip(on, ref_on, strict=True))
    assert (enabled == ref_en).all()


def _synthetic_tile(key: tuple[int, int, int], size: int = 17):
    level, x, y = key
    rng = np.random.default_rng(level * 1_000_003 + x * 1009 + y)
    return tile_clod(key, rng.normal(0.0, 300.0, (size, size)).astype(np.float32), 1.0)


def _synthetic_tiles(keys):
    return [_synthetic_tile(k) for k in keys]


def test_tiles_built_together_equal_tiles_built_alone() -> None:
    """`tile_clods` (the batch the provider builds its misses with) gives each tile's data
    bit for bit as `tile_clod` alone, with and without a displacement."""
    from globeview.plugins.builtin.clod.mesh import tile_clods

    keys = [(6, 20, 10), (6, 21, 10), (9, 300, 80), (3, 0, 0)]
    rng = np.random.default_rng(5)
    heights = [rng.normal(0.0, 500.0, (17, 17)).astype(np.float32) for _ in keys]

    def squash(p: np.ndarray) -> np.ndarray:  # not affine: bends tiles
        r = np.linalg.norm(p, axis=-1, keepdims=True)
        return p * (1.0 - 1e-4 * np.tanh(p[..., :1] / 1e6)) * (r / r)

    for displace in (None, squash):
        batch = tile_clods(keys, heights, 2.0, displace)
        for k, h, got in zip(keys, heights, batch, strict=True):
            one = tile_clod(k, h, 2.0, displace)
            for name in ("origin", "basis", "pos", "err"):
                assert np.array_equal(getattr(got, name), getattr(one, name)), name
            for a, b in zip(got.emax + got.radius, one.emax + one.radius, strict=True):
                assert np.array_equal(a, b)


def test_packed_cache_returns_the_data_it_was_given() -> None:
    built: list[tuple] = []

    def build(keys):
        built.extend(keys)
        return [_synthetic_tile(k) for k in keys]

    cache = ClodTiles(capacity=8)
    keys_a = np.array([[6, x, 20] for x in range(6)])
    s_a = cache.slots(keys_a, 17, "g1", build)
    assert len(set(s_a.tolist())) == 6 and len(built) == 6
    again = cache.slots(keys_a[::-1], 17, "g1", build)
    assert (again == s_a[::-1]).all() and len(built) == 6  # all hits
    # Another generation (say, another exaggeration) of the same tiles is other data.
    s_b = cache.slots(keys_a[:2], 17, "g2", build)
    assert len(built) == 8 and not set(s_b.tolist()) & set(s_a.tolist())
    # Beyond the capacity: the least recently used go (keys_a[2:] were used before g2).
    keys_c = np.array([[6, x, 21] for x in range(4)])
    s_c = cache.slots(keys_c, 17, "g1", build)
    assert len(built) == 12 and len(cache) == 8
    for keys, slots in ((keys_c, s_c), (keys_a[:2], s_b)):
        for k, s in zip(keys.tolist(), slots.tolist(), strict=True):
            ref = _synthetic_tile(tuple(k))
            gen_slot = s
            assert np.array_equal(cache.pos[gen_slot], ref.pos)
            assert np.array_equal(cache.err[gen_slot], ref.err)
            assert all(np.array_equal(cache.emax[j][gen_slot], ref.emax[j]) for j in range(4))
    # A frame needing more tiles than the capacity still gets them all, distinct.
    keys_d = np.array([[7, x, 40] for x in range(11)])
    s_d = cache.slots(keys_d, 17, "g3", build)
    assert len(set(s_d.tolist())) == 11
    for k, s in zip(keys_d.tolist(), s_d.tolist(), strict=True):
        assert np.array_equal(cache.pos[s], _synthetic_tile(tuple(k)).pos)
    # Generations with no tile left are forgotten (a displacement animating makes one a
    # frame): the cache's bookkeeping stays bounded.
    for g in range(20):
        cache.slots(keys_d[:3], 17, ("anim", g), build)
    assert len(cache._gens) <= 12


def test_frame_from_the_packed_cache_is_deterministic_in_slot_order() -> None:
    """The same tiles in other slots (another fill order) give the same frame."""
    from globeview.app.testing import make_view

    keys = np.array([[9, 2 * 512 - 1 - x, 150] for x in range(3)] + [[9, 1022, 151]])
    view = make_view(-179.5, 37.3, 30_000.0, 0.0, -60.0, viewport=(640, 360))
    frames = []
    for order in (slice(None), slice(None, None, -1)):
        cache = ClodTiles(16)
        cache.slots(keys[order], 17, "g", _synthetic_tiles)
        slots = cache.slots(keys, 17, "g", _synthetic_tiles)
        eye, planes = view.in_local_frames(cache.origin[slots], cache.basis[slots])
        frames.append(clod_frame(keys, cache, slots, eye, planes, 2.0 / view.sse_factor, 1.0))
    a, b = frames
    assert (a.enabled == b.enabled).all() and np.array_equal(a.error_px, b.error_px)
    assert all((x == y).all() for x, y in zip(a.on, b.on, strict=True))
    assert a.enabled.sum() > 4 * 4  # more than the corners


def test_three_vector_norms_are_numpys_bit_for_bit() -> None:
    """The 3-vector norms of the LOD fast paths (`culling.norm3`, clod's `_norm`) give
    np.linalg.norm's floats exactly, on contiguous and strided inputs of any leading shape."""
    from globeview.lod.culling import norm3
    from globeview.plugins.builtin.clod.mesh import _norm

    rng = np.random.default_rng(11)
    v = rng.normal(size=(40, 33, 3)) * 10.0 ** rng.uniform(-3, 7, (40, 33, 1))
    v[0, 0] = 0.0
    v[0, 1] = [-0.0, 1e-150, 1e150]
    for x in (v, v[::3, 1::2], v.reshape(-1, 3), v.transpose(1, 0, 2)):
        want = np.linalg.norm(x, axis=-1)
        assert np.array_equal(norm3(x), want)
        assert np.array_equal(_norm(x), want)


def test_grid_positions_are_lonlat_to_ecef_bit_for_bit() -> None:
    """clod's node positions with per-row / per-column trigonometry equal `lonlat_to_ecef`
    of the meshgrid, on tiles of many levels (poles and the antimeridian included)."""
    from globeview.geodesy import lonlat_to_ecef
    from globeview.plugins.api import node_lonlat, tile_bounds_arrays
    from globeview.plugins.builtin.clod.mesh import _grid_ecef

    rng = np.random.default_rng(2)
    tiles = [(0, 0, 0), (0, 1, 0), (5, 63, 31), (5, 0, 0)]
    for _ in range(60):
        lv = int(rng.integers(0, 22))
        tiles.append((lv, int(rng.integers(0, 2 << lv)), int(rng.integers(0, 1 << lv))))
    for level, x, y in tiles:
        w, s, e, n = (float(v) for v in tile_bounds_arrays(level, x, y))
        lon, lat = node_lonlat((w, s, e, n), 33)
        h = rng.normal(0.0, 2000.0, (33, 33))
        want = np.asarray(lonlat_to_ecef(*np.meshgrid(lon, lat), h))
        assert np.array_equal(_grid_ecef(lon, lat, h), want), (level, x, y)
