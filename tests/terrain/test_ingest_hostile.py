"""Hostile sources and damaged stores at planet scale (issue #25, design §4.5): each is one
line (exit 2, no traceback, nothing written) or a recovered build.

- a tile whose footprint is wrong: an .hgt whose size is no SRTM tile's, a Copernicus-named
  tile whose header is another cell, a GeoTIFF whose transform puts it off the globe;
- the same tile twice (one path, or two copies): built once, the copy named;
- overlapping tiles: the finer pixels win, then the tile given first, pixel sizes equal to a
  ppm being equal (two transforms of one resolution differ in their last bits);
- a chunk file missing from a built store, a metadata shard damaged: one line naming it,
  the rest of the store still read;
- ``ingest --plan`` and a build on a full disk (a real tmpfs, root only).

Small rasters (100 x 100), the CLI in this process (`inprocess_cli`)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from globeview.errors import StoreError
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.quadtree import TileKey, key_for_lonlat
from globeview.terrain.store.tile_store import TileStore
from tests.cli.run_cli import globeview_here, one_error_line
from tests.fault.contract import fill_disk, tmpfs
from tests.terrain.planet_tiles import copernicus_name, write_geotiff


def _const(path: Path, value: float, west: float, north: float, res: float, n: int) -> Path:
    """An n x n constant float32 lon/lat GeoTIFF, north-west corner (west, north)."""
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=n,
        height=n,
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=Affine(res, 0.0, west, 0.0, -res, north),
    ) as ds:
        ds.write(np.full((n, n), value, dtype=np.float32), 1)
    return path


def _new_entries(folder: Path, before: set[str]) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name not in before)


# -- wrong footprints -----------------------------------------------------------------------------


def _short_hgt(folder: Path) -> tuple[Path, str]:
    p = folder / "N44W072.hgt"
    np.zeros(1000, dtype=">i2").tofile(p)
    return p, (
        f'{p}: 2000 bytes is not an SRTM tile\'s size (25934402 for 1", 2884802 for 3"): the '
        "file is cut short or not an SRTM .hgt, so its name cannot place it"
    )


def _renamed_copernicus(folder: Path) -> tuple[Path, str]:
    p = write_geotiff(folder / copernicus_name(44, -72), 10.0, 45.0, 0.01, 100)
    return p, (
        f"{p.name}: its header puts it at 10 E..11 E, 44 N..45 N, not where its name says "
        "(72 W..71 W, 44 N..45 N); rename it (ingest --plan places a named tile by "
        "its name)"
    )


def _off_in_latitude(folder: Path) -> tuple[Path, str]:
    p = write_geotiff(folder / "lat200.tif", 10.0, 200.0, 0.01, 100)
    return p, f"{p} places samples at latitude 199.995, beyond +-90 degrees: its georeferencing"


def _off_in_longitude(folder: Path) -> tuple[Path, str]:
    p = write_geotiff(folder / "lon1e6.tif", 1e6, 45.0, 0.01, 100)
    return p, f"{p} places samples at longitude 1e+06, beyond +-540 degrees: its georeferencing"


WRONG = {
    "short hgt": (_short_hgt, True),
    "renamed copernicus": (_renamed_copernicus, False),  # --plan goes by the name: no open
    "latitude 200": (_off_in_latitude, True),
    "longitude 1e6": (_off_in_longitude, True),
}


@pytest.mark.parametrize("case", list(WRONG))
def test_a_tile_with_a_wrong_footprint_is_one_line_and_writes_nothing(
    tmp_path: Path, case: str
) -> None:
    make, plan_too = WRONG[case]
    src, words = make(tmp_path)
    before = {p.name for p in tmp_path.iterdir()}
    out = tmp_path / "s"
    line = one_error_line(
        globeview_here("ingest", str(src), "--out", str(out), "--vdatum", "egm96", cache=tmp_path)
    )
    assert line.startswith("globeview: error: " + words), line
    assert _new_entries(tmp_path, before) == []  # no store, no building folder, no lock
    if plan_too:
        plan = one_error_line(globeview_here("ingest", str(src), "--plan", cache=tmp_path))
        assert plan == line


# -- duplicates and overlaps ----------------------------------------------------------------------


def test_the_same_tile_twice_is_built_once(tmp_path: Path) -> None:
    a = write_geotiff(tmp_path / "a.tif", 10.0, 45.0, 0.01, 100)
    (tmp_path / "copy").mkdir()
    b = Path(shutil.copy(a, tmp_path / "copy" / "a.tif"))
    out = tmp_path / "s"
    args = ("ingest", str(a), str(a), str(b), "--out", str(out), "--quiet", "--vdatum", "egm96")
    r = globeview_here(*args, cache=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout == f"{b}: the same data as {a}: using the first\n"
    sources = json.loads((out / "manifest.json").read_text())["sources"]
    assert [s["path"] for s in sources] == [str(a)]
    again = globeview_here(*args, cache=tmp_path)
    assert again.stdout.splitlines()[-1] == f"{out}: store is up to date"


@pytest.fixture(scope="module")
def overlaps(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Given in this order: A (0.01 deg, 1000 m); D (0.02 deg, 3000 m); B (A's pixel size
    less 1 ppb, 2000 m) over A's east half and beyond; C (0.005 deg, 4000 m) inside D."""
    base = tmp_path_factory.mktemp("overlaps")
    a = _const(base / "a.tif", 1000.0, 20.0, 45.0, 0.01, 100)
    d = _const(base / "d.tif", 3000.0, 30.0, 45.0, 0.02, 50)
    b = _const(base / "b.tif", 2000.0, 20.5, 45.0, 0.01 * (1 - 1e-9), 100)
    c = _const(base / "c.tif", 4000.0, 30.25, 44.75, 0.005, 100)
    ingest([a, d, b, c], base / "s", vdatum="ellipsoid", workers=1)
    return base / "s"


