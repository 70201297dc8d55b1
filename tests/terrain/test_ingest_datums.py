"""Sources on different vertical datums in one build (issue #25, design §4.6).

An SRTM tile (EGM96: the shipped grid), a Copernicus-named tile (EGM2008 by its name), a
GeoTIFF whose CRS says EGM2008 (EPSG:4326+3855) and an ellipsoidal GeoTIFF (EPSG:4979) built
together hold ellipsoidal heights h = H + N everywhere, each source converted with its own
geoid. EGM2008's grid is a synthetic global grid laid out as PROJ's us_nga_egm08_25.tif
(Debian's proj-data 9.1.1 does not ship that file), and N is checked against PROJ's own
vgridshift on that grid, not against globeview's interpolation. The build reads the grid a
chunk's window at a time; without the grid, the build is one line before anything is written.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine

from globeview.errors import DemError
from globeview.terrain.dem import vdatum
from globeview.terrain.dem.vdatum import egm96, grid_sha256, undulation_on_grid
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.store.tile_store import TileStore
from tests.cli.run_cli import globeview_here, one_error_line
from tests.terrain.planet_tiles import copernicus_name, geoid_n, write_geoid_grid

#: Orthometric (or ellipsoidal) height of each constant source, m.
H = {"srtm": 100.0, "cop": 200.0, "ell": 300.0, "crs": 400.0}
#: West edge of each source's 1-degree cell at 44..45 N.
WEST = {"srtm": -72.0, "cop": -71.0, "ell": -70.0, "crs": -69.0}
RES = 1.0 / 120.0  # 30": the GeoTIFFs are 120 x 120


def _proj_n(grid: Path, lons: np.ndarray, lats: np.ndarray) -> np.ndarray:
    """N from PROJ's vgridshift on ``grid`` (h = H + N: the shift of a zero height)."""
    t = pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        f"+step +proj=vgridshift +grids={grid} +multiplier=1 "
        "+step +proj=unitconvert +xy_in=rad +xy_out=deg"
    )
    lo, la = np.broadcast_arrays(lons, lats)
    _, _, z = t.transform(lo.ravel(), la.ravel(), np.zeros(lo.size))
    return np.asarray(z).reshape(lo.shape)


def _tif(path: Path, value: float, west: float, crs: str) -> Path:
    """A constant 1 x 1 degree 30" GeoTIFF at (west..west+1, 44..45); compound CRSs by WKT."""
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=120,
        height=120,
        count=1,
        dtype="float32",
        crs=rasterio.crs.CRS.from_wkt(pyproj.CRS(crs).to_wkt()),
        transform=Affine(RES, 0, west, 0, -RES, 45.0),
    ) as ds:
        ds.write(np.full((120, 120), value, dtype=np.float32), 1)
    return path


def _sources(folder: Path) -> list[Path]:
    hgt = folder / "N44W072.hgt"
    np.full((1201, 1201), H["srtm"], dtype=">i2").tofile(hgt)  # SRTM 3": the real size
    return [
        hgt,
        _tif(folder / copernicus_name(44, -71), H["cop"], WEST["cop"], "EPSG:4326"),
        _tif(folder / "ellipsoidal.tif", H["ell"], WEST["ell"], "EPSG:4979"),
        _tif(folder / "egm2008_crs.tif", H["crs"], WEST["crs"], "EPSG:4326+3855"),
    ]


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """The four sources built to level 8 with the synthetic EGM2008 grid; the sizes (nodes)
    of the grid windows the build read."""
    base = tmp_path_factory.mktemp("datums")
    grid = write_geoid_grid(base / "egm08_synthetic.tif")
    sources = _sources(base)
    windows: list[int] = []
    real = vdatum._read_window

    def spy(path: str, i0: int, i1: int, j0: int, j1: int) -> np.ndarray:
        windows.append((i1 - i0 + 1) * (j1 - j0 + 1))
        return real(path, i0, i1, j0, j1)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(vdatum, "_read_window", spy)
        mp.delenv(vdatum.GEOID_GRIDS_ENV, raising=False)
        ingest(sources, base / "s", max_level=8, workers=1, geoid_grids={"egm2008": grid})
    return {"store": base / "s", "grid": grid, "sources": sources, "windows": windows}


