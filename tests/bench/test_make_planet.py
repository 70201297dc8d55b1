"""benchmarks/make_planet.py (issue #25's synthetic planet), in this process on tiny cases:
the cells grow outward (N's tiles are the first N of any larger N's), tiles are real SRTM 3"
files that neighbours agree with on their shared edge and that `ingest --plan` places by name,
a second run writes nothing, placeholders hold no disk, the GEBCO-size VRT is nodata outside
its regions, and bad arguments are one line."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import rasterio

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def mp() -> Iterator[ModuleType]:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import make_planet

        yield make_planet
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_cells_grow_outward_over_land(mp: ModuleType) -> None:
    import scale_planet

    big = mp.compact_cells(40, (46.5, 10.5))
    assert mp.compact_cells(7, (46.5, 10.5)) == big[:7]
    assert big[0] == (46, 10)  # the cell holding the centre (the Alps are land)
    land = scale_planet.land_cells(mp.ETOPO)
    assert all(land[89 - lat, lon + 180] for lat, lon in big)
    assert len(set(big)) == len(big)


def test_tiles_are_srtm3_files_written_once(mp: ModuleType, tmp_path: Path) -> None:
    from globeview.terrain.ingest.footprints import footprints

    listing, made, _ = mp.ensure_srtm(tmp_path, 2, (46.5, 10.5), placeholders=False)
    names = listing.read_text().split()
    assert made == 2 and names == ["N46E010.hgt", "N46E009.hgt"]
    assert mp.ensure_srtm(tmp_path, 2, (46.5, 10.5), placeholders=False)[1] == 0  # lazy
    assert not list(tmp_path.glob("*.part"))
    east, west = (tmp_path / n for n in names)
    assert east.stat().st_size == 1201 * 1201 * 2
    with rasterio.open(east) as a, rasterio.open(west) as b:
        assert a.driver == "SRTMHGT"
        assert a.bounds.left == pytest.approx(10.0 - 1.5 / 3600)  # pixel-is-point, 3"
        za, zb = a.read(1), b.read(1)
    assert np.array_equal(za[:, 0], zb[:, -1])  # the shared meridian, sample for sample
    assert za.min() > 0 and za.max() < 9000 and za.std() > 10.0  # land with relief
    table = footprints([east], how="name")  # by name and size, as `ingest --plan` does
    assert table.west[0] == pytest.approx(10.0 - 3 / 3600) and table.res[0] == 3 / 3600


def test_placeholders_hold_no_disk(mp: ModuleType, tmp_path: Path) -> None:
    listing, made, _ = mp.ensure_srtm(tmp_path, 3, (0.0, 0.0), placeholders=True)
    files = [tmp_path / n for n in listing.read_text().split()]
    assert made == 3 and all(f.stat().st_size == mp.SRTM1_BYTES for f in files)
    assert sum(f.stat().st_blocks for f in files) == 0  # holes only


def test_the_gebco_grid_is_nodata_outside_its_regions(
    mp: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(mp, "GEBCO_REGIONS", ((46, 10),))
    monkeypatch.setattr(mp, "GEBCO_REGION_DEG", 1)  # one 240^2 region: cheap
    vrt, _ = mp.make_gebco(tmp_path, netcdf=False)
    with rasterio.open(vrt) as ds:
        assert (ds.width, ds.height) == (86_400, 43_200) and ds.nodata == mp.GEBCO_NODATA
        row, col = ds.index(10.5, 46.5)
        inside = ds.read(1, window=((row - 8, row + 8), (col - 8, col + 8)))
        outside = ds.read(1, window=((row - 8, row + 8), (col + 400, col + 416)))
    assert (inside > 0).all() and (outside == mp.GEBCO_NODATA).all()


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["srtm", "--tiles", "0"], "--tiles"),
        (["srtm", "--tiles", "2", "--center", "x"], "--center"),
        (["srtm", "--tiles", "99999"], "--tiles"),
    ],
)
def test_bad_arguments_are_one_line(
    mp: ModuleType, argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert mp.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("make_planet: error: ") and needle in err[0]
