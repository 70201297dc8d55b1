"""Stride errors of tiles finer than a layer's data (issue #17 item 2): measured on each tile's
own part of its ancestor (`globeview.terrain.compose.drawn_error`), not copied from the ancestor's
whole tile, and still upper bounds on the stride-s surface (bilinear between the drawn nodes,
the convention of every stored error) against the data's surface (the ancestor's bilinear
surface), brute force."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.terrain.compose.drawn_error import N_STRIDES, AncestorErrors
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.interpolate import upsample_subtile
from globeview.terrain.quadtree import key_for_lonlat

SIZE = 65


@pytest.fixture(scope="module")
def stack(globeview_terrain: TerrainStack) -> TerrainStack:
    """The embedded terrain: the run's one stack (`globeview_terrain`, tests/conftest.py), not
    one of the module's own (each stack measures its layers' blend masks again: up to ~7 CPU-s)."""
    return globeview_terrain


def bilinear_at(h: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bilinear surface of node grid ``h`` (float64) at fractional (rows, cols)."""
    n = h.shape[0] - 1
    r0 = np.minimum(np.floor(rows).astype(int), n - 1)
    c0 = np.minimum(np.floor(cols).astype(int), n - 1)
    fr, fc = rows - r0, cols - c0
    top = h[r0, c0] * (1 - fc) + h[r0, c0 + 1] * fc
    bot = h[r0 + 1, c0] * (1 - fc) + h[r0 + 1, c0 + 1] * fc
    return top * (1 - fr) + bot * fr


