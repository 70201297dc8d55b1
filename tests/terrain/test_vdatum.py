"""Vertical datums at ingest (issue #16): stores hold ellipsoidal heights h = H + N.

Real rasters (the SRTM tile, GeoTIFFs with real compound CRSs written here), real ingests, real
`globeview` commands (run in this process, `inprocess_cli`) for the one-line CLI contracts."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine
from inprocess_cli import run_globeview

from globeview.errors import DemError, StoreError
from globeview.terrain.dem.reader import open_dem
from globeview.terrain.dem.vdatum import VerticalDatum, egm96, parse_vdatum
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.store.schema import FORMAT_VERSION
from globeview.terrain.store.tile_store import TileStore

DATA = Path(__file__).resolve().parents[2] / "data"
SRTM = DATA / "N44W072.hgt"


def _cli(*args: str, cache: Path) -> subprocess.CompletedProcess:
    """``globeview ARGS`` run in this process (`inprocess_cli`: its output and exit status
    as a child process would give them) with its cache in ``cache``."""
    return run_globeview(list(args), env={"GLOBEVIEW_CACHE_DIR": str(cache)})


def _finest(store: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The finest level's nodes of a store: heights (rows, cols), node lons, node lats."""
    st = TileStore.open(store)
    g = st.level_grid(st.max_level)
    st.close()
    with rasterio.open(store / g.file_name) as ds:
        z = ds.read(1)
    lons = g.west + g.d * np.arange(g.width)
    lats = g.north - g.d * np.arange(g.height)
    return z, lons, lats


def _tif(path: Path, z: np.ndarray, crs: str, transform: Affine) -> Path:
    wkt = pyproj.CRS(crs).to_wkt()  # compound CRSs by WKT: GDAL writes their vertical keys
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=z.shape[1],
        height=z.shape[0],
        count=1,
        dtype="float32",
        crs=rasterio.crs.CRS.from_wkt(wkt),
        transform=transform,
    ) as ds:
        ds.write(z.astype(np.float32), 1)
    return path


@pytest.fixture(scope="module")
def srtm_stores(tmp_path_factory: pytest.TempPathFactory, seed_dem_store) -> tuple[Path, Path]:
    """N44W072 ingested by default (SRTM -> EGM96) and declared ellipsoidal. The default one
    is what ``ingest([SRTM], out)`` writes (the same files, byte for byte), copied from the
    session's `seed_dem_store` instead of ingested again (~4.5 CPU-s)."""
    base = tmp_path_factory.mktemp("srtm")
    (store,) = (seed_dem_store(tmp_path_factory.mktemp("cache"), SRTM) / "stores").iterdir()
    store.rename(base / "egm96")
    ingest([SRTM], base / "ell", vdatum="ellipsoid")
    return base / "egm96", base / "ell"


@pytest.mark.slow
def test_srtm_store_holds_samples_plus_geoid(srtm_stores: tuple[Path, Path]) -> None:
    conv, _ = srtm_stores
    z, lons, lats = _finest(conv)
    with open_dem(SRTM) as dem:
        H = dem.read_grid(lons[0], lats[0], lons[1] - lons[0], lats[0] - lats[1], *z.T.shape)
    n = egm96().undulation(lons[None, :], lats[:, None])
    ok = np.isfinite(H)
    assert ok.sum() > 1_000_000
    assert np.array_equal(ok, np.isfinite(z))
    np.testing.assert_allclose(z[ok], (H + n)[ok], atol=0.01)
    # The geoid is about 27.5 m below the ellipsoid in the White Mountains: h = H - 27.5.
    assert -28.5 < float(np.mean((z - H)[ok])) < -26.5


@pytest.mark.slow
def test_ellipsoid_declared_stores_samples_unchanged(srtm_stores: tuple[Path, Path]) -> None:
    conv, ell = srtm_stores
    zc, lons, lats = _finest(conv)
    ze, _, _ = _finest(ell)
    ok = np.isfinite(ze)
    n = egm96().undulation(lons[None, :], lats[:, None])
    np.testing.assert_allclose((zc - ze)[ok], n[ok], atol=0.01)
    with open_dem(SRTM) as dem:
        H = dem.read_grid(lons[0], lats[0], lons[1] - lons[0], lats[0] - lats[1], *ze.T.shape)
    np.testing.assert_allclose(ze[ok], H[ok], atol=1e-3)


@pytest.mark.slow
def test_mount_washington_done_when_figure(srtm_stores: tuple[Path, Path]) -> None:
    """h - H at Mount Washington is N there, about -27.5 m."""
    conv, ell = srtm_stores
    zc, lons, lats = _finest(conv)
    ze, _, _ = _finest(ell)
    j = int(np.argmin(np.abs(lons - -71.3033)))
    i = int(np.argmin(np.abs(lats - 44.2705)))
    n = float(egm96().undulation(lons[j], lats[i]))
    assert n == pytest.approx(-27.5, abs=0.1)
    assert float(zc[i, j] - ze[i, j]) == pytest.approx(n, abs=0.01)


