"""Source footprints without pixel reads (issue #25, `terrain/ingest/footprints.py`): SRTM and
Copernicus names give the cell grown by a pixel, which holds what the header says; other
files are read by header only; datums by kind; a renamed tile is one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from globeview.errors import DemError
from globeview.terrain.dem.reader import open_dem
from globeview.terrain.ingest import driver
from globeview.terrain.ingest.footprints import (
    DATUMS,
    check_name_footprint,
    footprints,
    footprints_from_names,
    natural_levels,
)
from tests.terrain.planet_tiles import (
    copernicus_name,
    write_copernicus,
    write_geotiff,
    write_hgt,
)

SRTM = Path(__file__).resolve().parents[2] / "data" / "N44W072.hgt"


def test_srtm_names_give_the_cell_grown_by_a_pixel() -> None:
    t = footprints_from_names(["N44W072.hgt", "s17e179.hgt", "S01W180.hgt"], [2884802] * 3)
    px = 3 / 3600
    assert t.west[0] == pytest.approx(-72 - px) and t.east[0] == pytest.approx(-71 + px)
    assert t.south[0] == pytest.approx(44 - px) and t.north[0] == pytest.approx(45 + px)
    # 179..180 E grown past 180: across the antimeridian (west > east).
    assert t.west[1] == pytest.approx(179 - px) and t.east[1] == pytest.approx(-180 + px)
    assert t.south[1] == pytest.approx(-17 - px)
    assert t.west[2] == pytest.approx(180 - px) and t.east[2] == pytest.approx(-179 + px)
    assert t.res.tolist() == [px] * 3 and (t.how == 0).all()
    assert {DATUMS[d] for d in t.datum} == {"egm96"}
    assert set(t.datum_why) == {"SRTM .hgt default"}


def test_copernicus_names_widen_longitude_pixels_and_are_egm2008() -> None:
    names = [copernicus_name(44, -72, 10), copernicus_name(55, 10, 30), copernicus_name(-86, 0)]
    t = footprints_from_names(names)
    assert t.res.tolist() == pytest.approx([1 / 3600, 3 / 3600, 3 / 3600])
    assert t.reach.tolist() == pytest.approx([1 / 3600, 4.5 / 3600, 30 / 3600])
    assert t.west[1] == pytest.approx(10 - 4.5 / 3600)
    assert {DATUMS[d] for d in t.datum} == {"egm2008"}
    assert set(t.datum_why) == {"Copernicus DEM default"}
    forced = footprints_from_names(names, vdatum="egm96")
    assert {DATUMS[d] for d in forced.datum} == {"egm96"} and forced.datum_why[0] == "--vdatum"


def test_unrecognised_names_are_one_line() -> None:
    with pytest.raises(DemError, match=r"not an SRTM .* or Copernicus .* tile name"):
        footprints_from_names(["dem.tif"])
    with pytest.raises(DemError, match=r"123 bytes is neither SRTM 1\" .* nor 3\""):
        footprints_from_names(["N44W072.hgt"], [123])
    with pytest.raises(DemError, match=r"outside -90\.\.90"):
        footprints_from_names(["N95W072.hgt"])
    with pytest.raises(DemError, match=r"outside -90\.\.90"):
        footprints_from_names([copernicus_name(10, 190)])


def test_a_real_srtm_tile_by_name_holds_its_header_footprint() -> None:
    by_name = footprints([SRTM])
    by_header = footprints([SRTM], how="header")
    assert by_name.how.tolist() == [0] and by_header.how.tolist() == [1]
    with open_dem(SRTM) as dem:
        info = dem.info
    assert by_header.west[0] == info.bounds_lonlat[0]
    assert by_header.north[0] == info.bounds_lonlat[3]
    for col in ("west", "south"):
        assert getattr(by_name, col)[0] < getattr(by_header, col)[0]
    for col in ("east", "north"):
        assert getattr(by_name, col)[0] > getattr(by_header, col)[0]
    assert by_name.res[0] == pytest.approx(by_header.res[0])
    assert by_name.levels(6).tolist() == by_header.levels(6).tolist() == [12]
    assert DATUMS[by_name.datum[0]] == DATUMS[by_header.datum[0]] == "egm96"
    check_name_footprint(str(SRTM), info.bounds_lonlat, by_name, 0)  # no error


def test_auto_mixes_names_and_headers_in_input_order(tmp_path: Path) -> None:
    hgt = write_hgt(tmp_path, 44, -72)
    other = write_geotiff(tmp_path / "patch.tif", 10.0, 46.0, 0.01, 50)
    cop = write_copernicus(tmp_path, 45, 9)
    calls: list[tuple[int, int]] = []
    t = footprints([other, hgt, cop], on_progress=lambda d, n: calls.append((d, n)))
    assert t.paths == (str(other), str(hgt), str(cop))
    assert t.how.tolist() == [1, 0, 0]
    assert calls == [(1, 1)]  # one header read
    assert t.west[0] == pytest.approx(10.0) and t.north[0] == pytest.approx(46.0)
    assert [DATUMS[d] for d in t.datum] == ["egm96", "egm96", "egm2008"]
    assert t.datum_why[0] == "assumed"
    # Headers only: the Copernicus tile keeps its datum from its name.
    h = footprints([other, hgt, cop], how="header")
    assert h.how.tolist() == [1, 1, 1] and DATUMS[h.datum[2]] == "egm2008"
    with pytest.raises(DemError, match=r"patch\.tif: not an SRTM"):
        footprints([other, hgt], how="name")


def test_a_renamed_tile_is_one_line(tmp_path: Path) -> None:
    """N44W072.hgt holding another cell's header: the build's check names both places."""
    t = footprints_from_names(["N44W072.hgt"], [2884802])
    with pytest.raises(
        DemError,
        match=r"N44W072.hgt: its header puts it at 10 E..11 E, 44 N..45 N, not where its "
        r"name says \(72 W..71 W",
    ):
        check_name_footprint("N44W072.hgt", (10.0, 44.0, 11.0, 45.0), t, 0)


def test_header_reads_skip_the_value_scan(tmp_path: Path) -> None:
    p = write_geotiff(tmp_path / "a.tif", 0.0, 1.0, 0.01, 100)
    with open_dem(p, scan=False) as dem:
        assert np.isnan(dem.info.vmin) and dem.info.masked_samples == 0
    with open_dem(p) as dem:
        assert dem.info.vmin > 0


def test_natural_levels_are_the_builds() -> None:
    res = np.array([1 / 3600, 3 / 3600, 0.25, 1.0, 1e-6, 0.5])
    extent = np.array([1.0, 1.0, 0.3, 360.0, 0.001, 0.6])
    for tile_n in (4, 6, 10):
        want = [driver._natural_level(r, tile_n, e) for r, e in zip(res, extent, strict=True)]
        assert natural_levels(res, extent, tile_n).tolist() == want


def test_a_table_from_opened_sources_plans_as_one_from_headers() -> None:
    """What a build that opened its sources hands the planner: the same table and plan as
    the header footprints give."""
    from globeview.terrain.ingest.footprints import table_from_bounds
    from globeview.terrain.ingest.plan import plan_chunks

    paths = [SRTM, Path(__file__).resolve().parents[2] / "data" / "topobathy_vancouver.tif"]
    infos = []
    for p in paths:
        with open_dem(p, scan=False) as dem:
            infos.append(dem.info)
    t = table_from_bounds(
        [str(p) for p in paths],
        [i.bounds_lonlat for i in infos],
        [min(i.res_deg) for i in infos],
        [max(i.res_deg) for i in infos],
        [i.wraps_longitude for i in infos],
        [i.vertical_datum for i in infos],
    )
    h = footprints(paths, how="header")
    for col in ("west", "south", "east", "north", "res", "reach", "extent", "wraps", "datum"):
        np.testing.assert_array_equal(getattr(t, col), getattr(h, col))
    a, b = plan_chunks(t, 6), plan_chunks(h, 6)
    assert a.chunk_sets() == b.chunk_sets() and len(a.chunk_sets()) == a.max_level + 1
    assert sum(len(s) for s in a.chunk_sets()) == a.chunks
