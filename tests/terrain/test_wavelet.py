"""Tests for the grid-registered dyadic wavelet approximation (globeview.terrain.ingest.wavelet)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from globeview.errors import GlobeviewError
from globeview.terrain.ingest.wavelet import (
    WaveletError,
    approximate_grid,
    approximate_window,
    extend_borders,
    kernel_halo,
    lowpass_kernel,
)

WAVELETS = ["bior2.2", "bior4.4"]


def _plane(rows: int, cols: int) -> np.ndarray:
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    return (1250.0 + 3.5 * x - 2.25 * y).astype(np.float32)


@pytest.mark.parametrize("wavelet", WAVELETS)
def test_kernel_is_symmetric_odd_unit_sum(wavelet: str) -> None:
    k = lowpass_kernel(wavelet)
    assert k.size % 2 == 1
    np.testing.assert_allclose(k, k[::-1], atol=1e-14)
    assert k.sum() == pytest.approx(1.0, abs=1e-14)
    assert k[0] != 0.0 and k[-1] != 0.0


def test_default_is_le_gall_5_3() -> None:
    np.testing.assert_allclose(lowpass_kernel(), np.array([-1, 2, 6, 2, -1]) / 8.0, atol=1e-14)


@pytest.mark.parametrize("wavelet", ["haar", "db2", "bior3.3", "morl", "nonsense"])
def test_rejected_wavelets(wavelet: str) -> None:
    with pytest.raises(ValueError, match=r"wavelet|low-pass") as info:
        lowpass_kernel(wavelet)
    assert isinstance(info.value, GlobeviewError)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("wavelet", WAVELETS)
def test_halo_even_and_covers_kernel(wavelet: str) -> None:
    h = kernel_halo(wavelet)
    assert h % 2 == 0
    assert h >= lowpass_kernel(wavelet).size // 2


@pytest.mark.parametrize("wavelet", WAVELETS)
@pytest.mark.parametrize("shape", [(9, 11), (33, 17), (3, 5), (1, 7)])
def test_plane_reproduced_at_coarse_nodes(wavelet: str, shape: tuple[int, int]) -> None:
    fine = _plane(*shape)
    coarse = approximate_grid(fine, wavelet)
    assert coarse.dtype == np.float32
    assert coarse.shape == ((shape[0] + 1) // 2, (shape[1] + 1) // 2)
    # Exact up to float32 rounding of the accumulated taps, borders included (odd mirror).
    np.testing.assert_allclose(coarse, fine[::2, ::2], rtol=1e-6, atol=0)


@pytest.mark.parametrize("wavelet", WAVELETS)
def test_constant_stays_constant(wavelet: str) -> None:
    fine = np.full((17, 25), 431.5, dtype=np.float32)
    coarse = approximate_grid(fine, wavelet)
    np.testing.assert_allclose(coarse, 431.5, rtol=0, atol=1e-4)


def test_smooths_a_spike() -> None:
    fine = np.zeros((9, 9), dtype=np.float32)
    fine[4, 4] = 64.0
    coarse = approximate_grid(fine)
    # Centre weight of the 2-D 5/3 low-pass is (6/8)^2.
    assert coarse[2, 2] == pytest.approx(64.0 * 0.75**2)
    assert coarse.sum() == pytest.approx(64.0 / 4.0)  # unit-sum kernel, decimation by 2x2


@pytest.mark.parametrize("wavelet", WAVELETS)
def test_windowed_equals_whole(wavelet: str) -> None:
    rng = np.random.default_rng(7)
    fine = rng.normal(500.0, 80.0, size=(129, 97)).astype(np.float32)
    whole = approximate_grid(fine, wavelet)
    halo = kernel_halo(wavelet)
    for r0, r1, c0, c1 in [(3, 20, 4, 9), (10, 11, 10, 11), (5, 60, 2, 46), (30, 63, 20, 45)]:
        rows = slice(2 * r0 - halo, 2 * (r1 - 1) + 1 + halo)
        cols = slice(2 * c0 - halo, 2 * (c1 - 1) + 1 + halo)
        padded = fine[rows, cols]
        win = approximate_window(padded, halo, wavelet)
        assert win.shape == (r1 - r0, c1 - c0)
        np.testing.assert_array_equal(win, whole[r0:r1, c0:c1])


@pytest.mark.parametrize("wavelet", WAVELETS)
def test_windowed_at_true_borders_with_extend_borders(wavelet: str) -> None:
    rng = np.random.default_rng(11)
    fine = rng.normal(0.0, 30.0, size=(41, 57)).astype(np.float32)
    fine[:6, :5] = np.nan
    whole = approximate_grid(fine, wavelet)
    halo = kernel_halo(wavelet)
    ext = extend_borders(fine, halo)
    # Window touching the top-left corner and one touching the bottom-right corner.
    for r0, r1, c0, c1 in [(0, 8, 0, 10), (12, 21, 20, 29)]:
        padded = ext[2 * r0 : 2 * (r1 - 1) + 1 + 2 * halo, 2 * c0 : 2 * (c1 - 1) + 1 + 2 * halo]
        win = approximate_window(padded, halo, wavelet)
        np.testing.assert_array_equal(win, whole[r0:r1, c0:c1])


def test_nan_does_not_spread() -> None:
    rng = np.random.default_rng(3)
    fine = rng.uniform(100.0, 200.0, size=(33, 33)).astype(np.float32)
    fine[10:17, 8:21] = np.nan
    coarse = approximate_grid(fine)
    # NaN exactly where the coarse node's own fine node is NaN.
    np.testing.assert_array_equal(np.isnan(coarse), np.isnan(fine[::2, ::2]))


def test_node_next_to_nan_is_weighted_mean_of_valid_neighbours() -> None:
    rng = np.random.default_rng(5)
    fine = rng.uniform(100.0, 200.0, size=(33, 33)).astype(np.float32)
    # Spikes next to the hole that a negative-lobe renormalisation would amplify.
    fine[9, :] = 1000.0
    fine[10:17, 8:21] = np.nan
    coarse = approximate_grid(fine)
    nan_fine = np.isnan(fine)
    for j, i in [(4, 6), (4, 4), (9, 3), (9, 11), (8, 11)]:
        win = fine[max(2 * j - 2, 0) : 2 * j + 3, max(2 * i - 2, 0) : 2 * i + 3]
        assert np.isnan(win).any(), "test node must touch the hole"
        valid = win[~np.isnan(win)]
        assert not np.isnan(coarse[j, i])
        assert valid.min() - 1e-3 <= coarse[j, i] <= valid.max() + 1e-3
    # Nodes whose support is all valid get the plain low-pass (compare with NaN-free input).
    filled = np.where(nan_fine, np.float32(150.0), fine)
    plain = approximate_grid(filled)
    np.testing.assert_array_equal(coarse[0:3, :], plain[0:3, :])


def test_nan_node_with_valid_constant_neighbourhood() -> None:
    fine = np.full((11, 11), 42.0, dtype=np.float32)
    fine[3:8, 3:8] = np.nan
    coarse = approximate_grid(fine)
    valid = ~np.isnan(coarse)
    np.testing.assert_allclose(coarse[valid], 42.0, atol=1e-4)


@pytest.mark.parametrize("shape", [(8, 9), (9, 8), (10, 10), (0, 3)])
def test_even_sides_rejected(shape: tuple[int, int]) -> None:
    with pytest.raises(WaveletError, match="odd sides"):
        approximate_grid(np.zeros(shape, dtype=np.float32))


def test_bad_dimensions_and_halo_rejected() -> None:
    with pytest.raises(WaveletError, match="2-D"):
        approximate_grid(np.zeros(9, dtype=np.float32))
    with pytest.raises(WaveletError, match="halo"):
        approximate_window(np.zeros((21, 21), dtype=np.float32), 1)
    with pytest.raises(WaveletError, match="halo"):
        approximate_window(np.zeros((21, 21), dtype=np.float32), 2, "bior4.4")


@pytest.mark.parametrize("wavelet", ["bior2.2", "bior4.4", "bior6.8"])
@pytest.mark.parametrize("step", [2, 3, 4])
@pytest.mark.parametrize("rows", [1, 3, 16, 1000])
def test_strip_filter_is_the_whole_array_filter(wavelet: str, step: int, rows: int) -> None:
    """The cache-sized strips of ``_separable`` give the whole-array passes' floats, bit for
    bit, on heights with NaN (the all-valid, NaN-aware and mask passes all use it) and -0."""
    from globeview.terrain.ingest.wavelet import _filter_decimate, _separable

    rng = np.random.default_rng(step * 100 + rows)
    taps = lowpass_kernel(wavelet)
    for shape in [(taps.size, taps.size), (taps.size + 37, taps.size + 5), (83, 61)]:
        x = (rng.normal(size=shape) * 300.0).astype(np.float32)
        x[rng.random(shape) < 0.1] = -0.0
        x[rng.random(shape) < 0.05] = np.nan
        for k in (taps, np.ones_like(taps), np.clip(taps, 0.0, None)):
            whole = _filter_decimate(_filter_decimate(x, k, 1, step), k, 0, step)
            got = _separable(x, k, step, rows)
            assert got.shape == whole.shape
            np.testing.assert_array_equal(got.view(np.int32), whole.view(np.int32))


@pytest.mark.parametrize("wavelet", WAVELETS)
@pytest.mark.parametrize("extra", [0, 2, 6])
def test_window_path_is_the_padded_whole_window(wavelet: str, extra: int) -> None:
    """approximate_window filters straight from the window; it must give, bit for bit, the
    interior of approximate_grid on the window (its former implementation), also with NaN in
    the supports, NaN only in the outer ring, -0 and a halo wider than needed."""
    rng = np.random.default_rng(extra + len(wavelet))
    halo = kernel_halo(wavelet) + extra
    for shape in [(2 * halo + 1, 2 * halo + 1), (2 * halo + 41, 2 * halo + 17)]:
        for case in ("valid", "nan", "ring"):
            x = rng.normal(400.0, 90.0, size=shape).astype(np.float32)
            x[rng.random(shape) < 0.1] = -0.0
            if case == "nan":
                x[rng.random(shape) < 0.08] = np.nan
            elif case == "ring":
                x[0, :] = np.nan
            k = halo // 2
            old = approximate_grid(x, wavelet)[k:-k, k:-k]
            got = approximate_window(x, halo, wavelet)
            assert got.shape == old.shape
            np.testing.assert_array_equal(got.view(np.int32), old.view(np.int32))


def test_window_with_even_sides_is_refused() -> None:
    with pytest.raises(WaveletError, match="odd sides"):
        approximate_window(np.zeros((22, 21), dtype=np.float32), 2)


def _whole_array_nan_filter(fine: np.ndarray, taps: np.ndarray, step: int) -> np.ndarray:
    """The NaN-aware filter as whole-array passes (the former filter_decimate_grid body)."""
    from globeview.terrain.ingest.wavelet import _filter_decimate

    def sep(a: np.ndarray, k: np.ndarray) -> np.ndarray:
        return _filter_decimate(_filter_decimate(a, k, 1, step), k, 0, step)

    h = taps.size // 2
    padded = np.pad(fine, h, mode="reflect", reflect_type="odd")
    invalid = np.isnan(padded)
    values = np.where(invalid, np.float32(0.0), padded)
    exact = sep(values, taps)
    touched = sep(invalid.astype(np.float32), np.ones_like(taps)) > 0.5
    positive = np.clip(taps, 0.0, None)
    num = sep(values, positive)
    den = sep((~invalid).astype(np.float32), positive)
    convex = np.divide(num, den, out=np.full_like(num, np.nan), where=den > 0)
    out = np.where(touched, convex, exact)
    out[np.isnan(fine[::step, ::step])] = np.nan
    return out.astype(np.float32)


@pytest.mark.slow
@pytest.mark.parametrize("wavelet", ["bior2.2", "bior4.4"])
@pytest.mark.parametrize("step", [2, 3])
@pytest.mark.parametrize("block", [(32, 256), (3, 5), (1, 1)])
def test_nan_blocks_are_the_whole_array_nan_filter(
    wavelet: str, step: int, block: tuple[int, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The convex values computed per block of touched nodes equal the whole-array formula
    bit for bit: NaN borders, blobs, scattered NaN, an all-NaN raster, -0."""
    from globeview.terrain.ingest import wavelet as wv
    from globeview.terrain.ingest.wavelet import filter_decimate_grid

    monkeypatch.setattr(wv, "_NAN_BLOCK", block)
    taps = lowpass_kernel(wavelet)
    rng = np.random.default_rng(step * 7 + block[0])
    n = 40 * step + 1
    for case in ("border", "blob", "scattered", "all"):
        x = (rng.normal(size=(n + 3 * step, 3 * n)) * 250.0).astype(np.float32)[:n, : 3 * n - 2]
        x = x[: (x.shape[0] - 1) // step * step + 1, : (x.shape[1] - 1) // step * step + 1]
        x[rng.random(x.shape) < 0.05] = -0.0
        if case == "border":
            x[:, :7] = np.nan
            x[-4:, :] = np.nan
        elif case == "blob":
            x[10:30, 40:90] = np.nan
        elif case == "scattered":
            x[rng.random(x.shape) < 0.03] = np.nan
        else:
            x[:] = np.nan
        want = _whole_array_nan_filter(x, taps, step)
        got = filter_decimate_grid(x, taps, step)
        assert got.shape == want.shape and got.dtype == np.float32
        np.testing.assert_array_equal(got.view(np.int32), want.view(np.int32))


@pytest.mark.parametrize("case", ["edges", "island", "one_node", "none"])
def test_only_valid_centres_are_filtered(case: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The filter runs on the box of output nodes with a valid centre: on real heights with
    the NaN a coarse level's window around a small DEM has (data in a corner, an island, one
    node, none), the result is the whole window's, bit for bit."""
    import rasterio

    from globeview.terrain.ingest import wavelet as wv

    root = Path(wv.__file__).resolve().parents[3]
    with rasterio.open(root / "data" / "N44W072.hgt") as ds:
        x = ds.read(1, window=((0, 2 * 150 + 5), (0, 2 * 200 + 5))).astype(np.float32)
    keep = np.zeros(x.shape, dtype=bool)
    if case == "edges":
        keep[37:, :120] = True
    elif case == "island":
        keep[101:180, 211:260] = True
    elif case == "one_node":
        keep[120, 240] = True
    x[~keep] = np.nan
    got = approximate_window(x, 2)
    monkeypatch.setattr(wv, "_valid_box", lambda c: ((0, c.shape[0]), (0, c.shape[1])))
    whole = approximate_window(x, 2)
    np.testing.assert_array_equal(got.view(np.int32), whole.view(np.int32))
    assert np.isfinite(got).any() == (case != "none")
