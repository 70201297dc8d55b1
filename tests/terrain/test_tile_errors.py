"""The fast tile-statistics kernels (globeview.terrain.ingest.tile_errors) against the
straightforward gather-based ones they replace: bit-identical results on random grids with
NaN, -0 and inf."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from globeview.terrain.ingest import tile_errors
from globeview.terrain.ingest.tile_errors import (
    PRUNE_BLOCK,
    block_node_max,
    block_node_min,
    cell_max,
    cell_min,
    error_window,
    lerp_rows,
    pruned_error_tiles,
    reduce_cells,
    stride_deltas,
    tile_min_max,
    transposed_nodes,
    upsample_nodes,
    upsample_window,
    upsampled_error_tiles,
)

STRIDES = (2, 4, 8, 16, 32, 64)
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _bits(a: np.ndarray) -> np.ndarray:
    """Bit patterns (NaN payloads folded to one value): equality means the same floats."""
    a = np.asarray(a)
    b = a.view(np.int64 if a.dtype == np.float64 else np.int32).copy()
    b[np.isnan(a)] = -1
    return b


def _assert_identical(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape and a.dtype == b.dtype
    np.testing.assert_array_equal(_bits(a), _bits(b))


def _grid(rng: np.random.Generator, shape: tuple[int, int], nan: float, inf: bool) -> np.ndarray:
    a = (rng.normal(size=shape) * 500.0).astype(np.float32)
    a[rng.random(shape) < nan] = np.nan
    a[rng.random(shape) < 0.05] = -0.0
    a[rng.random(shape) < 0.05] = 0.0
    if inf:
        a[rng.random(shape) < 0.05] = np.inf
    return a


def _reference_errors(coarse, fine, f, r_off, c_off, cell_r0, cell_c0, span, block, owned):
    """Today's ingest loop: gather upsampling, cell maxima, ownership mask, reduceat."""
    h, w = fine.shape
    up = upsample_nodes(coarse, f, r_off + np.arange(h), c_off + np.arange(w))
    np.subtract(up, fine.astype(np.float64), out=up)
    np.abs(up, out=up)
    cells = cell_max(up)
    if owned is not None:
        cells[~np.repeat(np.repeat(owned, block, 0), block, 1)] = np.nan
    return reduce_cells(
        cells, (cell_r0 + np.arange(h - 1)) // span, (cell_c0 + np.arange(w - 1)) // span
    )


def _reference_stats(arr: np.ndarray, s_n: int):
    """Today's ingest ``_tile_stats``: hmin, hmax and the running stride deltas."""
    kty, ktx = (arr.shape[0] - 1) // s_n, (arr.shape[1] - 1) // s_n

    def per_tile(cells, op):
        return op.reduce(op.reduce(cells.reshape(kty, s_n, ktx, s_n), axis=3), axis=1)

    rows, cols = np.arange(arr.shape[0]), np.arange(arr.shape[1])
    delta = np.zeros((kty, ktx))
    deltas = np.zeros((kty, ktx, len(STRIDES)))
    for i, s in enumerate(STRIDES):
        if s <= s_n:
            up = upsample_nodes(arr[::s, ::s], s, rows, cols, np.float32)
            np.subtract(up, arr, out=up)
            np.abs(up, out=up)
            delta = np.maximum(delta, np.nan_to_num(per_tile(cell_max(up), np.fmax), nan=0.0))
        deltas[:, :, i] = delta
    return per_tile(cell_min(arr), np.fmin), per_tile(cell_max(arr), np.fmax), deltas


