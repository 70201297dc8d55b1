"""Tests for the M-band wavelet transforms (globeview.terrain.ingest.mband, Zhang eq. 4-5)."""

from __future__ import annotations

import numpy as np
import pytest
import pywt

from globeview.errors import GlobeviewError
from globeview.terrain.ingest.mband import (
    mband_approximate,
    mband_approximate_grid,
    mband_decompose2d,
    mband_filter_bank,
    mband_grid_kernel,
    mband_reconstruct2d,
    mband_wavedec2,
    mband_waverec2,
)

MS = [2, 3, 4, 5]


@pytest.mark.parametrize("M", MS)
def test_filter_bank_is_orthonormal_with_constant_scaling_filter(M: int) -> None:
    c, d = mband_filter_bank(M)
    assert c.shape == (M,) and d.shape == (M - 1, M)
    np.testing.assert_allclose(c, 1.0 / np.sqrt(M), atol=1e-15)
    bank = np.vstack([c, d])
    np.testing.assert_allclose(bank @ bank.T, np.eye(M), atol=1e-14)
    # Wavelet filters have a vanishing moment of order 0: they annihilate constants.
    np.testing.assert_allclose(d.sum(axis=1), 0.0, atol=1e-14)


@pytest.mark.parametrize("M", MS)
def test_perfect_reconstruction_one_level(M: int) -> None:
    rng = np.random.default_rng(M)
    a = rng.normal(800.0, 150.0, size=(M * 5, M * 7))
    c, d = mband_filter_bank(M)
    approx, details = mband_decompose2d(a, M, c, d)
    assert approx.shape == (5, 7)
    assert set(details) == {(s1, s2) for s1 in range(M) for s2 in range(M)} - {(0, 0)}
    assert all(b.shape == (5, 7) for b in details.values())
    rec = mband_reconstruct2d(approx, details, M, c, d)
    np.testing.assert_allclose(rec, a, rtol=1e-10, atol=0)


@pytest.mark.parametrize("M", [2, 3, 4])
def test_perfect_reconstruction_several_levels(M: int) -> None:
    rng = np.random.default_rng(10 + M)
    a = rng.normal(0.0, 1000.0, size=(M**3 * 2, M**3))
    coeffs = mband_wavedec2(a, M, levels=3)
    assert len(coeffs) == 4
    assert np.shape(coeffs[0]) == (2, 1)
    np.testing.assert_allclose(mband_waverec2(coeffs, M), a, rtol=1e-10, atol=1e-10 * 1000)


@pytest.mark.parametrize("M", [2, 3, 4])
def test_energy_preserved(M: int) -> None:
    rng = np.random.default_rng(20 + M)
    a = rng.uniform(-50.0, 3000.0, size=(M * M * 3, M * M * 2))
    coeffs = mband_wavedec2(a, M, levels=2)
    energy = float(np.sum(np.asarray(coeffs[0]) ** 2))
    for det in coeffs[1:]:
        energy += sum(float(np.sum(b**2)) for b in det.values())
    assert energy == pytest.approx(float(np.sum(a**2)), rel=1e-12)


@pytest.mark.parametrize("M", [2, 3, 4])
def test_constant_exact_with_zero_details(M: int) -> None:
    a = np.full((M * 4, M * 3), 1234.5)
    c, d = mband_filter_bank(M)
    approx, details = mband_decompose2d(a, M, c, d)
    # Orthonormal scaling: each axis multiplies a constant by sqrt(M).
    np.testing.assert_allclose(approx, 1234.5 * M, rtol=1e-14)
    for band in details.values():
        np.testing.assert_allclose(band, 0.0, atol=1e-9)
    coarse, rec = mband_approximate(a, M, levels=1)
    np.testing.assert_allclose(coarse, 1234.5, rtol=1e-14)
    np.testing.assert_allclose(rec, a, rtol=1e-14)


