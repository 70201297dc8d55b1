"""A folder of DEM tiles as an ingest source (issue #18: "point globeview ingest at a folder
of DEM tiles"): the folder is its DEM files, sorted; sidecars, hidden files, VRTs and
subfolders are not read; an empty folder or a store folder is one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
from inprocess_cli import run_globeview
from rasterio.windows import Window

from globeview.errors import DemError
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.ingest.sources import expand_sources

SRTM = Path(__file__).resolve().parents[2] / "data" / "N44W072.hgt"
# A 480 x 480 part of the SRTM3 tile (0.4 degree) inside one chunk of every level: a store of
# 13 chunks, ~2.4 CPU-s to ingest (the whole tile's 29 chunks take ~4.3).
PART = Window(400, 360, 480, 480)


@pytest.fixture(scope="module")
def dem(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`PART` of the SRTM3 tile as a GeoTIFF with its georeferencing and tags."""
    path = tmp_path_factory.mktemp("dem") / "srtm_part.tif"
    with rasterio.open(SRTM) as ds:
        prof = ds.profile | {
            "driver": "GTiff",
            "width": PART.width,
            "height": PART.height,
            "transform": ds.window_transform(PART),
        }
        with rasterio.open(path, "w", **prof) as dst:
            dst.write(ds.read(1, window=PART), 1)
            dst.update_tags(**ds.tags())
    return path