def _at(store: Path, level: int, lon: float, lat: float) -> float:
    """The stored height at the node of ``level`` nearest (lon, lat)."""
    with TileStore.open(store) as st:
        g = st.level_grid(level)
        x, y = key_for_lonlat(level, lon, lat)
        z = st.heights(TileKey(level, int(x), int(y)))
    west, north = -180.0 + int(x) * g.d * 64, 90.0 - int(y) * g.d * 64
    return float(z[round((north - lat) / g.d), round((lon - west) / g.d)])


def test_overlapping_tiles_finer_wins_then_the_first_given(overlaps: Path) -> None:
    # A and B: the same resolution to a ppm, so the one given first wins where both are ...
    assert _at(overlaps, 8, 20.75, 44.5) == 1000.0
    assert _at(overlaps, 8, 20.25, 44.5) == 1000.0
    assert _at(overlaps, 8, 21.25, 44.5) == 2000.0  # ... and B where only B is
    # C's pixels are finer than D's: C wins inside its footprint although given last.
    assert _at(overlaps, 9, 30.5, 44.5) == 4000.0
    assert _at(overlaps, 7, 30.9, 44.1) == 3000.0


# -- a damaged store ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One 1-degree 36" tile at 10..11 E, 44..45 N, built to level 8 (a chunk a level)."""
    base = tmp_path_factory.mktemp("small")
    ingest([write_geotiff(base / "a.tif", 10.0, 45.0, 0.01, 100)], base / "s", workers=1)
    return base / "s"


def _key(level: int) -> TileKey:
    x, y = key_for_lonlat(level, 10.5, 44.5)
    return TileKey(level, int(x), int(y))


def _one_line_naming(exc: pytest.ExceptionInfo[StoreError], name: str) -> None:
    assert name in str(exc.value) and "\n" not in str(exc.value), str(exc.value)


def test_a_missing_chunk_is_named_and_the_rest_reads(small_store: Path, tmp_path: Path) -> None:
    copy = tmp_path / "s"
    shutil.copytree(small_store, copy)
    victim = next(copy.glob("chunks/08/*/*.tif"))
    victim.unlink()
    with TileStore.open(copy) as st:
        with pytest.raises(StoreError) as err:
            st.verify(full=False)
        _one_line_naming(err, victim.name)
        with pytest.raises(StoreError) as err:
            st.heights(_key(8))
        _one_line_naming(err, victim.name)
        assert np.isfinite(st.heights(_key(5))).any()  # the other levels' chunks still read


@pytest.mark.parametrize(("shard", "how"), [("meta/0*/*/*.gvm", "cut"), ("meta/top-*", "flip")])
def test_a_damaged_metadata_shard_is_one_line_naming_it(
    small_store: Path, tmp_path: Path, shard: str, how: str
) -> None:
    copy = tmp_path / "s"
    shutil.copytree(small_store, copy)
    victim = sorted(copy.glob(shard))[-1]  # the top shard, or level 6's holding the data
    data = bytearray(victim.read_bytes())
    if how == "cut":
        del data[len(data) // 2 :]
    else:
        data[len(data) // 2] ^= 0xFF
    victim.write_bytes(bytes(data))
    if shard.startswith("meta/top"):
        with pytest.raises(StoreError) as err:
            TileStore.open(copy)
        _one_line_naming(err, victim.name)
        return
    with TileStore.open(copy) as st:
        with pytest.raises(StoreError) as err:
            st.heights(_key(8))
        _one_line_naming(err, victim.name)
        with pytest.raises(StoreError) as err:
            st.verify(full=False)
        _one_line_naming(err, victim.name)
        assert np.isfinite(st.heights(_key(5))).any()  # levels the top shard holds


# -- a full disk ----------------------------------------------------------------------------------


@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a tmpfs (a full disk) needs root")
def test_plan_runs_and_the_build_is_one_line_on_a_full_disk(tmp_path: Path) -> None:
    src = write_geotiff(tmp_path / "a.tif", 10.0, 45.0, 0.01, 100)
    try:
        disk = tmpfs(tmp_path / "full", "256k")
        mnt = disk.__enter__()
    except OSError as exc:
        pytest.skip(str(exc))
    try:
        fill_disk(mnt)
        plan = globeview_here("ingest", str(src), "--plan", cache=mnt / "cache")
        assert plan.returncode == 0, plan.stderr  # writes nothing: not even its cache
        assert "sources: 1 (0 by name, 1 by header)" in plan.stdout
        out = mnt / "s"
        line = one_error_line(globeview_here("ingest", str(src), "--out", str(out), cache=mnt))
        assert f"the limit is the free space in {mnt}: " in line and "--max-level" in line
        assert sorted(p.name for p in mnt.iterdir()) == ["filler.bin"]
    finally:
        disk.__exit__(None, None, None)
