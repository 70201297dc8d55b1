"""Projects and bookmarks through the Python API (issue #26 item 4): a globe saved to a
project file and reopened draws the same picture (real EGL, a real DEM file from data/),
relative paths, missing layers reported per layer, bad files refused in one line, and
nothing partial left when the folder cannot be written."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import numpy as np
import pytest

import globeview
from globeview.errors import GlobeviewError
from globeview.plugins.api import PluginKind

SIZE = (240, 160)
#: A project's first lines, up to its camera's numbers.
HEAD = "schema = 1\n[camera]\n"


@pytest.fixture(scope="module")
def dem_file(tmp_path_factory, white_mountains) -> Path:
    """The White Mountains (data/N44W072.hgt, thinned) as a GeoTIFF in a folder of its own,
    beside the projects' folder (so a project names it as ../dems/white_mountains.tif)."""
    import rasterio

    heights, transform, crs = white_mountains
    path = tmp_path_factory.mktemp("dems") / "white_mountains.tif"
    profile = {
        "driver": "GTiff",
        "width": heights.shape[1],
        "height": heights.shape[0],
        "count": 1,
        "dtype": heights.dtype,
        "crs": crs,
        "transform": transform,
    }
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(heights, 1)
    return path


@pytest.fixture(scope="module")
def saved(tmp_path_factory, api_cache, dem_file, registry):
    """A globe on the DEM file with the country borders, a LOD provider with a setting,
    hillshade, the collapse tool's A and B and two bookmarks; saved to a project. Yields
    (globe, project path)."""
    from globeview.terrain.dem.data import EMBEDDED_DATA_DIR

    globe = globeview.Globe(registry=registry)
    globe.add_dem(dem_file, name="wm")
    borders = globe.add_overlay(EMBEDDED_DATA_DIR / "ne_110m_countries.geojson", "vector")
    borders.set_style(color=(0.2, 0.9, 1.0, 1.0), width_px=3.0)
    globe.set_lod("chunked-sse")
    globe.tau_px = 3.0
    globe.display.hillshade = True
    globe.display.exaggeration = 1.5
    globe.fly_to(-71.45, 44.12, 9000.0, heading=40.0, pitch=-30.0)
    globe.add_bookmark("washington", (-71.3036, 44.2705, 6000.0, 0.0, -60.0))
    globe.add_bookmark("here")
    folder = tmp_path_factory.mktemp("projects")
    path = globe.save_project(folder / "wm.toml")
    yield globe, path
    globe.close()


def test_the_file_is_readable_toml_with_relative_paths(saved, dem_file):
    _, path = saved
    doc = tomllib.loads(path.read_text())
    assert doc["schema"] == 1
    rel = f"../{dem_file.parent.name}/white_mountains.tif"
    assert doc["dems"] == [{"name": "wm", "path": rel, "visible": True}]
    assert doc["overlays"][0]["embedded"] == "ne_110m_countries.geojson"
    assert doc["overlays"][0]["style"]["width_px"] == 3.0
    assert doc["camera"]["lon"] == pytest.approx(-71.45)
    assert doc["lod"]["provider"] == "chunked-sse" and doc["lod"]["tau_px"] == 3.0
    assert doc["display"]["hillshade"] is True
    assert [b["name"] for b in doc["bookmarks"]] == ["washington", "here"]
    assert not any(p.name.endswith(".tmp") for p in path.parent.iterdir())


@pytest.mark.gl
@pytest.mark.slow  # a render on llvmpipe, over 1 s
def test_reopened_project_renders_the_same_picture(saved, registry):
    globe, path = saved
    before = globe.render(SIZE)
    again = globeview.Globe.open_project(path, registry=registry)
    try:
        assert again.project_problems == []
        assert again.dems == ["wm"]
        assert again.display.hillshade and again.display.exaggeration == 1.5
        assert again.tau_px == 3.0
        assert again.bookmarks.names == ["washington", "here"]
        after = again.render(SIZE)
    finally:
        again.close()
    diff = np.abs(before.astype(int) - after.astype(int)).max(axis=2)
    # The terrain is there (not the bare ellipsoid) and the pictures are the same.
    assert before[80:, :, :3].std() > 5.0
    assert int(diff.max()) == 0, f"{int((diff > 0).sum())} pixels differ, by up to {diff.max()}"


