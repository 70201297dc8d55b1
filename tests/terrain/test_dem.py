"""Tests of globeview.terrain.dem.reader on the real embedded data and on generated bad inputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.warp import transform as warp_transform

from globeview.errors import DemError
from globeview.terrain.dem.data import EMBEDDED_DATA_DIR, embedded_dem_paths
from globeview.terrain.dem.reader import open_dem

DATA = EMBEDDED_DATA_DIR
ETOPO5 = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "etopo5.tif"
if not ETOPO5.exists():
    ETOPO5 = Path("/work/shared/data/etopo5.tif")


def _write(path: Path, arr: np.ndarray, **profile: object) -> Path:
    prof = {
        "driver": "GTiff",
        "height": arr.shape[-2],
        "width": arr.shape[-1],
        "count": 1 if arr.ndim == 2 else arr.shape[0],
        "dtype": arr.dtype.name,
    }
    prof.update(profile)
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(arr if arr.ndim == 3 else arr[None])
    return path


# ---- embedded data ----------------------------------------------------------------------


def test_embedded_paths_exist_and_base_first() -> None:
    paths = embedded_dem_paths()
    assert [p.name for p in paths] == [
        "etopo20.tif",
        "N44W072.hgt",
        "craterlake-elev-16bit-30m.tif",
        "topobathy_vancouver.tif",
    ]
    assert all(p.is_file() for p in paths)
    assert (DATA / "README.md").is_file()


def test_etopo20_info() -> None:
    with open_dem(DATA / "etopo20.tif") as dem:
        info = dem.info
    assert info.crs == "EPSG:4326"
    assert info.bounds_lonlat == pytest.approx((-180, -90, 180, 90))
    assert info.res_deg == pytest.approx((1 / 3, 1 / 3))
    # 20 arc-min of latitude is about 37 km
    assert 30_000 < info.res_m[1] < 40_000
    assert not info.pixel_is_point
    assert info.vmin < -9000 and info.vmax > 5000
    assert info.range_exact and info.reaches_pole and info.crosses_antimeridian
    assert info.wraps_longitude
    assert "EPSG:4326" in info.summary() and "etopo20" in info.summary()


def test_srtm_tile_pixel_is_point_big_endian() -> None:
    with open_dem(DATA / "N44W072.hgt") as dem:
        info = dem.info
    assert info.pixel_is_point
    # samples sit on whole degrees: the footprint is the tile's nominal bounds
    assert info.bounds_lonlat == pytest.approx((-72, 44, -71, 45), abs=1e-9)
    assert info.res_deg == pytest.approx((1 / 1200, 1 / 1200))
    assert info.nodata == -32768 and info.fill_value is None
    # Mt Washington, 1 917 m in reality, 1 908 m in SRTM3; a byte-swap would be wildly off
    assert 1850 < info.vmax < 1950
    assert 0 < info.vmin < 300
    assert not info.reaches_pole and not info.crosses_antimeridian


def test_crater_lake_undeclared_fill_detected() -> None:
    with open_dem(DATA / "craterlake-elev-16bit-30m.tif") as dem:
        info = dem.info
        assert info.nodata is None
        assert info.fill_value == -32767
        # Crater Lake's surface is ~1 880 m; rim and surroundings above 1 200 m
        assert 1200 < info.vmin < 1400 and 1800 < info.vmax < 2000
        w, s, e, n = info.bounds_lonlat
        g = dem.read_grid(w, n, (e - w) / 50, (n - s) / 30, 51, 31)
    assert np.nanmin(g) > 1200  # the fill never leaks into the heights
    assert np.isnan(g).any()  # the collar outside the footprint stays no-data
    assert np.isfinite(g[15, 25])  # the centre is data


def test_vancouver_topobathy() -> None:
    with open_dem(DATA / "topobathy_vancouver.tif") as dem:
        info = dem.info
    assert info.vmin < 0 < info.vmax
    assert info.bounds_lonlat == pytest.approx((-126, 48, -122, 50), abs=0.01)


def test_etopo5_grid_registered() -> None:
    if not ETOPO5.exists():
        pytest.skip("shared etopo5.tif not available")
    with open_dem(ETOPO5) as dem:
        info = dem.info
        assert info.pixel_is_point and info.wraps_longitude and info.reaches_pole
        assert info.bounds_lonlat == pytest.approx((-180, -90, 180, 90), abs=1e-9)
        assert info.res_deg == pytest.approx((1 / 12, 1 / 12))
        assert info.vmin < -10_000 and info.vmax > 7000
        # grid-registered: node (0, 0) of a 5' grid at (-180, 90) is sample (0, 0)
        g = dem.read_grid(-180, 90, 1 / 12, 1 / 12, 4, 4)
        with rasterio.open(ETOPO5) as ds:
            raw = ds.read(1, window=((1, 4), (0, 4))).astype(np.float32)
    np.testing.assert_allclose(g[1:], raw, atol=1e-3)


def test_multiband_raster_uses_band_one() -> None:
    with open_dem(DATA / "bluemarble_2048x1024.tif") as dem:
        assert dem.info.band_count == 3
        assert "band 1" in dem.info.summary()


# ---- read_grid on the global base ----------------------------------------------------------


def test_etopo20_known_places() -> None:
    with open_dem(DATA / "etopo20.tif") as dem:
        pacific = dem.read_grid(-150.0, 0.0, 1.0, 1.0, 1, 1)[0, 0]
        himalaya = dem.read_grid(86.0, 29.0, 0.5, 0.5, 5, 5)
    assert pacific < -3000
    assert np.nanmax(himalaya) > 4000


def test_etopo20_poles_and_antimeridian() -> None:
    with open_dem(DATA / "etopo20.tif") as dem:
        g = dem.read_grid(-180.0, 90.0, 2.0, 2.0, 181, 91)
        # a window straddling the antimeridian agrees with the global read
        w = dem.read_grid(176.0, 10.0, 2.0, 2.0, 3, 3)
        w2 = dem.read_grid(-180.0, 10.0, 2.0, 2.0, 3, 3)
    assert not np.isnan(g).any()
    np.testing.assert_array_equal(g[:, 0], g[:, -1])  # lon -180 == lon 180
    assert np.ptp(g[0]) == 0 and np.ptp(g[-1]) == 0  # a pole is one point
    assert g[-1, 0] > 2000  # Antarctic ice sheet at the south pole
    assert g[0, 0] < -3000  # Arctic Ocean at the north pole
    np.testing.assert_allclose(w[:, 2], w2[:, 0])
    np.testing.assert_allclose(w[:, 2], g[40:43, 180])


def test_etopo20_node_registration_matches_source_cells() -> None:
    """Nodes on cell centres return the cell value exactly (no half-cell shift)."""
    with open_dem(DATA / "etopo20.tif") as dem:
        g = dem.read_grid(-180 + 1 / 6, 90 - 1 / 6, 1 / 3, 1 / 3, 20, 10)
    with rasterio.open(DATA / "etopo20.tif") as ds:
        raw = ds.read(1, window=((0, 10), (0, 20)))
    np.testing.assert_allclose(g, raw, atol=1e-2)


def test_outside_regional_dem_is_nan() -> None:
    with open_dem(DATA / "N44W072.hgt") as dem:
        out = dem.read_grid(10.0, 50.0, 0.1, 0.1, 8, 8)
        edge = dem.read_grid(-72.05, 44.5, 0.01, 0.01, 11, 2)
        corner = dem.read_grid(-72.0, 45.0, 1.0, 1.0, 2, 2)
    assert np.isnan(out).all()
    assert np.isnan(edge[:, :4]).all() and np.isfinite(edge[:, 6:]).all()
    assert np.isfinite(corner).all()  # the samples sit on the tile's corners


def test_interior_void_filled(tmp_path: Path) -> None:
    y, x = np.mgrid[0:60, 0:80]
    arr = (100 + x + y).astype(np.int16)
    arr[20:30, 30:40] = -32768  # a void inside the data
    p = _write(
        tmp_path / "void.tif",
        arr,
        crs="EPSG:4326",
        transform=Affine(0.01, 0, 5.0, 0, -0.01, 45.0),
        nodata=-32768,
    )
    with open_dem(p) as dem:
        g = dem.read_grid(5.005, 44.995, 0.01, 0.01, 80, 60)
    assert np.isfinite(g).all()
    # filled values stay within the surrounding heights
    assert g[20:30, 30:40].min() >= 100 + 30 + 20 - 2 and g[20:30, 30:40].max() <= 100 + 40 + 30


def test_projected_utm_reads_back_at_lonlat(tmp_path: Path) -> None:
    # a UTM 10N raster whose height is a linear function of easting/northing
    x0, y0, res = 500_000.0, 5_000_000.0, 100.0
    rows, cols = np.mgrid[0:200, 0:200]
    east, north = x0 + (cols + 0.5) * res, y0 - (rows + 0.5) * res
    arr = ((east - x0) / 100 + (y0 - north) / 50).astype(np.float32)
    p = _write(
        tmp_path / "utm.tif", arr, crs="EPSG:32610", transform=Affine(res, 0, x0, 0, -res, y0)
    )
    with open_dem(p) as dem:
        info = dem.info
        assert info.crs == "EPSG:32610"
        assert info.res_m == pytest.approx((100, 100), rel=0.01)
        w, s, e, n = info.bounds_lonlat
        # node spacing ~ the source's 100 m, so no downsampling kernel blurs the plane
        lons = np.array([-122.9, -122.899])
        lats = np.array([45.1, 45.099])
        g = dem.read_grid(lons[0], lats[0], 0.001, 0.001, 2, 2)
        assert s < lats.min() and lats.max() < n and w < lons.min() and lons.max() < e
        outside = dem.read_grid(w - 1.0, n, 0.1, 0.1, 3, 3)
    gl, gt = np.meshgrid(lons, lats)
    ex, ny = warp_transform("EPSG:4326", "EPSG:32610", gl.ravel(), gt.ravel())
    expect = (np.array(ex) - x0) / 100 + (y0 - np.array(ny)) / 50
    np.testing.assert_allclose(g.ravel(), expect, atol=0.5)
    assert np.isnan(outside).all()


def test_crs_override_supplies_missing_crs(tmp_path: Path) -> None:
    arr = np.arange(100, dtype=np.float32).reshape(10, 10)
    p = _write(tmp_path / "nocrs.tif", arr, transform=Affine(0.1, 0, 10, 0, -0.1, 50))
    with open_dem(p, crs="EPSG:4326") as dem:
        assert dem.info.crs == "EPSG:4326"
        assert dem.info.bounds_lonlat == pytest.approx((10, 49, 11, 50))


def test_regional_dem_in_0_360_longitudes(tmp_path: Path) -> None:
    arr = np.full((10, 10), 500, dtype=np.float32)
    p = _write(tmp_path / "east.tif", arr, crs="EPSG:4326", transform=Affine(1, 0, 200, 0, -1, 10))
    with open_dem(p) as dem:
        assert dem.info.bounds_lonlat == pytest.approx((-160, 0, -150, 10))
        g = dem.read_grid(-158.0, 8.0, 1.0, 1.0, 3, 3)
    np.testing.assert_allclose(g, 500)


# ---- bad input -----------------------------------------------------------------------------


def _bad_dem_error(path: Path, crs: str | None = None) -> str:
    with pytest.raises(DemError) as exc, open_dem(path, crs=crs) as dem:
        _ = dem.info
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_missing_file(tmp_path: Path) -> None:
    assert "not found" in _bad_dem_error(tmp_path / "nope.tif")


def test_text_file_named_tif(tmp_path: Path) -> None:
    p = tmp_path / "notes.tif"
    p.write_text("this is not a raster\n")
    assert "cannot read" in _bad_dem_error(p)


def test_truncated_geotiff(tmp_path: Path) -> None:
    arr = np.random.default_rng(0).normal(size=(300, 300)).astype(np.float32)
    src = _write(
        tmp_path / "full.tif", arr, crs="EPSG:4326", transform=Affine(0.01, 0, 0, 0, -0.01, 0)
    )
    data = src.read_bytes()
    p = tmp_path / "cut.tif"
    p.write_bytes(data[: len(data) // 2])
    msg = _bad_dem_error(p)
    assert "cut.tif" in msg


def test_no_crs_says_how_to_supply_one(tmp_path: Path) -> None:
    arr = np.ones((10, 10), dtype=np.float32)
    p = _write(tmp_path / "nocrs.tif", arr, transform=Affine(1, 0, 0, 0, -1, 10))
    msg = _bad_dem_error(p)
    assert "no coordinate reference system" in msg and "--crs EPSG:" in msg


def test_invalid_crs_override(tmp_path: Path) -> None:
    arr = np.ones((10, 10), dtype=np.float32)
    p = _write(tmp_path / "a.tif", arr, crs="EPSG:4326", transform=Affine(1, 0, 0, 0, -1, 10))
    assert "unknown CRS 'EPSG:nonsense'" in _bad_dem_error(p, crs="EPSG:nonsense")


def test_all_nodata_and_all_nan(tmp_path: Path) -> None:
    t = Affine(1, 0, 0, 0, -1, 10)
    a = np.full((10, 10), -9999, dtype=np.int16)
    p1 = _write(tmp_path / "nd.tif", a, crs="EPSG:4326", transform=t, nodata=-9999)
    p2 = _write(
        tmp_path / "nan.tif", np.full((10, 10), np.nan, np.float32), crs="EPSG:4326", transform=t
    )
    assert "no valid data" in _bad_dem_error(p1)
    assert "no valid data" in _bad_dem_error(p2)


def test_one_pixel_raster(tmp_path: Path) -> None:
    p = _write(
        tmp_path / "one.tif",
        np.ones((1, 1), np.float32),
        crs="EPSG:4326",
        transform=Affine(1, 0, 0, 0, -1, 10),
    )
    assert "too small" in _bad_dem_error(p)


def test_real_minus_9999_is_data_not_fill(tmp_path: Path) -> None:
    # bathymetry reaching -10 000 m: -9999 amid it is a real depth
    arr = np.linspace(-10_000, 100, 100).astype(np.float32).reshape(10, 10)
    arr[5, 5] = -9999
    p = _write(tmp_path / "deep.tif", arr, crs="EPSG:4326", transform=Affine(1, 0, 0, 0, -1, 10))
    with open_dem(p) as dem:
        assert dem.info.fill_value is None
        assert dem.info.vmin == pytest.approx(-10_000)


def _reference_window(dem, window, f):  # type: ignore[no-untyped-def]
    """_read_window's float64 route (the only one before the float32 fast path)."""
    import math

    from rasterio.enums import Resampling

    from globeview.terrain.dem.reader import MAX_HEIGHT_M, MIN_HEIGHT_M

    shape = (max(1, math.ceil(window.height / f)), max(1, math.ceil(window.width / f)))
    clean = not dem.fill_values and not dem.masked_samples
    rs = Resampling.average if (f > 1 and clean) else Resampling.nearest
    a = dem._ds.read(1, window=window, out_shape=shape, resampling=rs, masked=True)
    raw = a.astype(np.float64).filled(np.nan)
    if dem.fill_values:
        raw[np.isin(raw, dem.fill_values)] = np.nan
    h = dem._to_metres(raw)
    h[~((h >= MIN_HEIGHT_M) & (h <= MAX_HEIGHT_M))] = np.nan
    return h.astype(np.float32)


