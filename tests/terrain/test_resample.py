"""The separable resampler (globeview.terrain.dem.resample, issue #25 C1) against GDAL's own warp.

`Dem.read_grid_parts` used `rasterio.warp.reproject` (GDAL's bilinear warp) for every source;
lon/lat sources now go through `resample_bilinear`. The tolerance, derived in the module's
docstring: GDAL forms the same weighted sums in double and rounds them to float32; ours are
float64 sums in another order, rounded once. Two float64 sums of the same terms differ by a
few 1e-16 of the sum of |terms| (<= the window's largest |height|), so after the rounding the
values differ by at most 1 ulp of float32 of the value, plus ~1e-15 of the largest |height|
where the terms cancel (a value near 0 m between hills and sea). Tested with 1e-12 for that
second term: still below 1e-8 m at 9 km. NaN (no value) must be exactly where GDAL's is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rasterio.enums import Resampling
from rasterio.warp import reproject

from globeview.terrain.dem import reader as dem_module
from globeview.terrain.dem.reader import open_dem
from globeview.terrain.dem.resample import resample_bilinear, warp_chunks
from globeview.terrain.quadtree import node_spacing

DATA = Path(__file__).resolve().parents[2] / "data"


def _gdal(arr: np.ndarray, src_t: Affine, dst_t: Affine, shape: tuple[int, int]) -> np.ndarray:
    """GDAL's bilinear warp, as `Dem._warp` called it for lon/lat sources."""
    dst = np.full(shape, np.nan, dtype=np.float32)
    reproject(
        arr,
        dst,
        src_transform=src_t,
        src_crs="EPSG:4326",
        dst_transform=dst_t,
        dst_crs="EPSG:4326",
        resampling=Resampling.bilinear,
        src_nodata=np.nan,
        dst_nodata=np.nan,
    )
    return dst


def _assert_within_rounding(ours: np.ndarray, gdal: np.ndarray, largest: float) -> None:
    """NaN where GDAL's is; elsewhere within 1 ulp of float32 + 1e-12 of ``largest``."""
    assert ours.dtype == np.float32 and ours.shape == gdal.shape
    np.testing.assert_array_equal(np.isnan(ours), np.isnan(gdal))
    ok = ~np.isnan(gdal)
    tol = np.spacing(np.abs(gdal[ok])).astype(np.float64) + 1e-12 * largest
    diff = np.abs(ours[ok].astype(np.float64) - gdal[ok])
    assert (diff <= tol).all(), f"max {diff.max():.3g} m, {np.max(diff / tol):.1f}x the tolerance"


# ---- real data, through Dem.read_grid_parts ---------------------------------------------------

# (file, level, (west, north) offsets from the footprint's west/north edge in node spacings,
# nodes (cols, rows)): inside the data, reaching past each side, and an ingest-sized window.
CASES = [
    ("N44W072.hgt", 12, (100, 100), (257, 129)),  # upsampled (nodes 2.47", pixels 3")
    ("N44W072.hgt", 12, (-40, -30), (300, 200)),  # past the west and north edges
    ("N44W072.hgt", 12, (1400, 1300), (300, 200)),  # past the east and south edges
    ("N44W072.hgt", 12, (-16, -16), (1025, 1025)),  # an ingest chunk over the whole tile
    ("N44W072.hgt", 10, (-8, -8), (400, 400)),  # downsampled 3.3x: GDAL's general kernel
    ("craterlake-elev-16bit-30m.tif", 13, (-20, -20), (400, 300)),  # fill -> NaN, 1.27x
    ("craterlake-elev-16bit-30m.tif", 14, (-50, -50), (700, 500)),  # past every side, 0.64x
    ("craterlake-elev-16bit-30m.tif", 12, (10, 10), (60, 40)),  # 2.5x, inside
    ("etopo20.tif", 3, (-8, 0), (1025, 513)),  # global: poles, antimeridian, 1.05x
    ("etopo20.tif", 5, (300, 100), (200, 200)),  # 0.26x inside the globe
    ("topobathy_vancouver.tif", 7, (-5, -5), (100, 80)),  # sea and land, upsampled
]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "level", "offset", "nodes"), CASES)
def test_read_grid_parts_is_gdals_warp_on_real_data(
    monkeypatch: pytest.MonkeyPatch,
    name: str,
    level: int,
    offset: tuple[int, int],
    nodes: tuple[int, int],
) -> None:
    """The data part (the warp) within rounding of GDAL's, NaN where GDAL's; the edge part
    (the surface continued past the data edge, decided from the data part's NaN) the same
    within the same tolerance."""
    d = node_spacing(level, 6)
    with open_dem(DATA / name) as dem:
        west, _, _, north = dem.info.bounds_lonlat
        args = (west + offset[0] * d, north - offset[1] * d, d, d, *nodes)
        ours = dem.read_grid_parts(*args)
        largest = max(abs(dem.vmin), abs(dem.vmax))
        with monkeypatch.context() as mp:
            mp.setattr(dem_module, "resample_bilinear", _gdal)
            gdal = dem.read_grid_parts(*args)
    assert np.isfinite(ours.data).any()
    _assert_within_rounding(ours.data, gdal.data, largest)
    _assert_within_rounding(ours.edge, gdal.edge, largest)