@pytest.mark.gl
@pytest.mark.slow  # a render on llvmpipe, over 1 s
def test_the_collapse_tool_and_its_points_come_back(tmp_path, api_cache, dem_file, registry):
    globe = globeview.Globe(registry=registry)
    globe.add_dem(dem_file)
    globe.fly_to(-71.3, 44.3, 60000.0)
    globe.model.tool = "collapse"
    tool = registry.find(PluginKind.TOOL, "collapse")
    tool.place_points([(-71.5, 44.3), (-71.1, 44.3)])
    collapsed = globe.render(SIZE)
    path = globe.save_project(tmp_path / "c.toml")
    tool.cancel()
    globe.model.tool = None
    flat = globe.render(SIZE)
    assert np.abs(flat.astype(int) - collapsed.astype(int)).max() > 30  # the fold shows
    doc = tomllib.loads(path.read_text())
    assert doc["tool"]["name"] == "collapse"
    assert doc["tool"]["points"] == [[-71.5, 44.3], [-71.1, 44.3]]
    again = globeview.Globe.open_project(path, registry=registry)
    try:
        assert again.model.tool == "collapse"
        assert (tool.a, tool.b) == ((-71.5, 44.3), (-71.1, 44.3))
        assert tool.state == "collapsed"
        assert int(np.abs(again.render(SIZE).astype(int) - collapsed.astype(int)).max()) == 0
    finally:
        tool.cancel()
        again.model.tool = None
        again.close()
        globe.close()


def test_bookmarks_add_goto_replace(registry):
    globe = globeview.Globe(registry=registry)
    globe.fly_to(10.0, 46.0, 5000.0)
    globe.add_bookmark("alps")
    globe.fly_to(-71.0, 44.0, 9000.0, heading=30.0, pitch=-40.0)
    globe.add_bookmark("wm")
    pose = globe.goto_bookmark("alps")
    assert (pose.lon, pose.lat) == pytest.approx((10.0, 46.0))
    assert pose.height == pytest.approx(5000.0, abs=1e-3)
    globe.add_bookmark("alps", (11.0, 47.0, 3000.0))
    assert globe.bookmarks.names == ["alps", "wm"]
    assert globe.bookmarks["alps"].pose[:3] == pytest.approx((11.0, 47.0, 3000.0))
    with pytest.raises(GlobeviewError, match="no bookmark named 'nowhere'"):
        globe.goto_bookmark("nowhere")
    with pytest.raises(GlobeviewError, match="finite"):
        globe.add_bookmark("bad", (float("nan"), 0.0, 100.0))
    with pytest.raises(GlobeviewError, match=r"1\.\.200 characters"):
        globe.add_bookmark("  ")


def test_missing_layers_are_reported_per_layer_and_the_rest_opens(
    tmp_path, api_cache, dem_file, registry
):
    os.symlink(dem_file, tmp_path / "wm.tif")
    (tmp_path / "p.toml").write_text(
        "schema = 1\n[camera]\nlon = -71.3\nlat = 44.3\nheight = 9000.0\n"
        '[[dems]]\nname = "gone"\npath = "nowhere/gone.tif"\n'
        '[[dems]]\nname = "abs"\npath = "/etc/passwd"\n'
        '[[dems]]\nname = "up"\npath = "../../../../../../etc/hostname"\n'
        '[[dems]]\nname = "wm"\npath = "wm.tif"\n'
        '[[overlays]]\nname = "dir"\npath = "."\n'
        '[[overlays]]\nname = "out"\nembedded = "../../pyproject.toml"\n'
    )
    globe = globeview.Globe.open_project(tmp_path / "p.toml", registry=registry)
    try:
        assert globe.dems == ["wm"]
        problems = globe.project_problems
        assert len(problems) == 5, problems
        assert problems[0].startswith("DEM layer 'gone': 'nowhere/gone.tif': no such file")
        assert "absolute path" in problems[1]
        assert problems[2].startswith("DEM layer 'up': ")
        assert problems[3] == "overlay 'dir': '.' is not a file"
        assert problems[4] == "overlay 'out': '../../pyproject.toml' is not a file globeview ships"
        assert all("\n" not in p for p in problems)
    finally:
        globe.close()