@pytest.mark.parametrize("nodata", [None, -9999.0, float("nan")])
def test_float32_window_fast_path_is_the_float64_route(tmp_path: Path, nodata) -> None:  # type: ignore[no-untyped-def]
    """Float32 metres skip the float64 round trip: same array bit for bit, with NaN, +-inf,
    -0, the limits themselves and values just past them, declared nodata, decimation."""
    from rasterio.windows import Window

    from globeview.terrain.dem.reader import MAX_HEIGHT_M, MIN_HEIGHT_M

    rng = np.random.default_rng(4)
    arr = (rng.normal(size=(120, 90)) * 3000.0).astype(np.float32)
    specials = np.array(
        [np.nan, np.inf, -np.inf, -0.0, 0.0, MIN_HEIGHT_M, MAX_HEIGHT_M,
         np.nextafter(np.float32(MAX_HEIGHT_M), np.float32(1e9)),
         np.nextafter(np.float32(MIN_HEIGHT_M), np.float32(-1e9)), 1e30, -9999.0],
        dtype=np.float32,
    )  # fmt: skip
    pick = rng.random(arr.shape) < 0.15
    arr[pick] = rng.choice(specials, size=int(pick.sum()))
    profile: dict[str, object] = {
        "crs": "EPSG:4326",
        "transform": Affine(0.01, 0.0, -71.0, 0.0, -0.01, 45.0),
    }
    if nodata is not None:
        profile["nodata"] = nodata
    path = _write(tmp_path / "f32.tif", arr, **profile)
    with open_dem(path) as dem:
        for win, f in [
            (Window(0, 0, 90, 120), 1),
            (Window(7, 11, 50, 61), 1),
            (Window(0, 0, 90, 120), 3),
        ]:
            got = dem._read_window(win, f)
            want = _reference_window(dem, win, f)
            assert got.dtype == np.float32 and got.shape == want.shape
            np.testing.assert_array_equal(got.view(np.int32), want.view(np.int32))
    for name in ("etopo20.tif", "topobathy_vancouver.tif"):
        with open_dem(DATA / name) as dem:
            win = Window(0, 0, dem._ds.width, dem._ds.height)
            np.testing.assert_array_equal(
                dem._read_window(win, 1).view(np.int32),
                _reference_window(dem, win, 1).view(np.int32),
            )
