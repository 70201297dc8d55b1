"""Hostile DEM input (issue #13): non-finite and impossible heights, undeclared fills in both
directions, complex samples, odd dtypes and geotransforms, vertical units, CF netCDF grids,
latitudes beyond 90 and paths that are not DEM files. Every raster here is real, written with
rasterio in tmp_path and read through the real `open_dem` (and ingest where it matters)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import rasterio
import rasterio.shutil
from affine import Affine
from rasterio.io import MemoryFile

from globeview.errors import DemError
from globeview.terrain.dem.reader import MAX_HEIGHT_M, MIN_HEIGHT_M, open_dem
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.store.tile_store import TileStore

# 100 x 100 cells of 0.01 deg at 5E..6E, 44N..45N; heights 100 .. 2080 m, no two rows equal.
T = Affine(0.01, 0, 5.0, 0, -0.01, 45.0)
ROWS, COLS = np.mgrid[0:100, 0:100]
BASE = (100 + 19 * COLS + ROWS).astype(np.float32)


def _write(path: Path, arr: np.ndarray, **profile: object) -> Path:
    prof: dict[str, object] = {
        "driver": "GTiff",
        "height": arr.shape[-2],
        "width": arr.shape[-1],
        "count": 1 if arr.ndim == 2 else arr.shape[0],
        "dtype": arr.dtype.name,
        "crs": "EPSG:4326",
        "transform": T,
    }
    prof.update(profile)
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(arr if arr.ndim == 3 else arr[None])
    return path


def _grid(path: Path, **kw: object) -> np.ndarray:
    """The whole raster read back at its own cell centres."""
    with open_dem(path, **kw) as dem:  # type: ignore[arg-type]
        return dem.read_grid(5.005, 44.995, 0.01, 0.01, 100, 100)


def _error(path: Path | str, crs: str | None = None) -> str:
    with pytest.raises(DemError) as exc, open_dem(path, crs=crs) as dem:
        _ = dem.info
    msg = str(exc.value)
    assert "\n" not in msg and "Traceback" not in msg
    return msg


# ---- non-finite and impossible heights ------------------------------------------------------


def test_limits_are_the_documented_ones() -> None:
    assert (MIN_HEIGHT_M, MAX_HEIGHT_M) == (-12_000.0, 9_000.0)


def test_infinite_samples_are_nodata_and_counted(tmp_path: Path) -> None:
    a = BASE.copy()
    a[10:40, 10:70] = np.inf
    a[50:60, 50:60] = -np.inf
    p = _write(tmp_path / "inf.tif", a)
    with open_dem(p) as dem:
        info = dem.info
    assert info.masked_samples == 30 * 60 + 10 * 10
    assert (info.vmin, info.vmax) == (100, 2080)
    assert "masked      1900 samples (non-finite or outside -12000..9000 m)" in info.summary()
    g = _grid(p)
    # interior voids are filled from their surroundings like any nodata: no inf, no holes
    assert np.isfinite(g).all()
    assert g.min() >= 100 and g.max() <= 2080


def test_absurd_heights_are_nodata(tmp_path: Path) -> None:
    a = BASE.copy()
    a[30:35, 30:35] = 1e30
    a[0:3, 0:3] = -20_000  # deeper than any ocean
    a[97:, 97:] = 9_500  # higher than Everest
    p = _write(tmp_path / "huge.tif", a)
    with open_dem(p) as dem:
        info = dem.info
    assert info.masked_samples == 25 + 9 + 9
    assert (info.vmin, info.vmax) == (103, 2077)  # the extremes were in the masked corners
    g = _grid(p)
    assert np.nanmax(g) <= 2077 and np.nanmin(g) >= 103
    assert np.isnan(g[0:3, 0:3]).all()  # at the edge: left as nodata, not invented
    assert np.isfinite(g[30:35, 30:35]).all()  # interior: filled


def test_clean_dem_masks_nothing(tmp_path: Path) -> None:
    with open_dem(_write(tmp_path / "ok.tif", BASE)) as dem:
        assert dem.info.masked_samples == 0
        assert "masked" not in dem.info.summary()


def test_limits_apply_after_scale_and_offset(tmp_path: Path) -> None:
    # decimetres stored as int16 with a 0.1 scale: raw 25 000 is 2 500 m, a real height
    a = (BASE * 10).astype(np.int32)
    p = tmp_path / "dm.tif"
    _write(p, a)
    with rasterio.open(p, "r+") as ds:
        ds.scales = (0.1,)
        ds.offsets = (-50.0,)
    with open_dem(p) as dem:
        assert dem.info.masked_samples == 0
        assert dem.info.vmax == pytest.approx(2080 - 50)
    np.testing.assert_allclose(_grid(p), BASE - 50, atol=1e-3)


def test_feet_are_converted_to_metres(tmp_path: Path) -> None:
    # 20 000 ft (6 096 m) is a real height in feet and must not be masked as > 9 000
    a = np.full((100, 100), 20_000.0, dtype=np.float32)
    a[:, 50:] = 1000.0
    p = tmp_path / "feet.tif"
    _write(p, a)
    with rasterio.open(p, "r+") as ds:
        ds.units = ("ft",)
    with open_dem(p) as dem:
        info = dem.info
    assert info.masked_samples == 0
    assert info.vmax == pytest.approx(6096.0)
    assert "converted from ft" in info.summary()
    g = _grid(p)
    assert g[50, 10] == pytest.approx(6096.0) and g[50, 90] == pytest.approx(304.8)
    with rasterio.open(p, "r+") as ds:
        ds.units = ("feet above MSL",)  # a CF-style long unit: the first word is the unit
    with open_dem(p) as dem:
        assert dem.info.vmax == pytest.approx(6096.0)


# ---- undeclared fills ------------------------------------------------------------------------


def test_minus_9999_block_is_fill(tmp_path: Path) -> None:
    a = BASE.astype(np.int16)
    a[60:90, 10:50] = -9999
    p = _write(tmp_path / "f.tif", a)
    with open_dem(p) as dem:
        assert dem.info.fill_value == -9999 and dem.info.vmin == 100
    g = _grid(p)
    assert np.nanmin(g) >= 100


def test_minus_999_corner_is_fill(tmp_path: Path) -> None:
    a = BASE.astype(np.int16)
    a[:20, :20] = -999
    p = _write(tmp_path / "corner.tif", a)
    with open_dem(p) as dem:
        info = dem.info
    assert info.fill_value == -999 and info.vmin == 100 + 20  # the first non-fill cell
    assert info.masked_samples == 0  # a recognised fill is reported as such, not as garbage
    assert "fill value  -999 (undeclared; treated as nodata" in info.summary()
    g = _grid(p)
    assert np.isnan(g[:20, :20]).all() and np.nanmin(g) >= 100


def test_flat_lake_at_zero_is_data(tmp_path: Path) -> None:
    for dtype in (np.float32, np.uint16):
        a = BASE.astype(dtype)
        a[20:60, 20:60] = 0
        p = _write(tmp_path / f"lake_{np.dtype(dtype).name}.tif", a)
        with open_dem(p) as dem:
            assert dem.info.fill_value is None and dem.info.vmin == 0
        assert (_grid(p)[20:60, 20:60] == 0).all()


def test_dead_sea_and_minus_28_lake_are_data(tmp_path: Path) -> None:
    a = BASE - 1000
    a[20:60, 20:60] = -430
    a[70:80, 70:80] = -28
    p = _write(tmp_path / "deadsea.tif", a)
    with open_dem(p) as dem:
        assert dem.info.fill_value is None and dem.info.vmin == -900
    assert (_grid(p)[20:60, 20:60] == -430).all()


def test_minus_999_within_bathymetry_is_data(tmp_path: Path) -> None:
    # -999 m among depths reaching -5 000 m, and a -999 plateau right next to -998: data
    a = BASE * 3 - 5000
    a[40:50, 40:50] = -999
    p = _write(tmp_path / "bathy.tif", a)
    with open_dem(p) as dem:
        assert dem.info.fill_value is None
    b = BASE - 1098  # -998 .. 982
    b[:10, :10] = -999
    q = _write(tmp_path / "floor.tif", b)
    with open_dem(q) as dem:
        assert dem.info.fill_value is None and dem.info.vmin == -999


def test_fill_and_garbage_together(tmp_path: Path) -> None:
    a = BASE.copy()
    a[:10, :10] = -32768  # the fill, outside the limits
    a[40:45, 40:45] = np.inf  # garbage
    p = _write(tmp_path / "both.tif", a)
    with open_dem(p) as dem:
        assert dem.info.fill_value == -32768
        assert dem.info.masked_samples == 25


# ---- sample types and geotransforms ----------------------------------------------------------


@pytest.mark.parametrize("dtype", ["complex64", "complex_int16", "complex128"])
def test_complex_samples_refused(tmp_path: Path, dtype: str) -> None:
    c = (BASE + 1j * BASE).astype(np.complex64 if dtype != "complex128" else np.complex128)
    p = _write(tmp_path / f"{dtype}.tif", c, dtype=dtype)
    msg = _error(p)
    assert msg == f"{p} has complex samples; a DEM needs real heights"


@pytest.mark.parametrize(
    "dtype", ["int8", "uint8", "int16", "uint16", "uint32", "int32", "int64", "uint64", "float64"]
)
def test_other_dtypes_read(tmp_path: Path, dtype: str) -> None:
    a = ((ROWS + COLS) // 2).astype(dtype)  # 0 .. 99 fits every type
    p = _write(tmp_path / f"{dtype}.tif", a)
    with open_dem(p) as dem:
        assert dem.info.dtype == dtype and (dem.info.vmin, dem.info.vmax) == (0, 99)
    np.testing.assert_array_equal(_grid(p), a.astype(np.float32))


def test_multiband_uses_band_one(tmp_path: Path) -> None:
    p = _write(tmp_path / "mb.tif", np.stack([BASE, BASE * 100]))
    with open_dem(p) as dem:
        assert dem.info.band_count == 2 and dem.info.vmax == 2080
        assert "bands       2; band 1 is used as elevation" in dem.info.summary()
    np.testing.assert_array_equal(_grid(p), BASE)


def test_non_square_pixels(tmp_path: Path) -> None:
    p = _write(tmp_path / "ns.tif", BASE, transform=Affine(0.02, 0, 5.0, 0, -0.01, 45.0))
    with open_dem(p) as dem:
        assert dem.info.res_deg == pytest.approx((0.02, 0.01))
        assert dem.info.bounds_lonlat == pytest.approx((5, 44, 7, 45))
        g = dem.read_grid(5.01, 44.995, 0.02, 0.01, 100, 100)
    np.testing.assert_allclose(g, BASE, atol=1e-3)


def test_rotated_geotransform_is_reprojected(tmp_path: Path) -> None:
    # cells of 0.01 deg rotated by 30 degrees about the top-left corner (5E, 45N)
    t = Affine.translation(5.0, 45.0) @ Affine.rotation(30.0) @ Affine.scale(0.01, -0.01)
    p = _write(tmp_path / "rot.tif", BASE, transform=t)
    with open_dem(p) as dem:
        info = dem.info
        corners = [t @ (c, r) for c in (0, 100) for r in (0, 100)]
        lons, lats = zip(*corners)
        assert info.bounds_lonlat == pytest.approx(
            (min(lons), min(lats), max(lons), max(lats)), abs=1e-6
        )
        # the centre of cell (row 40, col 60) reads back its own value
        lon, lat = t @ (60.5, 40.5)
        v = dem.read_grid(lon, lat, 0.001, 0.001, 1, 1)[0, 0]
    assert v == pytest.approx(BASE[40, 60], abs=1.0)


# ---- latitude beyond 90 -----------------------------------------------------------------------


def test_samples_beyond_90_are_refused(tmp_path: Path) -> None:
    p = _write(tmp_path / "lat95.tif", BASE, transform=Affine(1, 0, 0, 0, -1, 95))
    msg = _error(p)
    assert "latitude 94.5" in msg and "beyond" in msg and "--crs" in msg


def test_half_cell_past_the_pole_is_a_pole_centred_grid(tmp_path: Path) -> None:
    # netCDF-style node grid: sample rows at 90, 89, ..., so GDAL's edge is 90.5
    a = np.full((11, 20), 300.0, dtype=np.float32)
    p = _write(tmp_path / "gebco.tif", a, transform=Affine(1, 0, 0, 0, -1, 90.5))
    with open_dem(p) as dem:
        assert dem.info.bounds_lonlat[3] == 90 and dem.info.reaches_pole
        g = dem.read_grid(5.0, 90.0, 1.0, 1.0, 3, 3)
    np.testing.assert_allclose(g, 300.0)


# ---- CF netCDF ---------------------------------------------------------------------------------


def _netcdf(path: Path, arr: np.ndarray, transform: Affine, crs: str | None = None) -> Path:
    """A real CF-1.5 netCDF written by GDAL's netCDF driver (lat/lon axes, degrees)."""
    assert "netCDF" in rasterio.drivers.raster_driver_extensions().values()
    with MemoryFile() as mf:
        with mf.open(
            driver="GTiff",
            height=arr.shape[0],
            width=arr.shape[1],
            count=1,
            dtype=arr.dtype.name,
            crs=crs,
            transform=transform,
        ) as ds:
            ds.write(arr[None])
        with mf.open() as src:
            rasterio.shutil.copy(src, path, driver="netCDF")
    return path


