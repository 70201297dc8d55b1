"""Pyramid build: level rasters, exact tile errors, wavelet levels, sources, poles, atomicity,
bad input."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from globeview.errors import DemError, GlobeviewError, StoreError
from globeview.terrain.dem.reader import open_dem
from globeview.terrain.ingest import schedule as ingest_graph
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.ingest.wavelet import approximate_grid
from globeview.terrain.quadtree import TileKey, tile_bounds
from globeview.terrain.store.schema import write_json_array
from globeview.terrain.store.tile_store import TileStore

DATA = Path(__file__).resolve().parents[2] / "data"
SHARED = Path("/work/shared/data")


def _data(name: str) -> Path:
    p = DATA / name
    return p if p.exists() else SHARED / name


@pytest.fixture(scope="module")
def etopo_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("etopo") / "store"
    ingest([_data("etopo20.tif")], out)
    return out


@pytest.fixture(scope="module")
def vancouver_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("van") / "store"
    # 17 x 17 tiles (TREND's block size): more, smaller tiles for the brute-force checks.
    ingest([_data("topobathy_vancouver.tif")], out, tile_n=4)
    return out


def _write_tif(
    path: Path,
    arr: np.ndarray,
    transform: Affine,
    crs: str | None = "EPSG:4326",
    nodata: float | None = None,
) -> Path:
    prof = {
        "driver": "GTiff",
        "width": arr.shape[1],
        "height": arr.shape[0],
        "count": 1,
        "dtype": arr.dtype.name,
        "transform": transform,
        "nodata": nodata,
    }
    if crs:
        prof["crs"] = crs
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(arr, 1)
    return path


@pytest.mark.slow
def test_levels_are_valid_geotiffs(etopo_store: Path) -> None:
    """Each level is a VRT (what gdalinfo / QGIS open) over chunk files that are valid
    GeoTIFFs on their own, at their place on the level's global chunk grid (store format 7:
    ``chunks/LL/<cy>/<cx>-<h16>.tif``, named by content)."""
    st = TileStore.open(etopo_store)
    n = 2**st.tile_n
    vrts = {}
    for lv in range(st.max_level + 1):
        rec = st.manifest.levels[lv]
        assert rec.file == f"level_{lv:02d}.vrt"
        with rasterio.open(etopo_store / rec.file) as ds:
            assert ds.driver == "VRT"
            assert ds.crs.to_epsg() == 4326
            assert ds.tags()["AREA_OR_POINT"] == "Point"
            assert ds.shape == (2**lv * n + 1, 2 ** (lv + 1) * n + 1)
            # Pixel (0, 0) centre is the node at (-180, 90).
            assert ds.xy(0, 0) == pytest.approx((-180.0, 90.0))
            assert np.isnan(ds.nodata)
            data = vrts[lv] = ds.read(1)
            assert np.isfinite(data).all()  # column W (lon 180) repeats column 0
            np.testing.assert_array_equal(data[:, -1], data[:, 0])
        assert rec.chunks > 0
    c = 1024
    seen = 0
    for lv, cy, cx, facts in st._meta.iter_chunks():
        assert facts.file is not None and facts.file.startswith(f"chunks/{lv:02d}/{cy}/{cx}-")
        assert facts.sha256.startswith(facts.file.rsplit("-", 1)[1][:16])
        data = vrts[lv]
        with rasterio.open(etopo_store / facts.file) as ch:
            assert ch.driver == "GTiff" and ch.crs.to_epsg() == 4326
            assert ch.block_shapes[0] == (256, 256) or max(ch.shape) < 256
            assert ch.tags()["AREA_OR_POINT"] == "Point" and np.isnan(ch.nodata)
            d = 180.0 / (data.shape[0] - 1)
            assert ch.xy(0, 0) == pytest.approx((-180.0 + cx * c * d, 90.0 - cy * c * d))
            assert ch.width == data.shape[1] - 1  # column W is never stored
            h, w = ch.shape
            np.testing.assert_array_equal(
                ch.read(1), data[cy * c : cy * c + h, cx * c : cx * c + w]
            )
        seen += 1
    assert seen == sum(rec.chunks for rec in st.manifest.levels)
    man = json.loads((etopo_store / "manifest.json").read_text())
    assert man["levels"][0]["bbox"] == {"x0": 0, "y0": 0, "nx": 2, "ny": 1}
    assert man["format_version"] == 7 and "error" not in man["levels"][0]


def test_shared_edges_and_poles(etopo_store: Path) -> None:
    st = TileStore.open(etopo_store)
    north, south = st.pole_heights["north"], st.pole_heights["south"]
    # Real data: the South Pole is on the ~2.8 km ice cap, the North Pole in the Arctic Ocean.
    assert 2000 < south < 3500 and north < -3000
    for lv in range(st.max_level + 1):
        ncols, nrows = 2 ** (lv + 1), 2**lv
        for x in range(ncols):
            a = st.heights(TileKey(lv, x, 0))
            b = st.heights(TileKey(lv, (x + 1) % ncols, 0))
            np.testing.assert_array_equal(a[:, -1], b[:, 0])  # incl. across the antimeridian
            assert np.all(a[0] == np.float32(north))
            assert np.all(st.heights(TileKey(lv, x, nrows - 1))[-1] == np.float32(south))
        if nrows > 1:
            np.testing.assert_array_equal(
                st.heights(TileKey(lv, 3, 0))[-1], st.heights(TileKey(lv, 3, 1))[0]
            )


def _brute_force_errors(store: TileStore) -> list[tuple[float, float]]:
    """(recorded, true) per tile: true = max |bilinear tile - finest data| at finest nodes."""
    fine_grid = store.level_grid(store.max_level)
    with rasterio.open(store.path / fine_grid.file_name) as ds:
        fine = ds.read(1).astype(np.float64)
    d_f = fine_grid.d
    pairs = []
    for lv in range(store.max_level):
        g = store.level_grid(lv)
        for iy in range(g.ny):
            for ix in range(g.nx):
                x, y = (g.x0 + ix) % g.ncols, g.y0 + iy
                if not store.has_data(lv, x, y):
                    continue
                tile = store.heights(TileKey(lv, x, y)).astype(np.float64)
                w, _, e, n = tile_bounds(TileKey(lv, x, y))
                # Finest nodes inside the tile (closed), by coordinates.
                c0 = round((w - fine_grid.west) / d_f)
                r0 = round((fine_grid.north - n) / d_f)
                span = round((e - w) / d_f)
                rs = np.arange(max(r0, 0), min(r0 + span, fine.shape[0] - 1) + 1)
                cs = np.arange(max(c0, 0), min(c0 + span, fine.shape[1] - 1) + 1)
                if rs.size == 0 or cs.size == 0:
                    continue
                # Independent bilinear evaluation in tile coordinates.
                u = (cs - c0) * (tile.shape[1] - 1) / span
                v = (rs - r0) * (tile.shape[0] - 1) / span
                i = np.minimum(np.floor(u).astype(int), tile.shape[1] - 2)
                j = np.minimum(np.floor(v).astype(int), tile.shape[0] - 2)
                tu, tv = u - i, v - j

                weights = (
                    ((j, i), np.outer(1 - tv, 1 - tu)),
                    ((j, i + 1), np.outer(1 - tv, tu)),
                    ((j + 1, i), np.outer(tv, 1 - tu)),
                    ((j + 1, i + 1), np.outer(tv, tu)),
                )
                # A zero weight ignores its corner (even a NaN one).
                bil = sum(
                    np.where(wgt == 0, 0.0, wgt * tile[np.ix_(jj, ii)]) for (jj, ii), wgt in weights
                )
                diff = np.abs(bil - fine[np.ix_(rs, cs)])
                true = float(np.nanmax(diff)) if np.isfinite(diff).any() else 0.0
                pairs.append((float(store.tile_error(lv, x, y)), true))
    return pairs


@pytest.mark.slow
def test_recorded_error_is_exact(vancouver_store: Path) -> None:
    st = TileStore.open(vancouver_store)
    pairs = _brute_force_errors(st)
    assert len(pairs) > 20
    for rec, true in pairs:
        assert rec >= true - 1e-6
        assert rec <= true * 1.1 + 1e-3
    # Finest tiles equal the data: no error; coarser levels deviate.
    assert st.level_error(st.max_level) == 0.0
    assert st.level_error(st.max_level - 1) > 0.0


def test_stride_errors_bound_the_subsampled_surface(vancouver_store: Path) -> None:
    st = TileStore.open(vancouver_store)
    lv = st.max_level
    g = st.level_grid(lv)
    ys, xs = np.meshgrid(np.arange(g.ny) + g.y0, (np.arange(g.nx) + g.x0) % g.ncols, indexing="ij")
    se = st.tile_stride_error(lv, xs.ravel(), ys.ravel())
    assert se.shape == (xs.size, 7)
    for k, (x, y) in enumerate(zip(xs.ravel(), ys.ravel())):
        if not st.has_data(lv, x, y):
            assert np.isnan(se[k]).all()
            continue
        t = st.heights(TileKey(lv, int(x), int(y))).astype(np.float64)
        n = t.shape[0] - 1
        for col, s_req in enumerate((2, 4, 8, 16, 32, 64), start=1):
            s = min(s_req, n)  # strides past the tile's size draw its corners only
            sub = t[::s, ::s]
            q = np.arange(n + 1) / s
            i = np.minimum(np.floor(q).astype(int), sub.shape[0] - 2)
            f = q - i
            rows = sub[i] * (1 - f)[:, None] + sub[np.minimum(i + 1, sub.shape[0] - 1)] * f[:, None]
            full = rows[:, i] * (1 - f) + rows[:, np.minimum(i + 1, sub.shape[1] - 1)] * f
            dev = np.abs(full - t)
            if np.isfinite(dev).any():
                assert se[k, col] >= np.nanmax(dev) - 1e-3


def test_coarse_levels_are_the_wavelet_approximation(vancouver_store: Path) -> None:
    st = TileStore.open(vancouver_store)
    checked = 0
    for lv in range(st.max_level):
        fg, cg = st.level_grid(lv + 1), st.level_grid(lv)
        with rasterio.open(vancouver_store / fg.file_name) as ds:
            approx = approximate_grid(ds.read(1))
        with rasterio.open(vancouver_store / cg.file_name) as ds:
            coarse = ds.read(1)
        r_off, c_off = fg.gr0 // 2 - cg.gr0, fg.gc0 // 2 - cg.gc0
        sub = coarse[r_off : r_off + approx.shape[0], c_off : c_off + approx.shape[1]]
        assert sub.shape == approx.shape
        ok = np.isfinite(approx) & np.isfinite(sub)
        # A regional DEM fades out at coarse levels (fewer nodes than its footprint holds).
        assert ok.sum() == np.isfinite(approx).sum()
        checked += int(ok.sum())
        np.testing.assert_allclose(sub[ok], approx[ok], atol=1e-3)
    assert checked > 1000


@pytest.mark.slow
def test_global_plus_regional(tmp_path: Path) -> None:
    out = tmp_path / "combo"
    van, eto = _data("topobathy_vancouver.tif"), _data("etopo20.tif")
    # Declared ellipsoidal: this checks which source wins, not the datum (test_vdatum does).
    ingest([eto, van], out, vdatum="ellipsoid")
    st = TileStore.open(out)
    g = st.level_grid(st.max_level)
    assert g.nx < g.ncols  # the finest level is regional
    assert st.level_grid(0).global_lon
    with rasterio.open(out / g.file_name) as ds:
        fine = ds.read(1)
    west, north = g.west, g.north
    with open_dem(van) as dv, open_dem(eto) as de:
        want_v = dv.read_grid(west, north, g.d, g.d, g.width, g.height)
        want_e = de.read_grid(west, north, g.d, g.d, g.width, g.height)
    inside = np.isfinite(want_v)
    assert inside.sum() > 100 and (~inside).sum() > 100
    np.testing.assert_allclose(fine[inside], want_v[inside], atol=1e-3)  # regional wins
    np.testing.assert_allclose(fine[~inside], want_e[~inside], atol=1e-3)  # base elsewhere
    assert np.isfinite(st.heights(TileKey(0, 0, 0))).all()


@pytest.mark.slow
def test_antimeridian_and_non_square_pixels(tmp_path: Path) -> None:
    # 170E .. 190E (= -170) in plain EPSG:4326 longitudes beyond 180; 0.05 x 0.1 deg pixels.
    lon = 170.0 + 0.05 * (np.arange(400) + 0.5)
    lat = 10.0 - 0.1 * (np.arange(100) + 0.5)
    z = (1000 * np.sin(np.radians(lon))[None, :] * 50 + lat[:, None] * 10).astype(np.float32)
    src = _write_tif(tmp_path / "am.tif", z, Affine(0.05, 0, 170.0, 0, -0.1, 10.0))
    out = tmp_path / "am_store"
    ingest([src], out, vdatum="ellipsoid")  # heights as the source's: the seam is the point
    st = TileStore.open(out)
    lv = st.max_level
    w_, _, e_, _ = st.bounds
    assert w_ > e_  # crosses the antimeridian
    g = st.level_grid(lv)
    assert g.nx < g.ncols and g.x0 + g.nx > g.ncols  # the extent wraps
    tile_w = 180.0 / 2**lv
    xw = int((179.9 + 180) // tile_w)
    xe = int((-179.9 + 180) // tile_w)
    y = int((90 - 5.0) // tile_w)
    assert st.has_data(lv, xw, y) and st.has_data(lv, xe, y)
    a, b = st.heights(TileKey(lv, xw, y)), st.heights(TileKey(lv, xe, y))
    if xe == (xw + 1) % g.ncols:
        np.testing.assert_array_equal(a[:, -1], b[:, 0])
    # Heights follow the source across the seam.
    with open_dem(src) as dem:
        lon0, _, _, lat0 = tile_bounds(TileKey(lv, xe, y))
        want = dem.read_grid(lon0, lat0, g.d, g.d, b.shape[1], b.shape[0])
    ok = np.isfinite(want)
    assert ok.any()
    np.testing.assert_allclose(b[ok], want[ok], atol=1e-2)


def test_pole_reaching_region(tmp_path: Path) -> None:
    z = np.linspace(0, 500, 40 * 30, dtype=np.float32).reshape(30, 40)
    src = _write_tif(tmp_path / "pole.tif", z, Affine(0.5, 0, 0.0, 0, -0.5, 90.0))
    out = tmp_path / "pole_store"
    ingest([src], out)
    st = TileStore.open(out)
    north = st.pole_heights["north"]
    assert north is not None and st.pole_heights["south"] is None
    for lv in range(st.max_level + 1):
        g = st.level_grid(lv)
        with rasterio.open(out / g.file_name) as ds:
            row = ds.read(1, window=((0, 1), (0, g.width)))[0]
        assert g.y0 == 0
        assert np.isfinite(row).any() and np.all(row[np.isfinite(row)] == np.float32(north))


@pytest.mark.slow
def test_reingest_is_a_noop_and_force_rebuilds(tmp_path: Path) -> None:
    out = tmp_path / "s"
    src = _data("topobathy_vancouver.tif")
    assert not ingest([src], out).up_to_date
    m = out / "manifest.json"
    before = m.stat().st_mtime_ns
    assert ingest([src], out).up_to_date
    assert m.stat().st_mtime_ns == before
    assert not ingest([src], out, tile_n=5).up_to_date  # other parameters: rebuilt
    assert TileStore.open(out).tile_size == 33
    assert not ingest([src], out, tile_n=5, force=True).up_to_date


def _leftovers(parent: Path, name: str) -> list[str]:
    return [p.name for p in parent.iterdir() if p.name.startswith(f".{name}.")]


@pytest.mark.slow
def test_failure_leaves_old_store_intact(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "s"
    src = _data("topobathy_vancouver.tif")
    ingest([src], out)

    def files() -> dict[str, bytes]:
        return {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    snapshot = files()

    def boom(*args: object) -> None:
        raise RuntimeError("simulated crash in the error pass")

    monkeypatch.setattr(ingest_graph, "error_task", boom)  # a task of the graph crashes
    with pytest.raises(RuntimeError):
        ingest([src], out, force=True)
    assert files() == snapshot
    assert _leftovers(tmp_path, "s") == []
    fresh = tmp_path / "fresh"
    with pytest.raises(RuntimeError):
        ingest([src], fresh)
    assert not fresh.exists() and _leftovers(tmp_path, "fresh") == []


def _bad_inputs(tmp: Path) -> dict[str, Path]:
    t = Affine(0.01, 0, 10, 0, -0.01, 50)
    good = np.arange(100, dtype=np.float32).reshape(10, 10)
    bad = {
        "no_crs": _write_tif(tmp / "nocrs.tif", good, t, crs=None),
        "all_nodata": _write_tif(
            tmp / "nodata.tif", np.full((10, 10), -9999, np.float32), t, nodata=-9999
        ),
        "nan_filled": _write_tif(tmp / "nan.tif", np.full((10, 10), np.nan, np.float32), t),
        "one_pixel": _write_tif(tmp / "one.tif", good[:1, :1], t),
    }
    text = tmp / "text.tif"
    text.write_text("this is not a raster\n")
    bad["text"] = text
    full = _write_tif(tmp / "full.tif", np.random.default_rng(1).random((300, 300), np.float32), t)
    data = full.read_bytes()
    trunc = tmp / "trunc.tif"
    trunc.write_bytes(data[: len(data) // 3])
    bad["truncated"] = trunc
    return bad


@pytest.mark.parametrize(
    "case", ["no_crs", "all_nodata", "nan_filled", "one_pixel", "text", "truncated"]
)
def test_bad_sources(tmp_path: Path, case: str) -> None:
    src = _bad_inputs(tmp_path)[case]
    out = tmp_path / "out"
    with pytest.raises((DemError, StoreError)) as exc:
        ingest([src], out)
    msg = str(exc.value)
    assert msg and "\n" not in msg
    assert not out.exists() and _leftovers(tmp_path, "out") == []


def test_refuses_non_store_directory(tmp_path: Path) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.docx").write_text("precious")
    with pytest.raises(StoreError, match="not a globeview store"):
        ingest([_data("topobathy_vancouver.tif")], out)
    assert (out / "thesis.docx").read_text() == "precious"
    assert not (out / "manifest.json").exists()


def test_read_only_location(tmp_path: Path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    target = ro / "store"
    if os.access(ro, os.W_OK):  # running as root: permissions do not bind, use sysfs
        target = Path("/sys/globeview-store")
    try:
        with pytest.raises(StoreError) as exc:
            ingest([_data("topobathy_vancouver.tif")], target)
        assert "\n" not in str(exc.value)
        assert not target.exists()
    finally:
        ro.chmod(0o755)


def test_bad_parameters(tmp_path: Path) -> None:
    src = _data("topobathy_vancouver.tif")
    for kw in ({"tile_n": 0}, {"max_level": -1}, {"wavelet": "db2"}):
        with pytest.raises(GlobeviewError):
            ingest([src], tmp_path / "x", **kw)
        assert not (tmp_path / "x").exists()


def test_manifest_arrays_are_streamed_as_the_same_json() -> None:
    import io

    rng = np.random.default_rng(3)
    for shape in [(3, 4), (2, 5, 6), (1, 1), (0, 3)]:
        a = rng.random(shape) * 1e4
        a.flat[:: max(1, a.size // 3)] = np.nan
        f = io.StringIO()
        write_json_array(f, a)
        want = a.astype(object)
        want[np.isnan(a)] = None
        assert json.loads(f.getvalue()) == want.tolist()