def split_into_tiles(src: Path, folder: Path) -> list[Path]:
    """Cut a DEM into 4 GeoTIFF quarters (sharing no pixels), georeferenced as the source."""
    folder.mkdir()
    out = []
    with rasterio.open(src) as ds:
        h, w = ds.height, ds.width
        for i, (r0, c0) in enumerate([(0, 0), (0, w // 2), (h // 2, 0), (h // 2, w // 2)]):
            ww = w // 2 if c0 == 0 else w - w // 2
            hh = h // 2 if r0 == 0 else h - h // 2
            win = Window(c0, r0, ww, hh)
            prof = ds.profile | {
                "driver": "GTiff",
                "width": int(win.width),
                "height": int(win.height),
                "transform": ds.window_transform(win),
            }
            p = folder / f"tile_{i}.tif"
            with rasterio.open(p, "w", **prof) as dst:
                dst.write(ds.read(1, window=win), 1)
                dst.update_tags(**ds.tags())
            out.append(p)
    return out


def manifest_arrays(store: Path) -> dict:
    """Every chunk's sha256 and its tiles' facts (errors, hmin, hmax; NaN as None), by
    (level, cy, cx): equal for stores with the same contents (store format 7's shards)."""
    from globeview.terrain.store.tile_store import TileStore

    st = TileStore.open(store)
    out = {}
    try:
        for lv, cy, cx, f in st._meta.iter_chunks():
            arrays = (f.errors, f.hmin, f.hmax)
            out[(lv, cy, cx)] = (f.sha256, *(np.nan_to_num(a, nan=-1e30).tolist() for a in arrays))
    finally:
        st.close()
    return out


@pytest.mark.slow
def test_a_folder_of_tiles_ingests_as_its_files(tmp_path: Path, dem: Path) -> None:
    tiles = split_into_tiles(dem, tmp_path / "tiles")
    # What a download holds beside the tiles: none of it is a DEM to read.
    (tmp_path / "tiles" / "README.txt").write_text("SRTM tiles")
    (tmp_path / "tiles" / "tile_0.tif.aux.xml").write_text("<PAMDataset/>")
    (tmp_path / "tiles" / ".hidden.tif").write_bytes(b"not a tiff")
    (tmp_path / "tiles" / "sub").mkdir()
    (tmp_path / "tiles" / "sub" / "other.tif").write_bytes(b"not read either")
    assert expand_sources([tmp_path / "tiles"]) == tiles
    a = ingest([tmp_path / "tiles"], tmp_path / "from_folder", vdatum="egm96")
    b = ingest(tiles, tmp_path / "from_files", vdatum="egm96")
    assert not a.up_to_date and not b.up_to_date
    assert manifest_arrays(tmp_path / "from_folder") == manifest_arrays(tmp_path / "from_files")
    recorded = json.loads((tmp_path / "from_folder" / "manifest.json").read_text())["sources"]
    assert [Path(s["path"]) for s in recorded] == tiles  # the files, not the folder
    # The tiles together are the whole DEM: the same heights as the one file.
    c = ingest([dem], tmp_path / "from_one", vdatum="egm96")
    assert c.max_level == a.max_level
    with (
        rasterio.open(tmp_path / "from_one" / f"level_{a.max_level:02d}.vrt") as one,
        rasterio.open(tmp_path / "from_folder" / f"level_{a.max_level:02d}.vrt") as four,
    ):
        x, y = one.read(1), four.read(1)
    assert x.shape == y.shape and np.isfinite(x).mean() > 0.2
    both = np.isfinite(x) & np.isfinite(y)
    same = (x == y) & both
    print("finest-level nodes identical to the one-file store:", same.sum() / both.sum())  # noqa: T201
    # The quarters meet at pixel edges: a node between two quarters' last pixel centres is
    # resampled from one quarter only, so only seam nodes may differ.
    assert same.sum() / both.sum() > 0.99
    # A file named twice, through its folder and directly, is read once.
    assert expand_sources([tmp_path / "tiles", tiles[0]]) == tiles


@pytest.mark.slow
def test_a_tile_changed_in_place_updates_the_store_as_a_full_build_would(
    tmp_path: Path, dem: Path
) -> None:
    tiles = split_into_tiles(dem, tmp_path / "tiles")
    ingest([tmp_path / "tiles"], tmp_path / "s", vdatum="egm96")
    assert ingest([tmp_path / "tiles"], tmp_path / "s", vdatum="egm96").up_to_date
    with rasterio.open(tiles[3], "r+") as ds:
        a = ds.read(1)
        a[10:20, 10:20] += 50
        ds.write(a, 1)
    again = ingest([tmp_path / "tiles"], tmp_path / "s", vdatum="egm96")
    assert not again.up_to_date and 0 < again.chunks_rebuilt <= again.chunks_total
    fresh = ingest([tmp_path / "tiles"], tmp_path / "fresh", vdatum="egm96")
    assert fresh.chunks_rebuilt == fresh.chunks_total
    assert manifest_arrays(tmp_path / "s") == manifest_arrays(tmp_path / "fresh")


@pytest.mark.slow
def test_an_empty_folder_or_a_store_folder_is_one_line(tmp_path: Path, dem: Path) -> None:
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("no DEM here")
    with pytest.raises(DemError, match="is a folder with no DEM files in it"):
        ingest([tmp_path / "empty"], tmp_path / "s")
    ingest([dem], tmp_path / "store", max_level=4)  # any store: its levels do not matter
    with pytest.raises(DemError, match="is a globeview tile store, not a folder of DEM files"):
        ingest([tmp_path / "store"], tmp_path / "s2")
    assert not (tmp_path / "s").exists() and not (tmp_path / "s2").exists()
    res = run_globeview(["ingest", str(tmp_path / "empty"), "--out", str(tmp_path / "s3")])
    assert res.returncode == 2
    assert res.stderr.splitlines() == [
        f"globeview: error: {tmp_path / 'empty'} is a folder with no DEM files in it (looked"
        " for .asc .bil .bt .dem .dt0 .dt1 .dt2 .flt .grd .hgt .img .nc .tif .tiff; subfolders"
        " are not searched)"
    ]
    assert not (tmp_path / "s3").exists()


# -- globs and lists (issue #25: datasets as users get them) ----------------------------------


def _tree(root: Path) -> list[Path]:
    """Copernicus-style per-tile folders: root/<tile>/DEM/<tile>_DEM.tif (empty files: only
    names are expanded here)."""
    out = []
    for name in ("B_N45_00_E009_00", "A_N44_00_W072_00"):
        d = root / name / "DEM"
        d.mkdir(parents=True)
        out.append(d / f"{name}_DEM.tif")
        out[-1].write_bytes(b"x")
        (d.parent / "INFO").mkdir()
        (d.parent / "INFO" / "x.xml").write_text("<x/>")
    return sorted(out)


def test_a_glob_expands_to_its_files_sorted_recursively(tmp_path: Path) -> None:
    files = _tree(tmp_path / "copdem")
    assert expand_sources([str(tmp_path / "copdem" / "**" / "*_DEM.tif")]) == files
    # A glob matching folders too keeps only the files, and duplicates are read once.
    got = expand_sources([str(tmp_path / "copdem" / "*" / "DEM" / "*"), str(files[0])])
    assert got == files


def test_a_list_names_paths_relative_to_itself_with_comments(tmp_path: Path) -> None:
    files = _tree(tmp_path / "copdem")
    lst = tmp_path / "lists" / "tiles.txt"
    lst.parent.mkdir()
    lst.write_text(
        "# two tiles, one relative to this list, one absolute\n\n"
        f"../copdem/{files[1].relative_to(tmp_path / 'copdem')}\n  {files[0]}  \n"
    )
    assert expand_sources([f"@{lst}"]) == [files[1], files[0]]
    # A list may name a glob too.
    lst.write_text("../copdem/**/*_DEM.tif\n")
    assert expand_sources([f"@{lst}"]) == files


def test_empty_globs_and_lists_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(DemError, match=r"nothing\*.hgt matches no files \(a glob: quote it"):
        expand_sources([str(tmp_path / "nothing*.hgt")])
    (tmp_path / "d1").mkdir()
    with pytest.raises(DemError, match="matches only folders"):
        expand_sources([str(tmp_path / "d*")])
    with pytest.raises(DemError, match=r"list of sources not found: .*missing\.txt"):
        expand_sources([f"@{tmp_path / 'missing.txt'}"])
    (tmp_path / "empty.txt").write_text("# nothing\n\n")
    with pytest.raises(DemError, match=r"empty\.txt names no file"):
        expand_sources([f"@{tmp_path / 'empty.txt'}"])
    (tmp_path / "bin.txt").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(DemError, match=r"cannot read the list of sources .*: not UTF-8 text"):
        expand_sources([f"@{tmp_path / 'bin.txt'}"])