def test_cf_netcdf_lat_lon_is_wgs84(tmp_path: Path) -> None:
    a = (np.arange(18 * 36).reshape(18, 36) * 10).astype(np.float32)  # 0 .. 6470 m
    p = _netcdf(tmp_path / "gebco_like.nc", a, Affine(10, 0, -180, 0, -10, 90))
    with rasterio.open(p) as ds:
        assert ds.crs is None  # the premise: GDAL reports no CRS for it
    with open_dem(p) as dem:
        info = dem.info
        assert info.crs == "EPSG:4326" and info.crs_assumed == "CF lat/lon axes"
        assert "CRS         EPSG:4326 (assumed from CF lat/lon axes)" in info.summary()
        assert info.bounds_lonlat == pytest.approx((-180, -90, 180, 90))
        g = dem.read_grid(-175.0, 85.0, 10.0, 10.0, 36, 18)
    np.testing.assert_allclose(g, a)
    # the real ingest path: a store whose coarsest tile holds the grid's heights
    store = ingest([p], tmp_path / "store", tile_n=4)
    ts = TileStore.open(store.path)
    assert ts.manifest.sources[0].crs == "EPSG:4326"
    h = ts.heights((0, 0, 0))
    assert np.isfinite(h).all() and h.min() >= 0 and h.max() <= a.max()