@pytest.mark.slow
@SETTINGS
@given(
    seed=st.integers(0, 2**32 - 1),
    f=st.sampled_from([2, 3, 4, 8, 16, 64]),
    h=st.integers(1, 40),
    w=st.integers(1, 40),
    dtype=st.sampled_from([np.float32, np.float64]),
    inf=st.booleans(),
)
def test_upsample_window_is_upsample_nodes(seed, f, h, w, dtype, inf) -> None:
    rng = np.random.default_rng(seed)
    r_off, c_off = int(rng.integers(0, 3 * f)), int(rng.integers(0, 3 * f))
    coarse = _grid(rng, ((r_off + h - 1) // f + 2, (c_off + w - 1) // f + 2), 0.2, inf)
    with np.errstate(invalid="ignore"):  # inf * 0 on purpose
        ref = upsample_nodes(coarse, f, r_off + np.arange(h), c_off + np.arange(w), dtype)
        got = upsample_window(coarse, f, r_off, c_off, h, w, dtype)
    _assert_identical(got, ref)


@pytest.mark.slow
@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), f=st.sampled_from([2, 4, 32, 256]), n=st.integers(1, 90))
def test_lerp_rows_zero_sign_free_differs_only_in_zero_signs(seed, f, n) -> None:
    """The einsum path may give +0 for -0; |value - y| is then the same for every y."""
    rng = np.random.default_rng(seed)
    off = int(rng.integers(0, 2 * f))
    a = _grid(rng, ((off + n - 1) // f + 2, 7), 0.2, False).astype(np.float64)
    exact = lerp_rows(a, f, off, np.empty((n, 7)), no_inf=True)
    fast = lerp_rows(a, f, off, np.empty((n, 7)), True, True, np.empty((n, 7)))
    for y in (0.0, -0.0, 1.5):
        _assert_identical(np.abs(fast - y), np.abs(exact - y))
    nonzero = exact != 0.0
    _assert_identical(fast[nonzero], exact[nonzero])


@pytest.mark.slow
@SETTINGS
@given(
    seed=st.integers(0, 2**32 - 1),
    f=st.sampled_from([2, 4, 8, 64, 1024]),
    block=st.sampled_from([1, 2, 4, 8]),
    m=st.integers(1, 6),
    n=st.integers(1, 6),
    tiles=st.integers(1, 3),
    masked=st.booleans(),
    inf=st.booleans(),
    strip=st.integers(1, 40),
)
def test_upsampled_error_tiles_is_the_reference(
    seed, f, block, m, n, tiles, masked, inf, strip
) -> None:
    rng = np.random.default_rng(seed)
    h, w = m * block + 1, n * block + 1
    r_off, c_off = int(rng.integers(0, f)), int(rng.integers(0, f))
    coarse = _grid(rng, ((r_off + h - 2) // f + 2, (c_off + w - 2) // f + 2), 0.2, inf)
    fine = _grid(rng, (h, w), 0.3, False)
    span = block * tiles
    cell_r0, cell_c0 = block * int(rng.integers(0, 7)), block * int(rng.integers(0, 7))
    owned = rng.random((m, n)) < 0.6 if masked else None
    with np.errstate(invalid="ignore"):  # inf * 0 and inf - inf on purpose
        ref = _reference_errors(coarse, fine, f, r_off, c_off, cell_r0, cell_c0, span, block, owned)
        got = upsampled_error_tiles(
            coarse,
            transposed_nodes(fine),
            f,
            r_off,
            c_off,
            cell_r0,
            cell_c0,
            span,
            block,
            owned,
            strip_cols=strip,
        )
    np.testing.assert_array_equal(got[0], ref[0])
    np.testing.assert_array_equal(got[1], ref[1])
    _assert_identical(got[2], ref[2])


def test_upsampled_error_tiles_known_value() -> None:
    """A coarse plane at 0 m against fine nodes with one 7 m spike: the spike's tile gets 7,
    its neighbour across the shared edge too (closed tiles), the far tile 0."""
    coarse = np.zeros((2, 4), dtype=np.float32)
    fine = np.zeros((5, 13), dtype=np.float32)
    fine[2, 4] = -7.0
    rv, cv, red = upsampled_error_tiles(coarse, transposed_nodes(fine), 4, 0, 0, 0, 0, 4, 4)
    assert rv.tolist() == [0] and cv.tolist() == [0, 1, 2]
    assert red.tolist() == [[7.0, 7.0, 0.0]]


def test_upsampled_error_tiles_all_nan_and_misaligned() -> None:
    coarse = np.full((3, 3), np.nan, dtype=np.float32)
    fine = np.ones((9, 9), dtype=np.float32)
    _, _, red = upsampled_error_tiles(coarse, transposed_nodes(fine), 4, 0, 0, 0, 0, 8, 4)
    assert np.isnan(red).all()
    with pytest.raises(
        ValueError, match="whole blocks"
    ):  # tiles of 6 cells are not whole blocks of 4
        upsampled_error_tiles(coarse, transposed_nodes(fine), 4, 0, 0, 0, 0, 6, 4)
    with pytest.raises(ValueError, match="whole blocks"):  # 8 cells do not split into blocks of 3
        upsampled_error_tiles(coarse, transposed_nodes(fine), 4, 0, 0, 0, 0, 6, 3)


def _terrain_case(
    rng: np.random.Generator, f: int, block: int, m: int, n: int, aligned: bool
) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(coarse, fine, r_off, c_off): a wavy tilted surface (metres) at the coarse nodes and,
    with noise and a few spikes (the tiles' maxima), at the fine nodes, so that most blocks
    can be skipped; offsets whole blocks (``aligned``) or anything."""
    h, w = m * block + 1, n * block + 1
    pb = PRUNE_BLOCK
    if aligned and f % pb == 0:
        r_off, c_off = pb * int(rng.integers(0, f // pb)), pb * int(rng.integers(0, f // pb))
    else:
        r_off, c_off = int(rng.integers(0, f)), int(rng.integers(0, f))
    ax, ay, amp = rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(0.0, 40.0)

    def surface(y: np.ndarray, x: np.ndarray) -> np.ndarray:
        return 1500.0 + ay * y[:, None] + ax * x[None, :] + amp * np.sin(x[None, :] / 37.0)

    rc = (r_off + h - 2) // f + 2, (c_off + w - 2) // f + 2
    coarse = surface(np.arange(rc[0]) * f, np.arange(rc[1]) * f).astype(np.float32)
    fine = surface(r_off + np.arange(h), c_off + np.arange(w)) + rng.normal(0.0, 0.3, (h, w))
    spikes = rng.integers(0, fine.size, size=3)
    fine.flat[spikes] += rng.uniform(-300.0, 300.0, size=3)
    return coarse, fine.astype(np.float32), r_off, c_off


@pytest.mark.slow
@SETTINGS
@given(
    seed=st.integers(0, 2**32 - 1),
    f=st.sampled_from([2, 8, 16, 32, 64, 256, 24]),
    block=st.sampled_from([8, 16, 32]),
    m=st.integers(1, 8),
    n=st.integers(1, 8),
    tiles=st.integers(1, 3),
    masked=st.booleans(),
    aligned=st.booleans(),
    holes=st.sampled_from(["none", "coarse", "fine", "both"]),
    zeros=st.booleans(),
)
def test_pruned_error_tiles_are_the_full_pass(
    seed, f, block, m, n, tiles, masked, aligned, holes, zeros
) -> None:
    """Branch and bound gives the strip pass's floats, bit for bit: with NaN coarse nodes
    (data edges: P finite only along cell edges) and fine NaN, zeros of both signs, ownership
    masks, tiles spanning several windows' worth of blocks, and factors/offsets where it does
    not apply (f not a multiple of the block, offsets inside a block: the full pass)."""
    rng = np.random.default_rng(seed)
    coarse, fine, r_off, c_off = _terrain_case(rng, f, block, m, n, aligned)
    if holes in ("coarse", "both"):
        coarse[rng.random(coarse.shape) < 0.25] = np.nan
    if holes in ("fine", "both"):
        fine[rng.random(fine.shape) < 0.2] = np.nan
        fine[: block // 2 + 1, :] = np.nan
    if zeros:
        coarse[rng.random(coarse.shape) < 0.2] = rng.choice(np.array([0.0, -0.0], np.float32))
        fine[rng.random(fine.shape) < 0.2] = rng.choice(np.array([0.0, -0.0], np.float32))
    span = block * tiles
    cell_r0, cell_c0 = block * int(rng.integers(0, 7)), block * int(rng.integers(0, 7))
    owned = rng.random((m, n)) < 0.6 if masked else None
    args = (f, r_off, c_off, cell_r0, cell_c0, span, block, owned)
    ref = upsampled_error_tiles(coarse, transposed_nodes(fine), *args)
    got = pruned_error_tiles(coarse, error_window(fine), *args)
    np.testing.assert_array_equal(got[0], ref[0])
    np.testing.assert_array_equal(got[1], ref[1])
    _assert_identical(got[2], ref[2])


def test_pruned_error_tiles_skip_what_cannot_be_the_maximum(monkeypatch) -> None:
    """On terrain-like data whose tile maxima show at a block corner (a 200 m spike on one
    of a tile's corner nodes), the pruned pass computes a few blocks exactly (never the full
    pass) and still finds every tile's maximum; an infinite height turns pruning off (no
    rounding margin can be derived), with the same result."""
    rng = np.random.default_rng(7)
    f, block, m, n = 64, 32, 16, 16
    coarse, fine, r_off, c_off = _terrain_case(rng, f, block, m, n, aligned=True)
    fine[8 * 5, 8 * 9] += 200.0
    computed: list[int] = []
    gathered = tile_errors._gathered_block_max

    def counting(*a):  # type: ignore[no-untyped-def]
        computed.append(a[5].size)
        return gathered(*a)

    def no_full_pass(*a, **k):  # type: ignore[no-untyped-def]
        raise AssertionError("the full pass ran")

    args = (f, r_off, c_off, 0, 0, f * 32, block, None)
    ref = upsampled_error_tiles(coarse, transposed_nodes(fine), *args)
    with monkeypatch.context() as mp:
        mp.setattr(tile_errors, "_gathered_block_max", counting)
        mp.setattr(tile_errors, "upsampled_error_tiles", no_full_pass)
        got = pruned_error_tiles(coarse, error_window(fine), *args)
    _assert_identical(got[2], ref[2])
    blocks = (m * block // PRUNE_BLOCK) * (n * block // PRUNE_BLOCK)
    assert sum(computed) < 0.05 * blocks
    fine[3, 5] = np.inf
    with np.errstate(invalid="ignore"):
        ref = upsampled_error_tiles(coarse, transposed_nodes(fine), *args)
        _assert_identical(pruned_error_tiles(coarse, error_window(fine), *args)[2], ref[2])


@pytest.mark.slow
@SETTINGS
@given(
    seed=st.integers(0, 2**32 - 1),
    b=st.sampled_from([1, 2, 4, 16]),
    m=st.integers(1, 5),
    n=st.integers(1, 5),
    nan=st.sampled_from([0.0, 0.5, 0.95, 1.0]),
)
def test_block_node_extrema_are_reduced_cell_extrema(seed, b, m, n, nan) -> None:
    """Equal up to the sign of a zero extremum (tile_min_max handles that case)."""
    rng = np.random.default_rng(seed)
    d = np.abs(_grid(rng, (m * b + 1, n * b + 1), nan, False))  # no -0: bit for bit

    def per_block(cells, op):
        return op.reduce(op.reduce(cells.reshape(m, b, n, b), axis=3), axis=1)

    _assert_identical(block_node_max(d, b), per_block(cell_max(d), np.fmax))
    _assert_identical(block_node_min(d, b), per_block(cell_min(d), np.fmin))
    d = _grid(rng, (m * b + 1, n * b + 1), nan, False) * np.float32(-1.0)
    np.testing.assert_array_equal(block_node_max(d, b), per_block(cell_max(d), np.fmax))
    np.testing.assert_array_equal(block_node_min(d, b), per_block(cell_min(d), np.fmin))


@pytest.mark.slow
@SETTINGS
@given(
    seed=st.integers(0, 2**32 - 1),
    tile_n=st.integers(1, 6),
    kty=st.integers(1, 3),
    ktx=st.integers(1, 3),
    nan=st.sampled_from([0.0, 0.1, 0.6]),
    zeros=st.booleans(),
)
def test_stride_stats_are_the_ingest_loop(seed, tile_n, kty, ktx, nan, zeros) -> None:
    s_n = 1 << tile_n
    rng = np.random.default_rng(seed)
    arr = _grid(rng, (kty * s_n + 1, ktx * s_n + 1), nan, False)
    arr[: s_n // 2 + 1, : s_n + 1] = np.nan  # a tile with (almost) no data
    if zeros:  # tiles whose extremum is a zero of either sign
        arr[-(s_n // 2) :, -(s_n // 2) :] = rng.choice(np.array([0.0, -0.0], np.float32))
    hmin, hmax, deltas = _reference_stats(arr, s_n)
    lo, hi = tile_min_max(arr, s_n)
    _assert_identical(lo, hmin)
    _assert_identical(hi, hmax)
    _assert_identical(stride_deltas(arr, s_n, STRIDES), deltas)


def _srtm_window(rows: int, cols: int) -> np.ndarray:
    """Real heights (metres, float32): the north-west corner of SRTM tile N44W072."""
    import rasterio

    from globeview.terrain.ingest import tile_errors as te

    root = Path(te.__file__).resolve().parents[3]
    with rasterio.open(root / "data" / "N44W072.hgt") as ds:
        return ds.read(1, window=((0, rows), (0, cols))).astype(np.float32)


@pytest.mark.parametrize("case", ["full", "edges", "corner", "node", "closing", "none"])
def test_tile_stats_on_the_data_box_are_the_whole_window(case: str) -> None:
    """tile_stats runs the per-tile passes on the box of tiles that hold data: on real
    heights with the NaN a chunk at a DEM's edge has (data from a column / row on, a corner
    block, one finite node on a tile corner (in four tiles), only the closing row, none),
    hmin, hmax and the stride deltas are those of the whole window, bit for bit."""
    s_n = 64
    arr = _srtm_window(8 * s_n + 1, 12 * s_n + 1)
    keep = np.zeros(arr.shape, dtype=bool)
    if case == "full":
        keep[:] = True
    elif case == "edges":
        keep[100:, 150:] = True
    elif case == "corner":
        keep[-70:, -70:] = True
    elif case == "node":
        keep[2 * s_n, 3 * s_n] = True
    elif case == "closing":
        keep[-1, :200] = True
    arr[~keep] = np.nan
    hmin, hmax, delta = tile_errors.tile_stats(arr, s_n, STRIDES)
    lo, hi = tile_min_max(arr, s_n)
    _assert_identical(hmin, lo)
    _assert_identical(hmax, hi)
    _assert_identical(delta, stride_deltas(arr, s_n, STRIDES))
    if case == "node":
        assert np.isfinite(hmin).sum() == 4


def test_data_blocks_is_the_box_of_closed_blocks_with_data() -> None:
    """A finite node on a block edge belongs to both closed blocks it bounds."""
    a = np.full((4 * 8 + 1, 5 * 8 + 1), np.nan, dtype=np.float32)
    assert tile_errors.data_blocks(a, 8) is None
    a[8, 17] = 1.0  # on the edge of block rows 0/1, inside block column 2
    assert tile_errors.data_blocks(a, 8) == (slice(0, 2), slice(2, 3))
    a[32, 0] = 2.0  # the closing row's first node: block row 3 only, block column 0
    assert tile_errors.data_blocks(a, 8) == (slice(0, 4), slice(0, 3))
    assert tile_errors.data_blocks(a[:32, :40], 8) == (slice(0, 2), slice(2, 3))  # no closing