# ---- synthetic rasters: NaN holes and edges, every ratio ------------------------------------


def _raster(rng: np.random.Generator, h: int, w: int, holes: str) -> np.ndarray:
    """A rough random-walk surface (metres) with no-data of the given kind."""
    base = rng.uniform(-500.0, 6000.0)
    a = np.cumsum(np.cumsum(rng.normal(size=(h, w)), 0), 1) * rng.uniform(0.01, 5.0) + base
    a = a.astype(np.float32)
    if holes == "speckle":
        a[rng.random((h, w)) < 0.1] = np.nan
    elif holes == "hole":
        r, c = int(rng.integers(0, h)), int(rng.integers(0, w))
        a[r : r + int(rng.integers(1, 20)), c : c + int(rng.integers(1, 20))] = np.nan
    elif holes == "edge":  # a data edge through the window
        a[:, : int(rng.integers(1, w // 2))] = np.nan
    return a


def _off_the_snap(ratio: float) -> bool:
    """GDAL snaps a kernel whose reciprocal scale is within 0.05 of an integer; exactly at
    0.05 its own rounding of the window decides (the one documented exception)."""
    return abs(abs(ratio - round(ratio)) - 0.05) > 1e-6


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    ratio=st.one_of(
        st.floats(0.3, 4.0), st.sampled_from([0.5, 0.96, 1.0, 1.04, 1.06, 1.5, 2.0, 2.97, 3.0])
    ),
    aspect=st.one_of(st.just(1.0), st.floats(0.7, 1.4)),
    holes=st.sampled_from(["none", "speckle", "hole", "edge"]),
    past=st.booleans(),
)
def test_resample_bilinear_is_gdals_warp(seed, ratio, aspect, holes, past) -> None:
    """Upsampling and downsampling (GDAL's 4-sample formula and its general kernel, snapped
    scales), NaN holes and data edges, destinations inside the raster and reaching past it
    (where GDAL narrows the kernel and cuts the warp into pieces)."""
    ratio_y = ratio * aspect
    if not (_off_the_snap(ratio) and _off_the_snap(ratio_y)):
        return
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(20, 160, 2))
    arr = _raster(rng, h, w, holes)
    px = rng.uniform(1e-4, 0.05)
    src_t = Affine(px, 0.0, rng.uniform(-170.0, 150.0), 0.0, -px, rng.uniform(-50.0, 80.0))
    dx, dy = px * ratio, px * ratio_y
    cols, rows = max(1, int(w / ratio) - 2), max(1, int(h / ratio_y) - 2)
    west = src_t.c + rng.uniform(0.0, max(1e-12, w * px - cols * dx))
    north = src_t.f - rng.uniform(0.0, max(1e-12, h * px - rows * dy))
    if past:
        cols, rows = cols + int(rng.integers(1, 60)), rows + int(rng.integers(1, 60))
        west -= int(rng.integers(0, 15)) * dx
        north += int(rng.integers(0, 15)) * dy
    dst_t = Affine(dx, 0.0, west, 0.0, -dy, north)
    ours = resample_bilinear(arr, src_t, dst_t, (rows, cols))
    _assert_within_rounding(
        ours, _gdal(arr, src_t, dst_t, (rows, cols)), float(np.nanmax(abs(arr)))
    )


def test_warp_chunks_cut_a_destination_mostly_off_the_raster() -> None:
    """A destination 3x a raster's width at a 1.4x ratio, half of it past the raster: GDAL
    halves it until each piece is mostly on the raster (pieces over 100 pixels); the pieces
    tile the destination; a piece inside the raster has the grids' own scale 1/1.4, those
    reaching past its end a larger one (a narrower kernel), none where it has no source."""
    step = 1.4
    chunks = warp_chunks((-60.0, step), (-10.0, step), (150, 300), (100, 120))
    cover = np.zeros((150, 300), dtype=int)
    for c in chunks:
        cover[c.row0 : c.row1, c.col0 : c.col1] += 1
    assert (cover == 1).all()
    assert len(chunks) > 2
    scales = [v for c in chunks if c.scales is not None for v in c.scales]
    assert any(v == pytest.approx(1 / step) for v in scales)
    assert any(v > 1 / step * 1.01 for v in scales)
    assert any(c.scales is None for c in chunks)
    # One piece when the destination is inside the raster.
    inside = warp_chunks((3.0, step), (3.0, step), (60, 60), (100, 120))
    assert [(c.row0, c.row1, c.col0, c.col1) for c in inside] == [(0, 60, 0, 60)]
    assert inside[0].scales == pytest.approx((1 / step, 1 / step))


def test_resample_bilinear_refuses_rotated_grids() -> None:
    arr = np.zeros((4, 4), dtype=np.float32)
    with pytest.raises(ValueError, match="north-up"):
        resample_bilinear(arr, Affine(1, 0.1, 0, 0, -1, 0), Affine(1, 0, 0, 0, -1, 0), (2, 2))