def test_netcdf_with_crs_is_not_marked_assumed(tmp_path: Path) -> None:
    a = np.ones((18, 36), dtype=np.float32)
    p = _netcdf(tmp_path / "crs.nc", a, Affine(10, 0, -180, 0, -10, 90), crs="EPSG:4326")
    with open_dem(p) as dem:
        assert dem.info.crs == "EPSG:4326" and dem.info.crs_assumed is None
        # The CRS line only: the vertical datum of a plain lon/lat grid is "(assumed)".
        crs_line = next(x for x in dem.info.summary().splitlines() if "CRS" in x)
        assert "assumed" not in crs_line


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")  # the premise
def test_no_georeferencing_still_refused(tmp_path: Path) -> None:
    p = tmp_path / "plain.tif"
    with rasterio.open(p, "w", driver="GTiff", width=10, height=10, count=1, dtype="float32") as ds:
        ds.write(np.ones((1, 10, 10), np.float32))
    assert "no georeferencing" in _error(p)


# ---- paths that are not DEM files -------------------------------------------------------------


def test_directory_and_missing_wording(tmp_path: Path) -> None:
    assert _error(tmp_path) == f"{tmp_path} is a directory, not a DEM file"
    assert _error(tmp_path / "nope.tif") == f"DEM file not found: {tmp_path / 'nope.tif'}"


