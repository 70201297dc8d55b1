"""The EGM96 geoid: N at the grid's nodes is the grid's value, bilinear between them, wrapping at
the antimeridian and flat on the pole rows; checked against the grid's nodes read by hand
(without `Geoid`): the original GTX file where the development checkout has it
(``../shared/data/egm96_15.gtx``, the source of the embedded copy), else the embedded GeoTIFF
``data/egm96_15.tif`` read with rasterio, so that a clean clone runs every check."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import rasterio

from globeview.geodesy.geoid import Geoid
from globeview.terrain.dem.vdatum import geoid_path

#: The original grid, next to the checkout; absent in a clean clone.
GTX = Path(__file__).resolve().parents[3] / "shared" / "data" / "egm96_15.gtx"

#: A GTX header: (south lat, west lon, dlat, dlon, rows, cols), degrees and counts.
Header = tuple[float, float, float, float, int, int]


def _raw_gtx(path: Path) -> tuple[np.ndarray, Header]:
    """A GTX file read without GDAL: a 40-byte big-endian header (south lat, west lon,
    dlat, dlon, rows, cols) then rows of big-endian float32 from the south."""
    raw = path.read_bytes()
    header: Header = struct.unpack(">4d2i", raw[:40])
    rows, cols = header[4], header[5]
    grid = np.frombuffer(raw[40:], dtype=">f4").reshape(rows, cols).astype(np.float64)
    return grid, header


def _raw_embedded() -> tuple[np.ndarray, Header]:
    """The embedded GeoTIFF's nodes as `_raw_gtx` gives them (rows from the south, the same
    header), read with rasterio: pixel-is-point, so node (0, 0) is half a cell inside the
    corner of GDAL's transform."""
    with rasterio.open(geoid_path()) as ds:
        grid = ds.read(1).astype(np.float64)[::-1]
        t = ds.transform
    rows, cols = grid.shape
    west, north = t.c + t.a / 2, t.f + t.e / 2
    return grid, (north + (rows - 1) * t.e, west, -t.e, t.a, rows, cols)


def _raw_grid() -> tuple[np.ndarray, Header]:
    """The EGM96 nodes read by hand: the original GTX where present, else the embedded copy."""
    return _raw_gtx(GTX) if GTX.exists() else _raw_embedded()


def _gtx_for_proj(tmp_path: Path) -> Path:
    """A GTX file for PROJ's vgridshift: the original, or one written from the embedded
    GeoTIFF's nodes (PROJ does not read that GeoTIFF as a grid)."""
    if GTX.exists():
        return GTX
    grid, header = _raw_embedded()
    out = tmp_path / "egm96_15.gtx"
    out.write_bytes(struct.pack(">4d2i", *header) + grid.astype(">f4").tobytes())
    return out


@pytest.fixture(scope="module")
def egm96():
    from globeview.terrain.dem.vdatum import egm96

    return egm96()


def test_shipped_grid_equals_the_source_nodes(egm96):
    grid, (south, west, dlat, dlon, rows, cols) = _raw_grid()
    assert (south, west, dlat, dlon, rows, cols) == (-90.0, -180.0, 0.25, 0.25, 721, 1440)
    rng = np.random.default_rng(16)
    i = rng.integers(0, rows, 500)
    j = rng.integers(0, cols, 500)
    lon = west + j * dlon
    lat = south + i * dlat
    np.testing.assert_allclose(egm96.undulation(lon, lat), grid[i, j], atol=1e-9)


def test_bilinear_midway_between_nodes_by_hand(egm96):
    grid, _ = _raw_grid()
    # Cell with south-west node (lon -71.5, lat 44.0): GTX row (44+90)/0.25, col (180-71.5)/0.25.
    i, j = int((44.0 + 90) / 0.25), int((-71.5 + 180) / 0.25)
    sw, se, nw, ne = grid[i, j], grid[i, j + 1], grid[i + 1, j], grid[i + 1, j + 1]
    assert egm96.undulation(-71.375, 44.125) == pytest.approx((sw + se + nw + ne) / 4, abs=1e-9)
    # A quarter of the way east and three quarters north.
    u, v = 0.25, 0.75
    want = (sw * (1 - u) + se * u) * (1 - v) + (nw * (1 - u) + ne * u) * v
    assert egm96.undulation(-71.5 + u * 0.25, 44.0 + v * 0.25) == pytest.approx(want, abs=1e-9)