def test_manifest_records_the_datum(srtm_stores: tuple[Path, Path]) -> None:
    conv, ell = srtm_stores
    src = json.loads((conv / "manifest.json").read_text())["sources"][0]
    assert src["vertical_datum"] == "egm96"
    assert src["vertical_datum_source"] == "SRTM .hgt default"
    assert src["heights"].startswith("converted to ellipsoidal heights with EGM96 (egm96_15.tif")
    assert "sha256 " in src["heights"]
    src = json.loads((ell / "manifest.json").read_text())["sources"][0]
    assert (src["vertical_datum"], src["vertical_datum_source"]) == ("ellipsoid", "--vdatum")


def _grid(tmp_path: Path, crs: str) -> Path:
    z = np.linspace(100.0, 900.0, 60 * 40).reshape(40, 60)
    return _tif(tmp_path / "g.tif", z, crs, Affine(0.01, 0, 10.0, 0, -0.01, 47.0))


@pytest.mark.slow
@pytest.mark.parametrize(
    ("crs", "datum", "converted"),
    [("EPSG:4979", "ellipsoid", False), ("EPSG:4326+5773", "egm96", True)],
)
def test_datum_from_the_crs(tmp_path: Path, crs: str, datum: str, converted: bool) -> None:
    src = _grid(tmp_path, crs)
    with open_dem(src) as dem:
        assert dem.info.vertical_datum == datum
        assert dem.info.vertical_datum_source.startswith("from the CRS EPSG:")
    ingest([src], tmp_path / "s")
    z, lons, lats = _finest(tmp_path / "s")
    with open_dem(src) as dem:
        H = dem.read_grid(lons[0], lats[0], lons[1] - lons[0], lats[0] - lats[1], *z.T.shape)
    ok = np.isfinite(H)
    assert ok.sum() > 100
    n = egm96().undulation(lons[None, :], lats[:, None]) if converted else 0.0
    np.testing.assert_allclose(z[ok], (H + n)[ok], atol=0.01)
    # The Alps: N ~ 48 m on the DEM's nodes (format 7's level grid is the bbox of its chunks,
    # whole 1024-node windows reaching well past the DEM, where N is smaller).
    assert not converted or float(np.min(np.abs(np.broadcast_to(n, z.shape)[ok]))) > 40


def test_defaults_per_source(tmp_path: Path) -> None:
    with open_dem(SRTM) as dem:
        assert (dem.info.vertical_datum, dem.info.vertical_datum_source) == (
            "egm96",
            "SRTM .hgt default",
        )
    with open_dem(DATA / "etopo20.tif") as dem:
        assert dem.info.vertical_datum == "egm96"
        assert "mean sea level" in dem.info.vertical_datum_source
    with open_dem(_grid(tmp_path, "EPSG:4326")) as dem:
        assert (dem.info.vertical_datum, dem.info.vertical_datum_source) == ("egm96", "assumed")
    with open_dem(_grid(tmp_path, "EPSG:4326+5773"), vdatum="ellipsoid") as dem:
        assert (dem.info.vertical_datum, dem.info.vertical_datum_source) == (
            "ellipsoid",
            "--vdatum",
        )


def test_other_vertical_crs_is_approximated_and_said(tmp_path: Path) -> None:
    z = np.full((20, 20), 300.0)
    src = _tif(tmp_path / "utm.tif", z, "EPSG:32619+5703", Affine(30, 0, 300000, 0, -30, 4900000))
    with open_dem(src) as dem:
        assert dem.info.vertical_datum == "egm96"
        assert "EPSG:5703" in dem.info.vertical_datum_source
        assert "approximated by EGM96" in dem.info.vertical_datum_source


def test_height_limits_apply_before_conversion(tmp_path: Path) -> None:
    """8995 m is a possible height above sea level; +17 m of N at 0,0 must not mask it."""
    z = np.full((20, 20), 8995.0)
    src = _tif(tmp_path / "hi.tif", z, "EPSG:4326", Affine(0.01, 0, -0.1, 0, -0.01, 0.1))
    ingest([src], tmp_path / "s")
    zs, _, _ = _finest(tmp_path / "s")
    n0 = float(egm96().undulation(0.0, 0.0))
    assert n0 > 10
    assert np.nanmax(zs) == pytest.approx(8995.0 + n0, abs=0.2)