def test_zero_byte_file(tmp_path: Path) -> None:
    p = tmp_path / "empty.tif"
    p.write_bytes(b"")
    assert _error(p) == f"{p} is empty (0 bytes), not a DEM raster"


def test_symlink_loop_and_dangling_link(tmp_path: Path) -> None:
    a, b = tmp_path / "a.tif", tmp_path / "b.tif"
    os.symlink(b, a)
    os.symlink(a, b)
    assert "symbolic link loop" in _error(a)
    d = tmp_path / "dangling.tif"
    os.symlink(tmp_path / "gone.tif", d)
    msg = _error(d)
    assert msg.startswith(f"DEM file not found: {d}") and "gone.tif" in msg


def test_dangling_vrt_names_the_missing_source(tmp_path: Path) -> None:
    p = tmp_path / "mosaic.vrt"
    p.write_text(
        '<VRTDataset rasterXSize="100" rasterYSize="100"><SRS>EPSG:4326</SRS>'
        "<GeoTransform>5.0, 0.01, 0, 45.0, 0, -0.01</GeoTransform>"
        '<VRTRasterBand dataType="Float32" band="1"><SimpleSource>'
        '<SourceFilename relativeToVRT="1">missing_tile.tif</SourceFilename>'
        "<SourceBand>1</SourceBand></SimpleSource></VRTRasterBand></VRTDataset>"
    )
    msg = _error(p)
    assert "missing_tile.tif" in msg and "does not exist" in msg