def _project(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "bad.toml"
    path.write_text("schema = 1\n[camera]\nlon = 0.0\nlat = 0.0\nheight = 1e7\n" + body)
    return path


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("schema = 2\n",
         "has project schema 2, from a newer globeview; this globeview reads schema 1"),
        ("not toml at all [", "is not a globeview project (not TOML"),
        ("[camera]\nlon = 0\n", "is not a globeview project (no `schema = 1` line)"),
        (f"{HEAD}lon = nan\nlat = 0.0\nheight = 1.0\n", "camera.lon = nan must be a finite"),
        (f"{HEAD}lon = 0.0\nlat = 91.0\nheight = 1.0\n", "latitude"),
        ("schema = 1\nlayers = []\n", "unknown key layers"),
    ],
)  # fmt: skip
def test_files_that_are_not_projects_are_one_line(tmp_path, registry, text, message):
    path = tmp_path / "p.toml"
    path.write_text(text)
    with pytest.raises(GlobeviewError, match="^.*" + _re(message)) as info:
        globeview.Globe.open_project(path, registry=registry)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ('[[overlays]]\npath = "x.geojson"\nopacity = -0.5\n',
         "overlays[0].opacity = -0.5 must be a finite number in 0..1"),
        ('[lod]\nprovider = "no-such-lod"\n', "no-such-lod"),
        ('[lod]\nprovider = "chunked-sse"\n[lod.settings]\nwarp = 3\n',
         "chunked-sse has no setting 'warp'"),
        ('[tool]\nname = "no-such-tool"\n', "no enabled tool named 'no-such-tool'"),
        ('[[overlays]]\npath = "x.geojson"\n[overlays.style]\nwidth_px = -1\n', "width_px"),
        ('[display]\nexaggeration = inf\n', "display.exaggeration"),
    ],
)  # fmt: skip
def test_hostile_values_are_one_line_and_nothing_opens(tmp_path, registry, body, message):
    with pytest.raises(GlobeviewError, match=_re(message)) as info:
        globeview.Globe.open_project(_project(tmp_path, body), registry=registry)
    assert "\n" not in str(info.value)


def test_a_directory_a_fifo_or_a_missing_file_is_one_line(tmp_path, registry):
    with pytest.raises(GlobeviewError, match="is a directory, not a project file"):
        globeview.Globe.open_project(tmp_path, registry=registry)
    os.mkfifo(tmp_path / "fifo.toml")
    with pytest.raises(GlobeviewError, match="is not a regular file"):
        globeview.Globe.open_project(tmp_path / "fifo.toml", registry=registry)
    with pytest.raises(GlobeviewError, match="cannot read project"):
        globeview.Globe.open_project(tmp_path / "none.toml", registry=registry)