def _finest(store: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The finest level's nodes of a store: heights (rows, cols), node lons, node lats."""
    with TileStore.open(store) as st:
        g = st.level_grid(st.max_level)
    with rasterio.open(store / g.file_name) as ds:
        z = ds.read(1)
    return z, g.west + g.d * np.arange(g.width), g.north - g.d * np.arange(g.height)


def test_each_source_is_converted_with_its_own_geoid(mixed: dict) -> None:
    z, lons, lats = _finest(mixed["store"])
    rows = (lats > 44.05) & (lats < 44.95)
    for name, west in WEST.items():
        cols = (lons > west + 0.05) & (lons < west + 0.95)
        got = z[np.ix_(rows, cols)]
        lo, la = lons[cols][None, :], lats[rows][:, None]
        if name == "srtm":
            n = egm96().undulation(lo, la)
        elif name == "ell":
            n = np.zeros(got.shape)
        else:
            n = _proj_n(mixed["grid"], lo, la)
            # Not EGM96's N (tens of metres apart here): the source's own geoid.
            assert np.abs(n - egm96().undulation(lo, la)).min() > 10
        assert got.size > 500 and np.isfinite(got).all(), name
        np.testing.assert_allclose(got, H[name] + n, atol=2e-3, err_msg=name)


def test_the_manifest_names_each_datum_and_grid(mixed: dict) -> None:
    src = json.loads((mixed["store"] / "manifest.json").read_text())["sources"]
    got = [(s["vertical_datum"], s["vertical_datum_source"]) for s in src]
    assert got == [
        ("egm96", "SRTM .hgt default"),
        ("egm2008", "Copernicus DEM default"),
        ("ellipsoid", "from the CRS EPSG:4979"),
        ("egm2008", "from the CRS EPSG:3855"),
    ]
    grid = mixed["grid"]
    note = f"converted to ellipsoidal heights with EGM2008 ({grid.name} sha256 {grid_sha256(grid)})"
    assert src[1]["heights"] == src[3]["heights"] == note
    assert src[0]["heights"].startswith("converted to ellipsoidal heights with EGM96")


def test_the_build_reads_chunk_windows_of_the_grid_not_the_grid(mixed: dict) -> None:
    windows = mixed["windows"]
    assert windows, "the EGM2008 grid was never read"
    whole = 361 * 181
    assert max(windows) < whole / 50, (max(windows), whole)


def test_a_grid_change_rebuilds_and_the_same_grid_is_up_to_date(
    mixed: dict, tmp_path: Path
) -> None:
    grid, sources = mixed["grid"], mixed["sources"]
    store = tmp_path / "s"
    shutil.copytree(mixed["store"], store)
    again = ingest(sources, store, max_level=8, workers=1, geoid_grids={"egm2008": grid})
    assert again.up_to_date
    other = tmp_path / "other.tif"
    with rasterio.open(grid) as ds:
        prof, n = ds.profile, ds.read(1)
    with rasterio.open(other, "w", **prof) as ds:
        ds.write(n + 5.0, 1)
        ds.update_tags(AREA_OR_POINT="Point")
    redone = ingest(sources[1:2], tmp_path / "cop", max_level=6, geoid_grids={"egm2008": grid})
    z0, _, _ = _finest(redone.path)
    redone = ingest(sources[1:2], tmp_path / "cop", max_level=6, geoid_grids={"egm2008": other})
    assert not redone.up_to_date
    z1, _, _ = _finest(redone.path)
    ok = np.isfinite(z0)
    assert ok.sum() > 100
    np.testing.assert_allclose(z1[ok] - z0[ok], 5.0, atol=1e-3)


@pytest.mark.parametrize("closed", [True, False])
def test_window_undulations_are_projs_across_the_antimeridian_and_poles(
    tmp_path: Path, closed: bool
) -> None:
    """A level window's nodes may run past +180 (its columns are global indices) and reach
    the poles; N there is PROJ's, for a grid with a +180 column and for one that wraps."""
    grid = write_geoid_grid(tmp_path / "g.tif", 2.0, closed=closed)
    for lons, lats in (
        (178.3 + 0.37 * np.arange(20), np.linspace(-16.0, -19.0, 9)),
        (-180.0 + 0.5 * np.arange(30), np.linspace(90.0, 86.5, 8)),
        (np.linspace(-180.0, 179.0, 50), np.linspace(-85.0, -90.0, 6)),
    ):
        got = undulation_on_grid("egm2008", str(grid), lons, lats)
        lon_n = (lons + 180.0) % 360.0 - 180.0
        want = _proj_n(grid, lon_n[None, :], lats[:, None])
        np.testing.assert_allclose(got, want, atol=1e-6)
    # The synthetic geoid's own values at a node, as written.
    assert undulation_on_grid("egm2008", str(grid), np.array([10.0]), np.array([20.0]))[
        0, 0
    ] == pytest.approx(float(geoid_n(10.0, 20.0)), abs=1e-4)


@pytest.fixture
def no_grid(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """No EGM2008 grid anywhere: not in the environment, not in PROJ's folders."""
    monkeypatch.delenv(vdatum.GEOID_GRIDS_ENV, raising=False)
    monkeypatch.setattr(vdatum, "_proj_dirs", lambda: [tmp_path / "no-proj"])


def _missing(name: str, why: str) -> str:
    return (
        f"{name}: heights are on EGM2008 ({why}) and no EGM2008 grid is on this machine; get "
        "us_nga_egm08_25.tif (https://cdn.proj.org/us_nga_egm08_25.tif) and pass --geoid-grid "
        "egm2008=PATH, or --vdatum egm96 to approximate (about 1 m)"
    )


def test_without_the_grid_the_build_is_one_line_and_writes_nothing(
    mixed: dict, tmp_path: Path, no_grid: None
) -> None:
    cop, ell, crs = mixed["sources"][1:]
    out = tmp_path / "out"
    out.mkdir()
    for srcs, name, why in (
        ([ell, cop], cop.name, "Copernicus DEM default"),
        ([ell, crs], crs.name, "from the CRS EPSG:3855"),
        ([ell], ell.name, "--vdatum"),
    ):
        vd = "egm2008" if why == "--vdatum" else None
        with pytest.raises(DemError) as err:
            ingest(srcs, out / "s", vdatum=vd, workers=1)
        assert str(err.value) == _missing(name, why)
        assert list(out.iterdir()) == []  # no store, no building folder, no lock


def test_the_cli_builds_with_geoid_grid_and_refuses_without(
    mixed: dict, tmp_path: Path, no_grid: None
) -> None:
    cop, grid = mixed["sources"][1], mixed["grid"]
    out = tmp_path / "s"
    line = one_error_line(globeview_here("ingest", str(cop), "--out", str(out), cache=tmp_path))
    assert line == "globeview: error: " + _missing(cop.name, "Copernicus DEM default")
    assert not out.exists()
    args = ("ingest", str(cop), "--out", str(out), "--max-level", "6", "--quiet")
    ok = globeview_here(*args, "--geoid-grid", f"egm2008={grid}", cache=tmp_path)
    assert ok.returncode == 0, ok.stderr
    src = json.loads((out / "manifest.json").read_text())["sources"][0]
    assert src["vertical_datum"] == "egm2008" and grid.name in src["heights"]
    approx = globeview_here(*args, "--vdatum", "egm96", "--force", cache=tmp_path)
    assert approx.returncode == 0, approx.stderr


def test_point_conversions_use_the_grid_found_or_say_it_is_missing(
    mixed: dict, tmp_path: Path, no_grid: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    lon, lat = np.array([-70.3, 12.34]), np.array([44.2, -33.3])
    with pytest.raises(DemError, match=r"no EGM2008 grid is on this machine"):
        vdatum.VerticalDatum.EGM2008.to_ellipsoidal(np.zeros(2), lon, lat)
    monkeypatch.setenv(vdatum.GEOID_GRIDS_ENV, f"egm2008={mixed['grid']}")
    h = vdatum.VerticalDatum.EGM2008.to_ellipsoidal(np.array([100.0, 0.0]), lon, lat)
    np.testing.assert_allclose(h, np.array([100.0, 0.0]) + _proj_n(mixed["grid"], lon, lat))
    back = vdatum.VerticalDatum.EGM2008.from_ellipsoidal(h, lon, lat)
    np.testing.assert_allclose(back, [100.0, 0.0], atol=1e-9)


def _chunk_files(store: Path) -> dict[str, bytes]:
    return {p.relative_to(store).as_posix(): p.read_bytes() for p in store.glob("chunks/**/*.tif")}


@pytest.mark.slow
def test_worker_processes_convert_with_the_grid_as_threads_do(mixed: dict, tmp_path: Path) -> None:
    """The grid's path travels in each task's source spec; a process pool's workers read their
    own windows of it and write the same chunk files, byte for byte."""
    sources, grid = mixed["sources"], {"egm2008": mixed["grid"]}
    one = ingest(sources[1:], tmp_path / "t", max_level=7, workers=1, geoid_grids=grid)
    two = ingest(
        sources[1:], tmp_path / "p", max_level=7, workers=2, scheduler="processes", geoid_grids=grid
    )
    files = _chunk_files(one.path)
    assert len(files) > 3 and files == _chunk_files(two.path)