def test_unicode_path(tmp_path: Path) -> None:
    d = tmp_path / "höhen 山"
    d.mkdir()
    p = _write(d / "géo ü.tif", BASE)
    with open_dem(p) as dem:
        assert dem.info.path == str(p) and dem.info.vmax == 2080


def test_not_rasters(tmp_path: Path) -> None:
    t = tmp_path / "notes.tif"
    t.write_text("just text\n")
    assert _error(t).startswith(f"cannot read {t} as a raster")
    # a FIFO would block GDAL's open forever: refused before GDAL sees it
    fifo = tmp_path / "pipe.tif"
    os.mkfifo(fifo)
    assert _error(fifo) == f"{fifo} is not a regular file, not a DEM file"


def test_unknown_crs_override(tmp_path: Path) -> None:
    p = _write(tmp_path / "a.tif", BASE)
    msg = _error(p, crs="EPSG:999999")
    assert msg.startswith("unknown CRS 'EPSG:999999'")


def test_gcp_only_raster_refused(tmp_path: Path) -> None:
    from rasterio.control import GroundControlPoint as GCP

    gcps = [GCP(0, 0, 5, 45), GCP(0, 100, 6, 45), GCP(100, 0, 5, 44), GCP(100, 100, 6, 44)]
    p = tmp_path / "gcp.tif"
    with rasterio.open(
        p,
        "w",
        driver="GTiff",
        width=100,
        height=100,
        count=1,
        dtype="float32",
        gcps=gcps,
        crs="EPSG:4326",
    ) as ds:
        ds.write(BASE[None])
    assert "ground control points" in _error(p)


def test_vertical_crs_in_us_feet(tmp_path: Path) -> None:
    # WGS 84 + NAVD88 height (ftUS): the vertical CRS declares the unit, not the band
    import pyproj
    from rasterio.crs import CRS

    crs = CRS.from_wkt(pyproj.CRS("EPSG:4326+6360").to_wkt())
    p = _write(tmp_path / "navd88ft.tif", np.full((100, 100), 20_000.0, np.float32), crs=crs)
    with open_dem(p) as dem:
        assert dem.info.masked_samples == 0
        assert dem.info.vmax == pytest.approx(20_000 * 1200 / 3937)
    np.testing.assert_allclose(_grid(p), 20_000 * 1200 / 3937, rtol=1e-6)