def drawn_at(h: np.ndarray, s: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """The stride-``s`` surface (bilinear between every s-th node of ``h``) at (rows, cols) in
    node units, brute force."""
    m = (h.shape[0] - 1) // s
    i0 = np.minimum(np.floor(rows / s).astype(int), m - 1)
    j0 = np.minimum(np.floor(cols / s).astype(int), m - 1)
    v, u = rows / s - i0, cols / s - j0
    r, c = i0 * s, j0 * s
    top = h[r, c] * (1 - u) + h[r, c + s] * u
    bot = h[r + s, c] * (1 - u) + h[r + s, c + s] * u
    return top * (1 - v) + bot * v


def sample_points(rng: np.random.Generator, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """Random points of a tile plus every node cell's centre and the nodes, in node units."""
    rows = rng.uniform(0, SIZE - 1, n)
    cols = rng.uniform(0, SIZE - 1, n)
    cr, cc = np.meshgrid(np.arange(SIZE - 1) + 0.5, np.arange(SIZE - 1) + 0.5, indexing="ij")
    nr, nc = np.meshgrid(np.arange(SIZE), np.arange(SIZE), indexing="ij")
    return (
        np.concatenate([rows, cr.ravel(), nr.ravel().astype(float)]),
        np.concatenate([cols, cc.ravel(), nc.ravel().astype(float)]),
    )


def drawn_error(anc: np.ndarray, f: int, dx: int, dy: int, h: np.ndarray, rng) -> np.ndarray:
    """(N_STRIDES,) brute-force max |drawn - ancestor's bilinear surface| over a virtual tile
    (offset (dx, dy) tiles ``f`` levels below ``anc``) drawn from its nodes ``h``."""
    rows, cols = sample_points(rng)
    ref = bilinear_at(anc, (dy * (SIZE - 1) + rows) / 2**f, (dx * (SIZE - 1) + cols) / 2**f)
    return np.array([np.abs(drawn_at(h, 2**k, rows, cols) - ref).max() for k in range(N_STRIDES)])


def test_bound_holds_for_random_surfaces() -> None:
    """On random rugged ancestors, every virtual tile's bound (1 to 8 levels below) is at
    least the drawn error (brute force at random points, cell centres and nodes), and exact
    (the max sits at an ancestor node, which the nodes sampled include)."""
    rng = np.random.default_rng(17)
    for _ in range(16):
        anc = np.cumsum(np.cumsum(rng.normal(0, 40, (SIZE, SIZE)), axis=0), axis=1)
        anc = anc.astype(np.float32).astype(np.float64)
        tables = AncestorErrors(anc)
        f = int(rng.integers(1, 9))
        dx, dy = (int(v) for v in rng.integers(0, 2**f, 2))
        h = upsample_subtile(anc.astype(np.float32), f, dx, dy).astype(np.float64)
        bound = tables.bounds(f, np.array([dx]), np.array([dy]))[0]
        real = drawn_error(anc, f, dx, dy, h, rng)
        assert np.all(bound >= real - 1e-6 * np.abs(anc).max()), (f, bound, real)
        assert np.all(bound <= real + 1e-6 * np.abs(anc).max()), (f, bound, real)


def test_plane_is_drawn_exactly() -> None:
    """A plane is drawn exactly at every stride and depth: the bound is 0."""
    r, c = np.meshgrid(np.arange(SIZE), np.arange(SIZE), indexing="ij")
    tables = AncestorErrors(3.0 * r - 2.0 * c + 100.0)
    for f in (1, 3, 6, 9):
        q = np.arange(min(2**f, 8))
        np.testing.assert_allclose(tables.bounds(f, q, q), 0.0, atol=1e-9)


def test_nodata_is_not_measured() -> None:
    """Descendants touching a NaN node get NaN (the caller keeps its old bound there)."""
    anc = np.ones((SIZE, SIZE))
    anc[0, 0] = np.nan
    b = AncestorErrors(anc).bounds(2, np.array([0, 3]), np.array([0, 3]))
    assert np.isnan(b[0]).any() and np.all(b[1] == 0.0)


@pytest.mark.slow
def test_flat_vancouver_tile_is_no_longer_given_its_ancestors_error(stack) -> None:
    """Tile (8, 76, 56) lies below the Vancouver layer's finest level (7) in its border band,
    on nearly flat ground; its ancestor (7, 38, 28) is rugged (563.7 m at stride 2). The old
    ancestor-copied errors gave the tile 563.7 m at stride 4; measured on the tile they are a
    few metres, and never above the ancestor's errors (stride s here is s / 2 there)."""
    md = stack.metadata(8, np.array([76]), np.array([56]))
    anc = stack.metadata(7, np.array([38]), np.array([28]))
    assert anc.stride_error[0, 1] > 500.0  # the rugged ancestor
    assert md.stride_error[0, 2] < 5.0  # was 563.7 m
    assert np.all(md.stride_error[0, :2] < 1.0)
    assert np.all(md.stride_error[0, 1:] <= anc.stride_error[0, :-1])


@pytest.mark.slow
@pytest.mark.parametrize(
    ("lon", "lat", "layer"),
    [(-122.10, 42.94, 2), (-71.30, 44.27, 1), (-123.20, 49.25, 3)],
    ids=["crater-lake", "white-mountains", "vancouver"],
)
def test_stack_errors_bound_the_drawn_surface(stack, lon, lat, layer) -> None:
    """Random virtual tiles of the composed stack (1 to 4 levels below a layer's finest level
    at Crater Lake, the White Mountains and Vancouver): the metadata's stride errors bound the
    stride-s surface's departure from the composed surface at the finest level (bilinear
    between its nodes), brute force."""
    rng = np.random.default_rng(layer)
    lm = stack.visible_layers[layer].store.max_level
    for _ in range(6):
        f = int(rng.integers(1, 5))
        level = lm + f
        p_lon = lon + rng.uniform(-0.05, 0.05)
        p_lat = lat + rng.uniform(-0.05, 0.05)
        xs, ys = key_for_lonlat(level, p_lon, p_lat)
        x, y = int(xs), int(ys)
        ax, ay = x >> f, y >> f
        anc = stack.heights((lm, ax, ay)).astype(np.float64)
        h = stack.heights((level, x, y)).astype(np.float64)
        bound = stack.metadata(level, np.array([x]), np.array([y])).stride_error[0]
        real = drawn_error(anc, f, x - (ax << f), y - (ay << f), h, rng)
        assert np.all(bound >= real - 1e-2), ((level, x, y), bound, real)


@pytest.mark.slow
def test_ancestor_tables_are_kept_within_a_byte_budget_least_recently_used_first(
    monkeypatch,
) -> None:
    """More ancestors than the budget holds: the cache stays within it (plus the newest
    table) and keeps the most recent ones, instead of starting again from empty (which
    made every later call cold: ~100 ms instead of ~5 ms over 441 ancestors)."""
    import globeview.terrain.compose.metadata as metadata_mod
    from globeview.terrain.embedded import embedded_stores

    st = TerrainStack.from_stores(embedded_stores())
    level = 13
    x0, y0 = (int(v) for v in key_for_lonlat(level, -71.9, 44.4))
    xs, ys = np.meshgrid(np.arange(x0, x0 + 24, 2), np.arange(y0, y0 + 24, 2))
    x, y = xs.ravel(), ys.ravel()
    first = st.metadata(level, x, y)
    order = list(st._meta._virtual)
    tables = [t for t in st._meta._virtual.values() if t is not None]
    assert len(tables) > 8
    budget = 4 * max(t.nbytes for t in tables)
    monkeypatch.setattr(metadata_mod, "VIRTUAL_CACHE_BYTES", budget)
    st._changed()  # a new version: the cache starts empty under the small budget
    again = st.metadata(level, x, y)
    held = [t.nbytes for t in st._meta._virtual.values() if t is not None]
    assert 1 <= len(held) < len(tables)
    # The running count is what the tables hold, and within the budget.
    assert sum(held) == st._meta._virtual_bytes <= budget
    # The most recently used ancestors are the ones kept (the same order as the run
    # without a budget), and the figures do not depend on the cache.
    kept = list(st._meta._virtual)
    assert kept == order[-len(kept) :]
    np.testing.assert_array_equal(first.stride_error, again.stride_error)
