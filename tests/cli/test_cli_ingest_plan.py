"""`globeview ingest --plan` (issue #25): a folder, a glob or an @list of SRTM/Copernicus-named
tiles planned from their names, chunks only where the tiles are, nothing written; GEBCO's
shape at its native resolution; the EGM2008 grid's line; hostile inputs one line each."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest

from globeview.terrain.dem.vdatum import find_geoid_grid
from globeview.terrain.ingest.footprints import footprints
from globeview.terrain.ingest.plan import plan_chunks
from globeview.terrain.ingest.report import make_plan
from tests.fault.corpus import write_netcdf_cf
from tests.terrain.planet_tiles import (
    write_copernicus,
    write_geoid_grid,
    write_geotiff,
    write_hgt,
    write_netcdf,
)

from .run_cli import globeview, one_error_line

CELLS = [(44, -72), (44, -71), (-17, 179)]  # two neighbours and one at the antimeridian


def level_rows(stdout: str) -> dict[int, tuple[int, int]]:
    """level -> (chunks, source reads) from the plan's table (checking each level's tasks:
    a chunk and an error+meta task a chunk, and the shards rooted there)."""
    rows = {}
    tasks = 0
    for m in re.finditer(r"^\s+(\d+)\s+([\d,]+)\s+([\d,]+)\s+([\d,]+)\s", stdout, re.MULTILINE):
        lv, chunks, t, reads = (int(g.replace(",", "")) for g in m.groups())
        assert 2 * chunks <= t <= 2 * chunks + chunks
        tasks += t
        rows[lv] = (chunks, reads)
    total = re.search(r"chunks, ([\d,]+) tasks \(([\d,]+) source", stdout)
    assert total is not None
    assert int(total.group(1).replace(",", "")) == tasks + int(total.group(2).replace(",", "")) + 1
    return rows


@pytest.fixture(scope="module")
def srtm(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("srtm")
    for lat, lon in CELLS:
        write_hgt(folder, lat, lon)
    (folder / "README.txt").write_text("not a DEM: skipped by the folder's extension filter")
    return folder


def test_a_folder_a_glob_and_a_list_plan_the_same_chunks_where_the_tiles_are(
    srtm: Path, tmp_path: Path
) -> None:
    lst = tmp_path / "tiles.txt"
    rel = os.path.relpath(srtm, tmp_path)
    lst.write_text('# SRTM 3"\n' + "".join(f"{rel}/{p.name}\n" for p in sorted(srtm.glob("*.hgt"))))
    outs = []
    for src in (str(srtm), str(srtm / "*.hgt"), f"@{lst}"):
        res = globeview("ingest", src, "--plan", "--out", str(tmp_path / "s"), cache=tmp_path)
        assert res.returncode == 0, res.stderr
        assert res.stderr == ""
        outs.append(level_rows(res.stdout))
        assert "sources: 3 (3 by name, 0 by header); datums: egm96 3 (SRTM .hgt default)" in (
            res.stdout
        )
    assert outs[0] == outs[1] == outs[2]
    assert not (tmp_path / "s").exists()  # --plan writes nothing
    rows = outs[0]
    assert sorted(rows) == list(range(13))  # SRTM 3": level 12 at tile_n 6
    want = plan_chunks(footprints(sorted(srtm.glob("*.hgt"))), 6)
    assert {lv: rows[lv][0] for lv in rows} == {lv: lp.chunks for lv, lp in enumerate(want.levels)}
    # Only where the tiles are: each tile alone needs a few chunks a level; three tiles, far
    # fewer than level 12's 32 x 64... chunk grid.
    alone = [plan_chunks(footprints([p]), 6).levels[12].chunks for p in srtm.glob("*.hgt")]
    assert rows[12][0] <= sum(alone) < 3 * 16
    assert rows[12][1] == sum(alone)  # each tile read by each chunk it reaches
    assert rows[0] == (1, 0)


def test_copernicus_names_need_the_egm2008_grid(tmp_path: Path) -> None:
    tiles = tmp_path / "copdem" / "N45E009" / "DEM"
    tiles.mkdir(parents=True)
    write_copernicus(tiles, 45, 9)
    src = str(tmp_path / "copdem" / "**" / "*_DEM.tif")
    if find_geoid_grid("egm2008") is not None:
        pytest.skip("this machine has an EGM2008 grid in PROJ's folders")
    line = one_error_line(globeview("ingest", src, "--plan", cache=tmp_path))
    assert line == (
        "globeview: error: Copernicus_DSM_COG_30_N45_00_E009_00_DEM.tif: heights are on EGM2008 "
        "(Copernicus DEM default) and no EGM2008 grid is on this machine; get "
        "us_nga_egm08_25.tif (https://cdn.proj.org/us_nga_egm08_25.tif) and pass --geoid-grid "
        "egm2008=PATH, or --vdatum egm96 to approximate (about 1 m)"
    )
    approx = globeview("ingest", src, "--plan", "--vdatum", "egm96", cache=tmp_path)
    assert approx.returncode == 0 and "datums: egm96 1 (--vdatum)" in approx.stdout
    grid = write_geoid_grid(tmp_path / "egm08.tif", 2.0)
    ok = globeview("ingest", src, "--plan", "--geoid-grid", f"egm2008={grid}", cache=tmp_path)
    assert ok.returncode == 0, ok.stderr
    assert "datums: egm2008 1 (Copernicus DEM default)" in ok.stdout
    assert f"geoid grid egm2008: {grid}" in ok.stdout
    assert level_rows(ok.stdout)[12][0] > 0  # GLO-90: 3", level 12
    # Two datums in one build: SRTM's EGM96 beside Copernicus' EGM2008.
    hgt = write_hgt(tmp_path, 44, -72)
    both = globeview("ingest", src, str(hgt), "--plan", "--geoid-grid", str(grid), cache=tmp_path)
    assert both.returncode == 0, both.stderr
    assert (
        "sources: 2 (2 by name, 0 by header); datums: egm2008 1 (Copernicus DEM default), "
        "egm96 1 (SRTM .hgt default)"
    ) in both.stdout
    bad = one_error_line(globeview("ingest", src, "--plan", "--geoid-grid", "x=1", cache=tmp_path))
    assert "unknown geoid 'x' (known: egm2008)" in bad
    nofile = globeview(
        "ingest", src, "--plan", "--geoid-grid", str(tmp_path / "no.tif"), cache=tmp_path
    )
    assert one_error_line(nofile).endswith("no.tif: no such file")


def test_gebco_shapes_plan_at_native_resolution(tmp_path: Path) -> None:
    """A GEBCO-size grid (86 400 x 43 200, 15", header only) plans at level 9 with the default
    options: the whole globe, 2 048 chunks there and 2 734 in all; a small CF netCDF global
    grid opens as WGS84 by its lat/lon axes."""
    vrt = tmp_path / "gebco_like.vrt"
    vrt.write_text(
        '<VRTDataset rasterXSize="86400" rasterYSize="43200"><SRS>EPSG:4326</SRS>'
        f"<GeoTransform>-180, {1 / 240!r}, 0, 90, 0, {-1 / 240!r}</GeoTransform>"
        '<VRTRasterBand dataType="Int16" band="1"/></VRTDataset>'
    )
    r = make_plan([vrt])
    assert r.plan.max_level == 9
    assert r.plan.levels[9].chunks == 2048 and r.plan.chunks == 2734
    nc = write_netcdf(tmp_path / "gebco_small.nc", cf_axes=True)
    res = globeview("ingest", str(nc), "--plan", cache=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "sources: 1 (0 by name, 1 by header)" in res.stdout


def test_the_footprint_bar_has_an_eta(srtm: Path, capsys: pytest.CaptureFixture[str]) -> None:
    make_plan([srtm], how="header", progress=True)
    err = capsys.readouterr().err
    assert "footprints" in err and "3/3" in err and "<00:00" in err


def test_hostile_inputs_are_one_line_each(srtm: Path, tmp_path: Path) -> None:
    def line(*src: str) -> str:
        return one_error_line(globeview("ingest", *src, "--plan", cache=tmp_path))

    assert line(str(tmp_path / "none" / "*.hgt")).endswith(
        "*.hgt matches no files (a glob: quote it so the shell leaves it)"
    )
    lst = tmp_path / "l.txt"
    lst.write_text(f"{srtm / 'N44W072.hgt'}\nS01E001.hgt\n")
    assert line(f"@{lst}") == f"globeview: error: DEM file not found: {tmp_path / 'S01E001.hgt'}"
    junk = tmp_path / "junk"
    junk.mkdir()
    write_geotiff(junk / "a.tif", 0.0, 1.0, 0.01, 100)
    (junk / "b.tif").write_text("not a raster")
    assert line(str(junk)).startswith(f"globeview: error: cannot read {junk / 'b.tif'} as a raster")
    lats, lons = np.linspace(4500, -4500, 10), np.linspace(-9000, 9000, 20)
    nc = write_netcdf_cf(tmp_path / "xy.nc", lons, lats, np.ones((10, 20)), geographic=False)
    assert line(str(nc)) == (
        f"globeview: error: {nc} has no coordinate reference system; supply one with --crs "
        "EPSG:XXXX (e.g. --crs EPSG:4326 for lon/lat degrees)"
    )
    bad_name = one_error_line(
        globeview("ingest", str(junk / "a.tif"), "--plan", "--footprints", "name", cache=tmp_path)
    )
    assert "a.tif: not an SRTM (N44W072.hgt) or Copernicus" in bad_name
    assert line(str(srtm), "--max-level", "40").endswith("--max-level must be in 0..22, got 40")
    no_out = one_error_line(globeview("ingest", str(srtm), cache=tmp_path))
    assert no_out.endswith("the following arguments are required: --out (or --plan)")
    unused = globeview(
        "ingest", str(srtm), "--out", str(tmp_path / "s"), "--footprints", "name", cache=tmp_path
    )
    assert one_error_line(unused).endswith("--footprints is for --plan")
    assert not (tmp_path / "s").exists()
