"""The source value scan in the block's own dtype (globeview.terrain.dem.value_scan, issue #25 C6)
gives what the float64 scan gave: the same candidate counts, masked samples and range."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from globeview.terrain.dem import reader as dem_module
from globeview.terrain.dem.reader import _COMMON_FILLS, MAX_HEIGHT_M, MIN_HEIGHT_M, open_dem
from globeview.terrain.dem.value_scan import native_scan_applies, scan_block

DATA = Path(__file__).resolve().parents[2] / "data"
DTYPES = [np.int16, np.uint16, np.int32, np.float32, np.float64, np.uint8, np.int8]


def _reference(a: np.ndarray, nodata: float | None, cand: np.ndarray):
    """The per-block loop of `Dem._scan_values` before C6 (float64, scale 1, offset 0)."""
    a = a.astype(np.float64)
    v = a[~np.isnan(a)] if a.dtype.kind == "f" else a.ravel()
    if nodata is not None:
        v = v[v != nodata]
    counts = np.zeros(cand.size, dtype=np.int64)
    is_c = np.isin(v, cand)
    if cand.size and is_c.any():
        counts += np.count_nonzero(v[is_c, None] == cand[None, :], axis=0)
    h = v[~is_c]
    ok = (h >= MIN_HEIGHT_M) & (h <= MAX_HEIGHT_M)
    lo, hi = (float(h[ok].min()), float(h[ok].max())) if ok.any() else (np.inf, -np.inf)
    return counts, int(h.size - np.count_nonzero(ok)), lo, hi


def _block(rng: np.random.Generator, dtype: type, n: int, kind: str) -> np.ndarray:
    info = np.iinfo(dtype) if np.dtype(dtype).kind in "iu" else None
    lo, hi = (max(info.min, -500), min(info.max, 4000)) if info else (-500.0, 4000.0)
    a = rng.uniform(lo, hi, n)
    specials = [-999, -9999, -32767, -32768, 32767, 65535, 0, 255, -128, 127, 20000, -20000]
    if info is None:
        specials += [np.nan, np.inf, -np.inf, 3.4028234663852886e38, 9.969209968386869e36, 1e300]
    pick = rng.random(n) < {"clean": 0.0, "some": 0.05, "many": 0.6}[kind]
    a[pick] = rng.choice(np.array(specials, dtype=np.float64), size=int(pick.sum()))
    if info is not None:
        a = np.clip(np.nan_to_num(a), info.min, info.max)
    with np.errstate(over="ignore", invalid="ignore"):
        return a.astype(dtype)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    dtype=st.sampled_from(DTYPES),
    n=st.integers(0, 300),
    kind=st.sampled_from(["clean", "some", "many"]),
    nodata=st.sampled_from([None, -9999.0, -32768.0, 0.0, float("nan"), 1.5, 255.0]),
)
def test_scan_block_is_the_float64_scan(seed, dtype, n, kind, nodata) -> None:
    """Every dtype the native scan takes, with NaN, +-inf, values past the height limits,
    candidates present or not, nodata that the dtype does or does not represent."""
    assert native_scan_applies(np.dtype(dtype))
    rng = np.random.default_rng(seed)
    a = _block(rng, dtype, n, kind)
    cand = np.array(sorted(set(_COMMON_FILLS) - {nodata}), dtype=np.float64)
    got = scan_block(a, nodata, cand, MIN_HEIGHT_M, MAX_HEIGHT_M)
    counts, masked, lo, hi = _reference(a, nodata, cand)
    np.testing.assert_array_equal(got.counts, counts)
    assert (got.masked, got.lo, got.hi) == (masked, lo, hi)


def test_wide_integers_are_not_scanned_natively() -> None:
    """float64 does not hold every int64 / uint64: those keep the float64 scan."""
    assert not native_scan_applies(np.dtype(np.int64))
    assert not native_scan_applies(np.dtype(np.uint64))
    assert not native_scan_applies(np.dtype(np.float16))


@pytest.mark.parametrize(
    "name",
    [
        "N44W072.hgt",
        "etopo20.tif",
        "craterlake-elev-16bit-30m.tif",  # an undeclared -32767 fill
        "topobathy_vancouver.tif",
    ],
)
def test_dem_info_unchanged(monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    with open_dem(DATA / name) as dem:
        native = dem.info
    with monkeypatch.context() as mp:
        mp.setattr(dem_module, "native_scan_applies", lambda dtype: False)
        with open_dem(DATA / name) as dem:
            before = dem.info
    assert native == before


def _raster(path: Path, dtype: str, tiled: bool) -> Path:
    """A 613 x 701 DEFLATE raster with nodata (-9999) in a corner and an undeclared -32767
    fill plateau: what the decimated value scan must find."""
    rng = np.random.default_rng(3)
    a = rng.uniform(100.0, 900.0, (613, 701))
    a[:200, :150] = -9999.0
    a[300:420, 400:560] = -32767.0
    blocks = {"tiled": True, "blockxsize": 64, "blockysize": 128} if tiled else {}
    with rasterio.open(
        path, "w", driver="GTiff", width=701, height=613, count=1, dtype=dtype,
        crs="EPSG:4326", transform=Affine(0.001, 0, -71, 0, -0.001, 44.6), nodata=-9999,
        compress="deflate", **blocks,
    ) as ds:  # fmt: skip
        ds.write(a.astype(dtype), 1)
    return path


@pytest.mark.parametrize("dtype", ["float32", "int16"])
@pytest.mark.parametrize("tiled", [True, False])
def test_decimated_scan_reads_each_block_once_and_finds_what_gdal_decimation_did(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, dtype: str, tiled: bool
) -> None:
    """A raster too large for the exact scan is sampled as GDAL's decimated nearest read
    samples it (the same fills, masked samples and range), but one block at a time, each
    block read once: GDAL's own decimated read decompressed a row of blocks again for every
    output row when the row outgrew its block cache (16x the CPU on a 50 000^2 DTM)."""
    path = _raster(tmp_path / "d.tif", dtype, tiled)
    monkeypatch.setattr(dem_module, "EXACT_RANGE_MAX_PIXELS", 1000)
    monkeypatch.setattr(dem_module, "_DECIMATED_PIXELS", 30_000)
    windows: list[tuple[int, int, int, int]] = []
    read_raw = dem_module.Dem._read_raw

    def spy(self, window, out_shape=None, native=False):
        if window is not None:
            windows.append((window.col_off, window.row_off, window.width, window.height))
        return read_raw(self, window, out_shape=out_shape, native=native)

    with monkeypatch.context() as mp:
        mp.setattr(dem_module.Dem, "_read_raw", spy)
        with open_dem(path) as dem:
            by_blocks = dem.info
            bh, bw = dem._ds.block_shapes[0]
    with monkeypatch.context() as mp:
        mp.setattr(
            dem_module.Dem,
            "_decimated",
            lambda self, shape, native: iter(
                [self._read_raw(None, out_shape=shape, native=native)]
            ),
        )
        with open_dem(path) as dem:
            gdal_way = dem.info
    assert not by_blocks.range_exact and by_blocks.fill_values == (-32767.0,)
    assert by_blocks == gdal_way
    assert windows and len(set(windows)) == len(windows)  # no block read twice
    assert all(r % bh == 0 and c % bw == 0 and h <= bh and w <= bw for c, r, w, h in windows)