def test_vdatum_names() -> None:
    assert parse_vdatum("EGM96") is VerticalDatum.EGM96
    assert parse_vdatum("ellipsoid") is VerticalDatum.ELLIPSOID
    assert parse_vdatum("EGM2008") is VerticalDatum.EGM2008
    with pytest.raises(DemError, match="unknown vertical datum"):
        parse_vdatum("navd88x")
    h = VerticalDatum.EGM96.to_ellipsoidal(np.array([100.0]), -71.3033, 44.2705)
    assert float(h[0]) == pytest.approx(100.0 - 27.52, abs=0.05)
    back = VerticalDatum.EGM96.from_ellipsoidal(h, -71.3033, 44.2705)
    assert float(back[0]) == pytest.approx(100.0)


@pytest.mark.slow
def test_egm2008_without_its_grid_is_one_line_everywhere(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--vdatum egm2008 is known (issue #25); where no EGM2008 grid is on the machine, ingest
    and render (which ingests into the cache) say so in one line; info names the datum."""
    from globeview.terrain.dem import vdatum

    monkeypatch.delenv(vdatum.GEOID_GRIDS_ENV, raising=False)
    monkeypatch.setattr(vdatum, "_proj_dirs", lambda: [tmp_path / "no-proj"])
    for args in (
        ["ingest", str(SRTM), "--out", str(tmp_path / "s"), "--vdatum", "egm2008"],
        ["render", str(SRTM), "--out", str(tmp_path / "x.png"), "--vdatum", "egm2008"],
    ):
        r = _cli(*args, cache=tmp_path / "cache")
        assert r.returncode == 2, (args, r.stderr)
        assert r.stderr.startswith("globeview: error: ") and len(r.stderr.splitlines()) == 1
        assert "heights are on EGM2008 (--vdatum) and no EGM2008 grid" in r.stderr
    assert not (tmp_path / "s").exists() and not (tmp_path / "x.png").exists()
    r = _cli("info", str(SRTM), "--vdatum", "egm2008", cache=tmp_path / "cache")
    assert r.returncode == 0, r.stderr
    assert "vdatum      EGM2008 geoid (--vdatum)" in r.stdout


@pytest.mark.slow
def test_info_says_the_datum_and_where_it_came_from(tmp_path: Path) -> None:
    r = _cli("info", str(SRTM), cache=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "vdatum      EGM96 geoid (SRTM .hgt default)" in r.stdout
    r = _cli("info", str(_grid(tmp_path, "EPSG:4326+5773")), cache=tmp_path)
    assert "EGM96 geoid (from the CRS EPSG:5773)" in r.stdout
    r = _cli("info", str(SRTM), "--vdatum", "ellipsoid", "--json", cache=tmp_path)
    d = json.loads(r.stdout)[0]
    assert (d["vertical_datum"], d["vertical_datum_source"]) == ("ellipsoid", "--vdatum")


def _as_version_3(store: Path) -> None:
    man = json.loads((store / "manifest.json").read_text())
    man["format_version"] = 3
    (store / "manifest.json").write_text(json.dumps(man))


def test_store_built_before_vdatums_is_refused_in_one_line(tmp_path: Path) -> None:
    """A store of format 3 at --out (a small grid's: the refusal and the forced rebuild are
    the same for any source, the SRTM tile's rebuild cost ~2 CPU-s)."""
    src, old = _grid(tmp_path, "EPSG:4326"), tmp_path / "old"
    ingest([src], old, vdatum="ellipsoid")
    _as_version_3(old)
    with pytest.raises(StoreError, match="built before vertical datums"):
        TileStore.open(old)
    before = (old / "manifest.json").read_bytes()
    r = _cli("ingest", str(src), "--out", str(old), "--quiet", cache=tmp_path / "cache")
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1
    assert "built before vertical datums" in r.stderr and "--force" in r.stderr
    assert (old / "manifest.json").read_bytes() == before
    r = _cli("ingest", str(src), "--out", str(old), "--quiet", "--force", cache=tmp_path / "c")
    assert r.returncode == 0, r.stderr
    assert json.loads((old / "manifest.json").read_text())["format_version"] == FORMAT_VERSION


def test_cached_store_built_before_vdatums_is_rebuilt_silently(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from globeview.terrain.sources import open_source, store_path_for

    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path))
    src = _grid(tmp_path, "EPSG:4326")
    open_source(src).close()
    cached = store_path_for(src)
    _as_version_3(cached)
    st = open_source(src)
    assert st.manifest.header.format_version == FORMAT_VERSION
    assert st.manifest.sources[0].vertical_datum == "egm96"
    st.close()


def test_unreadable_geoid_is_one_line_and_no_store(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A damaged installation (geoid file truncated) fails the ingest in one DemError line and
    leaves nothing behind."""
    from globeview.terrain.dem import vdatum

    bad = tmp_path / "egm96_15.tif"
    bad.write_bytes(vdatum.geoid_path().read_bytes()[:5000])
    monkeypatch.setattr(vdatum, "geoid_path", lambda: bad)
    monkeypatch.setattr(vdatum, "_cache", {})
    with pytest.raises(DemError, match="cannot read the EGM96 geoid") as err:
        ingest([_grid(tmp_path, "EPSG:4326")], tmp_path / "s")
    assert "\n" not in str(err.value)
    assert not (tmp_path / "s").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["egm96_15.tif", "g.tif"]  # no build


# -- geoid grids not shipped (issue #25: Copernicus heights are EGM2008) ----------------------


def test_geoid_grids_from_the_option_the_environment_and_proj(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from globeview.terrain.dem import vdatum
    from tests.terrain.planet_tiles import write_geoid_grid, write_geotiff

    grid = write_geoid_grid(tmp_path / "g.tif", 2.0)
    assert vdatum.parse_geoid_grids([str(grid)]) == {"egm2008": grid}
    half = write_geotiff(tmp_path / "half.tif", -180.0, 90.0, 2.0, 90)
    with pytest.raises(DemError, match=r"half\.tif: a geoid grid must cover the globe; this one "):
        vdatum.parse_geoid_grids([str(half)])
    assert vdatum.parse_geoid_grids([f"EGM2008={grid}"]) == {"egm2008": grid}
    with pytest.raises(DemError, match=r"unknown geoid 'egm84' \(known: egm2008\)"):
        vdatum.parse_geoid_grids([f"egm84={grid}"])
    (tmp_path / "text.tif").write_text("no grid")
    with pytest.raises(DemError, match=r"text\.tif: not a geoid grid GDAL can read"):
        vdatum.parse_geoid_grids([str(tmp_path / "text.tif")])
    projected = write_geotiff(tmp_path / "utm.tif", 500000.0, 5e6, 1000.0, 10, crs="EPSG:32618")
    with pytest.raises(DemError, match="a geoid grid must be on lon/lat"):
        vdatum.parse_geoid_grids([str(projected)])
    # Nowhere: None (PROJ's folders looked in are empty ones here).
    monkeypatch.setattr(vdatum, "_proj_dirs", lambda: [tmp_path / "proj"])
    monkeypatch.delenv(vdatum.GEOID_GRIDS_ENV, raising=False)
    assert vdatum.find_geoid_grid("egm2008") is None
    monkeypatch.setenv(vdatum.GEOID_GRIDS_ENV, f"egm2008={grid}")
    assert vdatum.find_geoid_grid("egm2008") == grid
    monkeypatch.setenv(vdatum.GEOID_GRIDS_ENV, f"egm2008={tmp_path / 'gone.tif'}")
    with pytest.raises(DemError, match=r"\$GLOBEVIEW_GEOID_GRIDS egm2008=.*gone.tif: no such file"):
        vdatum.find_geoid_grid("egm2008")
    monkeypatch.delenv(vdatum.GEOID_GRIDS_ENV)
    (tmp_path / "proj").mkdir()
    (tmp_path / "proj" / "us_nga_egm08_25.tif").write_bytes(grid.read_bytes())
    assert vdatum.find_geoid_grid("egm2008") == tmp_path / "proj" / "us_nga_egm08_25.tif"
    # --geoid-grid wins over both.
    assert vdatum.find_geoid_grid("egm2008", {"egm2008": grid}) == grid


@pytest.mark.parametrize(
    ("west", "south", "east", "north"),
    [
        (-72.3, 44.1, -71.2, 45.4),  # a chunk over N44W072
        (-0.01, -0.02, 0.01, 0.01),  # inside one grid cell
        (178.5, -17.5, -178.7, -16.2),  # across the antimeridian
        (170.0, 80.0, 180.0, 90.0),  # the north pole and lon 180
        (-180.0, -90.0, -179.0, -88.5),  # the south pole and the grid's first column
    ],
)
def test_a_geoid_window_interpolates_as_the_whole_grid(
    west: float, south: float, east: float, north: float
) -> None:
    """`grid_window` reads a few rows and columns of a grid file; N on a window's nodes is
    the whole grid's (the shipped EGM96 grid standing in for EGM2008's)."""
    from globeview.terrain.dem import vdatum

    span = (east - west) % 360.0
    lons = west + np.linspace(0.0, span, 37)
    lats = np.linspace(north, south, 29)
    win = vdatum.grid_window(vdatum.geoid_path(), west, south, east, north)
    whole = vdatum.egm96()
    np.testing.assert_allclose(
        win.undulation_grid(lons, lats), whole.undulation_grid(lons, lats), rtol=0, atol=1e-9
    )
    if span < 10:  # a few rows (across the grid's seam: whole rows), not the grid
        assert win.grid.shape[0] < whole.grid.shape[0] / 20
        assert win.grid.shape[1] < whole.grid.shape[1] / 20 or win.wraps