@pytest.mark.parametrize(("M", "levels"), [(3, 1), (3, 2), (4, 1), (4, 2), (2, 3)])
def test_approximate_shapes_and_error(M: int, levels: int) -> None:
    rng = np.random.default_rng(M * 7 + levels)
    a = rng.normal(0.0, 10.0, size=(M**levels * 3, M**levels * 2))
    coarse, rec = mband_approximate(a, M, levels)
    assert coarse.shape == (3, 2)
    assert rec.shape == a.shape
    # Haar family: the approximation is the block mean, and the reconstruction repeats it.
    b = M**levels
    means = a.reshape(3, b, 2, b).mean(axis=(1, 3))
    np.testing.assert_allclose(coarse, means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(rec, np.kron(means, np.ones((b, b))), atol=1e-12)
    assert np.max(np.abs(rec - a)) > 0.0


@pytest.mark.parametrize("shape", [(7, 9), (9, 10), (0, 9)])
def test_sides_must_be_multiples_of_m(shape: tuple[int, int]) -> None:
    c, d = mband_filter_bank(3)
    with pytest.raises(ValueError, match="multiples of 3") as info:
        mband_decompose2d(np.zeros(shape), 3, c, d)
    assert isinstance(info.value, GlobeviewError)


def test_bad_m_and_family_rejected() -> None:
    with pytest.raises(GlobeviewError, match="M must be an integer >= 2"):
        mband_filter_bank(1)
    with pytest.raises(GlobeviewError, match="family"):
        mband_filter_bank(3, kind="daubechies")
    with pytest.raises(GlobeviewError, match="multiples of 9"):
        mband_wavedec2(np.zeros((18, 12)), 3, levels=2)


@pytest.mark.parametrize("M", [2, 3, 4])
def test_grid_kernel_symmetric_unit_sum(M: int) -> None:
    k = mband_grid_kernel(M)
    assert k.size == 2 * M - 1
    np.testing.assert_allclose(k, k[::-1])
    assert k.sum() == pytest.approx(1.0)
    assert np.all(k > 0)


@pytest.mark.parametrize("M", [2, 3, 4])
def test_grid_variant_reproduces_plane_and_shape(M: int) -> None:
    y, x = np.mgrid[0 : M * 6 + 1, 0 : M * 4 + 1].astype(np.float64)
    fine = (300.0 + 1.75 * x - 0.5 * y).astype(np.float32)
    coarse = mband_approximate_grid(fine, M)
    assert coarse.shape == (7, 5)
    np.testing.assert_allclose(coarse, fine[::M, ::M], rtol=1e-6)


def test_grid_variant_nan_rule_and_convexity() -> None:
    rng = np.random.default_rng(1)
    fine = rng.uniform(10.0, 20.0, size=(25, 25)).astype(np.float32)
    fine[6:13, 3:10] = np.nan
    coarse = mband_approximate_grid(fine, 3)
    np.testing.assert_array_equal(np.isnan(coarse), np.isnan(fine[::3, ::3]))
    valid = coarse[~np.isnan(coarse)]
    assert valid.min() >= 10.0 and valid.max() <= 20.0


def test_grid_variant_rejects_bad_sides() -> None:
    with pytest.raises(GlobeviewError, match="3\\*m\\+1"):
        mband_approximate_grid(np.zeros((12, 13), dtype=np.float32), 3)


def test_overlapping_paraunitary_bank_reconstructs() -> None:
    """The general (filters longer than M, periodic) path with Daubechies-2 as a 2-band bank."""

    c = np.asarray(pywt.Wavelet("db2").rec_lo)
    d = np.array([[(-1) ** t * c[c.size - 1 - t] for t in range(c.size)]])
    rng = np.random.default_rng(99)
    a = rng.normal(0.0, 50.0, size=(16, 12))
    approx, details = mband_decompose2d(a, 2, c, d)
    energy = np.sum(approx**2) + sum(np.sum(b**2) for b in details.values())
    assert energy == pytest.approx(np.sum(a**2), rel=1e-12)
    np.testing.assert_allclose(mband_reconstruct2d(approx, details, 2, c, d), a, rtol=1e-10)
    # Random data leaves energy in the details: the wavelet filter was really applied.
    assert max(np.abs(b).max() for b in details.values()) > 1.0