def test_mount_washington_is_about_minus_27_5(egm96):
    assert egm96.undulation(-71.3033, 44.2705) == pytest.approx(-27.5, abs=0.1)


def test_wraps_across_the_antimeridian(egm96):
    grid, _ = _raw_grid()
    i = int((10.0 + 90) / 0.25)
    # Between the last column (179.75) and +180 (== column 0, -180).
    want = (grid[i, -1] + grid[i, 0]) / 2
    assert egm96.undulation(179.875, 10.0) == pytest.approx(want, abs=1e-9)
    assert egm96.undulation(-180.125, 10.0) == pytest.approx(want, abs=1e-9)
    lon = np.array([180.0, -180.0, 540.0, 10.0, 370.0])
    n = egm96.undulation(lon, np.full(5, 10.0))
    assert n[0] == pytest.approx(grid[i, 0]) and n[1] == pytest.approx(grid[i, 0])
    assert n[2] == pytest.approx(n[0]) and n[3] == pytest.approx(n[4])


def test_poles_read_the_pole_rows(egm96):
    grid, _ = _raw_grid()
    lons = np.linspace(-180, 180, 37)
    np.testing.assert_allclose(egm96.undulation(lons, 90.0), grid[-1, 0], atol=1e-9)
    np.testing.assert_allclose(egm96.undulation(lons, -90.0), grid[0, 0], atol=1e-9)
    # Past the pole clamps to it instead of indexing out of the grid.
    assert egm96.undulation(0.0, 91.0) == pytest.approx(grid[-1, 0])


def test_non_finite_points_give_nan(egm96):
    n = egm96.undulation(np.array([np.nan, 0.0, np.inf]), np.array([0.0, np.nan, 0.0]))
    assert np.isnan(n).all()


def test_undulation_grid_equals_pointwise(egm96):
    lons = np.linspace(-200.0, 200.0, 57)
    lats = np.linspace(90.0, -90.0, 41)
    mesh = egm96.undulation(lons[None, :], lats[:, None])
    np.testing.assert_allclose(egm96.undulation_grid(lons, lats), mesh, atol=1e-9)


def test_small_regional_grid_clamps_instead_of_wrapping():
    g = Geoid(np.array([[0.0, 10.0], [20.0, 30.0]]), west=0.0, north=1.0, dlon=1.0, dlat=1.0)
    assert not g.wraps
    assert g.undulation(0.5, 0.5) == pytest.approx(15.0)
    assert g.undulation(5.0, 1.0) == pytest.approx(10.0)


def test_agrees_with_proj_vgridshift_on_the_raw_gtx(egm96, tmp_path: Path):
    """PROJ's own grid interpolation (``vgridshift``) of a GTX file gives the same N as our
    bilinear on the shipped GeoTIFF: an independent implementation, and with the original GTX
    an independent file too (without it, the embedded nodes written as a GTX).
    (PROJ's EPSG:4326+5773 -> 4979 would need its us_nga_egm96_15.tif, not installed here.)"""
    import pyproj

    t = pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        f"+step +proj=vgridshift +grids={_gtx_for_proj(tmp_path)} +multiplier=1 "
        "+step +proj=unitconvert +xy_in=rad +xy_out=deg"
    )
    lon = np.array([-71.3033, 10.0, 179.9, -120.0, 0.1, 33.3, -179.99])
    lat = np.array([44.2705, -33.0, 60.0, 0.0, 89.9, -77.7, -45.123])
    _, _, h = t.transform(lon, lat, np.zeros(lon.size))
    np.testing.assert_allclose(egm96.undulation(lon, lat), h, atol=1e-3)