@pytest.mark.parametrize("fault", ["enospc", "erofs"])
def test_saving_to_a_full_disk_or_read_only_folder_leaves_nothing(tmp_path, registry, fault):
    globe = globeview.Globe(registry=registry)
    (tmp_path / "keep.toml").write_text("old")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GLOBEVIEW_FAULT_WRITE", fault)
        with pytest.raises(GlobeviewError) as info:
            globe.save_project(tmp_path / "keep.toml")
    assert "\n" not in str(info.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.toml"]
    assert (tmp_path / "keep.toml").read_text() == "old"


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_saving_into_a_read_only_folder_is_one_line(tmp_path, registry):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(GlobeviewError, match="project"):
            globeview.Globe(registry=registry).save_project(folder / "p.toml")
        assert list(folder.iterdir()) == []
    finally:
        folder.chmod(0o700)


def test_a_newer_schemas_tours_are_kept_and_an_array_dem_is_left_out(
    tmp_path, api_cache, white_mountains, registry, caplog
):
    from globeview.model.project import parse_project, project_text

    text = _project(tmp_path, '[[tours]]\nname = "t"\n').read_text()
    assert parse_project(text).tours == [{"name": "t"}]
    assert parse_project(project_text(parse_project(text))).tours == [{"name": "t"}]
    heights, transform, crs = white_mountains
    globe = globeview.Globe(registry=registry)
    globe.add_dem(heights, transform=transform, crs=crs, name="arr")
    with caplog.at_level("WARNING", logger="globeview.project"):
        path = globe.save_project(tmp_path / "a.toml")
    assert "DEM layer 'arr' has no file a project can name; left out" in caplog.text
    assert tomllib.loads(path.read_text())["dems"] == []


def _re(text: str) -> str:
    import re

    return re.escape(text)


def test_crs_and_vdatum_given_when_opened_are_saved_and_used_again(
    tmp_path, api_cache, dem_file, registry
):
    globe = globeview.Globe(registry=registry)
    globe.add_dem(dem_file, crs="EPSG:4326", vdatum="ellipsoid", name="wm_ell")
    path = globe.save_project(tmp_path / "v.toml")
    dem = tomllib.loads(path.read_text())["dems"][0]
    assert (dem["crs"], dem["vdatum"]) == ("EPSG:4326", "ellipsoid")
    again = globeview.Globe.open_project(path, registry=registry)
    plain = globeview.Globe(registry=registry)
    plain.add_dem(dem_file)  # its own datum, EGM96: the geoid is about 28 m below WGS84 here
    point = (-71.3036, 44.2705)
    assert again.height_at(*point) == globe.height_at(*point)
    assert abs(plain.height_at(*point) - again.height_at(*point)) > 10.0


def test_a_store_folder_is_named_relative_to_the_project(tmp_path, api_cache, dem_file, registry):
    from globeview.terrain.ingest.driver import ingest

    (tmp_path / "stores").mkdir()
    ingest([dem_file], tmp_path / "stores" / "wm")
    globe = globeview.Globe(registry=registry)
    globe.add_dem(tmp_path / "stores" / "wm", name="store")
    (tmp_path / "p").mkdir()
    path = globe.save_project(tmp_path / "p" / "s.toml")
    assert tomllib.loads(path.read_text())["dems"][0]["path"] == "../stores/wm"
    again = globeview.Globe.open_project(path, registry=registry)
    assert again.project_problems == [] and again.dems == ["store"]
    assert again.height_at(-71.3036, 44.2705) == globe.height_at(-71.3036, 44.2705)


def test_layers_of_one_name_stay_apart(tmp_path, api_cache, dem_file, registry):
    os.symlink(dem_file, tmp_path / "wm.tif")
    (tmp_path / "p.toml").write_text(
        f"{HEAD}lon = -71.3\nlat = 44.3\nheight = 9000.0\n"
        '[[dems]]\nname = "wm"\npath = "wm.tif"\n'
        '[[dems]]\nname = "wm"\npath = "wm.tif"\nvisible = false\n'
    )
    globe = globeview.Globe.open_project(tmp_path / "p.toml", registry=registry)
    assert globe.dems == ["wm", "wm (2)"]
    assert [ly.visible for ly in globe.terrain.layers] == [True, False]


@pytest.mark.gl
@pytest.mark.slow  # two renders on llvmpipe, over 1 s
def test_a_gis_layer_keeps_its_layer_and_style(tmp_path, api_cache, dem_file, registry):
    """A GeoPackage's second layer coloured by a field, labelled and widened comes back from
    its project the same: the same layer of the file, legend, options and picture."""
    from .gis_samples import COLUMN_LON, ROW_LAT, write_gpkg

    gpkg = write_gpkg(tmp_path / "wm.gpkg")
    globe = globeview.Globe(registry=registry)
    try:
        globe.add_dem(dem_file, name="wm")
        trails = globe.add_vectors(gpkg, "trails", color_by="name", label="name", width_px=4.0)
        globe.fly_to(COLUMN_LON, ROW_LAT, 40000.0)
        before = globe.render(SIZE)
        path = globe.save_project(tmp_path / "gis.toml")
        opened = globe.overlay_host.opened_style(trails)
    finally:
        globe.close()
    doc = tomllib.loads(path.read_text())
    assert doc["overlays"][0]["path"] == "wm.gpkg" and doc["overlays"][0]["type"] == "gis"
    assert doc["overlays"][0]["open"] == {
        "layer": "trails",
        "color_by": "name",
        "label": "name",
        "width_px": 4.0,
    }
    again = globeview.Globe.open_project(path, registry=registry)
    try:
        assert again.project_problems == []
        (layer,) = again.overlays
        assert again.overlay_host.opened_style(layer) == opened
        assert [(e.label, e.color) for e in layer.legend] == [
            (e.label, e.color) for e in trails.legend
        ]
        assert [e.label for e in layer.legend] == ["Appalachian Trail"]  # trails, not roads
        widths = {p.width_px for p in layer.parts if hasattr(p, "width_px")}
        assert widths == {4.0}
        after = again.render(SIZE)
    finally:
        again.close()
    diff = np.abs(before.astype(int) - after.astype(int)).max(axis=2)
    assert int(diff.max()) == 0, f"{int((diff > 0).sum())} pixels differ, by up to {diff.max()}"


def test_hostile_gis_options_are_one_line_for_that_layer(tmp_path, registry):
    from .gis_samples import write_gpkg

    write_gpkg(tmp_path / "wm.gpkg")
    entry = '[[overlays]]\nname = "{}"\npath = "wm.gpkg"\ntype = "gis"\nopen = {}\n'
    path = _project(
        tmp_path,
        entry.format("field", '{ layer = "trails", color_by = "colour" }')
        + entry.format("nan", '{ layer = "trails", width_px = nan }')
        + entry.format("huge", "{ width_px = 1e9 }")
        + entry.format("option", "{ colour = 3 }")
        + entry.format("layer", '{ layer = "rivers" }')
        + entry.format("text", '{ width_px = "3" }')
        + entry.format("ok", '{ layer = "roads", color_by = "kind" }')
        # Another layer type's options are not kept: it may not check them (a TypeError
        # from the built-in vector type would disable it for the session).
        + '[[overlays]]\nname = "vector"\nembedded = "ne_110m_countries.geojson"\n'
        'type = "vector"\nopen = { bogus = 1 }\n',
    )
    globe = globeview.Globe.open_project(path, registry=registry)
    try:
        problems = globe.project_problems
        assert len(problems) == 7, problems
        assert problems[0].startswith("overlay 'field': ") and "no field 'colour'" in problems[0]
        assert problems[1] == "overlay 'nan': width_px nan is not in (0, 200]"
        assert problems[2] == "overlay 'huge': width_px 1000000000.0 is not in (0, 200]"
        assert problems[3].startswith("overlay 'option': no vector style 'colour'")
        assert problems[4].startswith("overlay 'layer': wm.gpkg: no layer 'rivers'")
        assert problems[5] == "overlay 'text': width_px '3' is not a positive number"
        assert problems[6] == (
            "overlay 'vector': open options are for the gis layer type; this file opens as vector"
        )
        assert all("\n" not in p for p in problems)
        (layer,) = globe.overlays
        assert [e.label for e in layer.legend] == ["road"]
        # The user's values: the types stay enabled.
        assert registry.failure_of("gis") is None and registry.failure_of("vector") is None
    finally:
        globe.close()