def test_netcdf_with_several_grids_names_them(tmp_path: Path) -> None:
    p = tmp_path / "two.nc"
    with MemoryFile() as mf:
        with mf.open(
            driver="GTiff",
            height=18,
            width=36,
            count=2,
            dtype="float32",
            transform=Affine(10, 0, -180, 0, -10, 90),
        ) as ds:
            ds.write(np.stack([np.full((18, 36), 5.0), np.full((18, 36), 7.0)]).astype("f4"))
        with mf.open() as src:
            rasterio.shutil.copy(src, p, driver="netCDF")
    msg = _error(p)
    assert "holds 2 grids" in msg and f"netcdf:{p}:Band1" in msg
    # the connection string it suggests opens the one grid (GDAL names are not plain files)
    with open_dem(f'NETCDF:"{p}":Band2') as dem:
        assert dem.info.crs_assumed == "CF lat/lon axes" and dem.info.vmax == 7.0


def test_colon_in_a_missing_file_name_is_not_a_gdal_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    p = Path("a:b.tif")  # relative, like `globeview info a:b.tif`
    assert _error(p) == "DEM file not found: a:b.tif"
    _write(p, BASE)
    with open_dem(p) as dem:
        assert dem.info.vmax == 2080


def test_all_garbage_is_no_valid_data(tmp_path: Path) -> None:
    a = np.full((10, 10), np.inf, np.float32)
    a[:5] = 1e30
    msg = _error(_write(tmp_path / "garbage.tif", a))
    assert "holds no valid data" in msg and "-12000..9000 m" in msg


def test_south_up_grid(tmp_path: Path) -> None:
    # rows from south to north (positive y pixel size), as some ASCII and netCDF grids come
    p = _write(tmp_path / "southup.tif", BASE, transform=Affine(0.01, 0, 5.0, 0, 0.01, 44.0))
    with open_dem(p) as dem:
        assert dem.info.bounds_lonlat == pytest.approx((5, 44, 6, 45))  # south < north
        g = dem.read_grid(5.005, 44.995, 0.01, 0.01, 100, 100)
    np.testing.assert_array_equal(g, BASE[::-1])


def test_coordinates_outside_the_crs_domain(tmp_path: Path) -> None:
    # a UTM easting of 1e9 m: PROJ maps it to inf; one line instead of a math domain error
    t = Affine(100, 0, 1e9, 0, -100, 1e9)
    p = _write(tmp_path / "far.tif", BASE, crs="EPSG:32610", transform=t)
    msg = _error(p)
    assert "cannot place" in msg and "EPSG:32610" in msg and "--crs" in msg


def test_degenerate_geotransform(tmp_path: Path) -> None:
    p = tmp_path / "flat.vrt"
    _write(tmp_path / "src.tif", BASE)
    p.write_text(
        '<VRTDataset rasterXSize="100" rasterYSize="100"><SRS>EPSG:4326</SRS>'
        "<GeoTransform>5.0, 0.01, 0, 45.0, 0, 0</GeoTransform>"
        '<VRTRasterBand dataType="Float32" band="1"><SimpleSource>'
        '<SourceFilename relativeToVRT="1">src.tif</SourceFilename>'
        "<SourceBand>1</SourceBand></SimpleSource></VRTRasterBand></VRTDataset>"
    )
    assert "degenerate geotransform" in _error(p)


def test_raster_of_only_a_conventional_fill_has_no_data(tmp_path: Path) -> None:
    p = _write(tmp_path / "allfill.tif", np.full((10, 10), -9999.0, np.float32))
    assert "holds no valid data" in _error(p)
    q = _write(tmp_path / "all999.tif", np.full((10, 10), -999, np.int16))
    assert "holds no valid data" in _error(q)
