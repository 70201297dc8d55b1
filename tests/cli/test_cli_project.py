"""``globeview render PROJECT.toml`` and ``globeview PROJECT.toml`` (issue #26 item 4): a
project saved from a `globeview.Globe` on a real DEM file (data/N44W072.hgt, thinned) is
drawn headless by the installed command to the very picture the API draws; missing layers
are one warning line each while the rest is drawn (``--strict``: nothing written); a file
that is not a project, a newer schema or a hostile value is one error line, exit 2, before
any window or GL. Real processes of the installed command (forked by `zygote`)."""

from __future__ import annotations

import os
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w
import zygote
from PIL import Image

import globeview

from .run_cli import GLOBEVIEW, one_error_line
from .run_cli import globeview as run_globeview

SIZE = (200, 140)


@pytest.fixture(scope="module")
def project(tmp_path_factory) -> tuple[Path, np.ndarray, Path]:
    """(project path, the API's RGBA picture of it, the cache folder): the White Mountains
    as a GeoTIFF beside the project, hillshade on, looking north-east over Mt Washington."""
    import rasterio
    from affine import Affine

    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.terrain.dem.data import EMBEDDED_DATA_DIR

    root = tmp_path_factory.mktemp("cli-project")
    cache = root / "cache"
    with rasterio.open(EMBEDDED_DATA_DIR / "N44W072.hgt") as src:
        heights = src.read(1)[::4, ::4].copy()
        profile = {
            "driver": "GTiff",
            "width": heights.shape[1],
            "height": heights.shape[0],
            "count": 1,
            "dtype": heights.dtype,
            "crs": src.crs,
            "transform": src.transform @ Affine.scale(4),
        }
    (root / "dems").mkdir()
    with rasterio.open(root / "dems" / "wm.tif", "w", **profile) as dst:
        dst.write(heights, 1)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GLOBEVIEW_CACHE_DIR", str(cache))
        globe = globeview.Globe(registry=PluginRegistry(MemorySettings()).discover())
        try:
            globe.add_dem(root / "dems" / "wm.tif")
            globe.display.hillshade = True
            globe.fly_to(-71.45, 44.12, 9000.0, heading=40.0, pitch=-30.0)
            path = globe.save_project(root / "wm.toml")
            rgba = globe.render(SIZE)
        finally:
            globe.close()
    return path, rgba, cache


def gv(*args: str, cache: Path) -> subprocess.CompletedProcess:
    return run_globeview(*args, cache=cache)


@pytest.mark.gl
@pytest.mark.slow
def test_render_project_draws_the_apis_picture(project, tmp_path):
    path, rgba, cache = project
    out = tmp_path / "out.png"
    res = gv("render", str(path), "-o", str(out), "--size", f"{SIZE[0]}x{SIZE[1]}", cache=cache)
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""
    assert f"wrote {out} ({SIZE[0]}x{SIZE[1]}; project {path}: 1 DEM(s), 0 overlay(s))" in (
        res.stdout
    )
    got = np.asarray(Image.open(out).convert("RGBA"))
    assert got.shape == rgba.shape
    assert rgba[70:, :, :3].std() > 5.0  # terrain, not the bare ellipsoid
    assert int(np.abs(got.astype(int) - rgba.astype(int)).max()) == 0


@pytest.mark.gl
@pytest.mark.slow
def test_missing_layers_are_warnings_and_strict_refuses(project, tmp_path):
    path, _, cache = project
    doc = tomllib.loads(path.read_text())
    doc["dems"].insert(0, {"name": "gone", "path": "gone.tif"})
    moved = path.parent / "with_gone.toml"
    moved.write_text(tomli_w.dumps(doc))
    out = tmp_path / "out.png"
    res = gv("render", str(moved), "-o", str(out), "--size", "64x48", cache=cache)
    assert res.returncode == 0, res.stderr
    assert res.stderr.splitlines() == [
        "globeview: warning: with_gone.toml: DEM layer 'gone': 'gone.tif': no such file "
        f"(looked in {path.parent})"
    ]
    assert "1 DEM(s), 0 overlay(s), 1 layer(s) missing" in res.stdout and out.is_file()
    strict = tmp_path / "strict.png"
    res = gv("render", str(moved), "-o", str(strict), "--strict", cache=cache)
    assert "1 layer(s) missing; nothing written (--strict)" in res.stderr.splitlines()[-1]
    assert res.returncode == 2 and not strict.exists()


@pytest.mark.slow
@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("schema = 7\n",
         "has project schema 7, from a newer globeview; this globeview reads schema 1"),
        ("\x00\x01binary", "is not a globeview project"),
        ("schema = 1\n[camera]\nlon = nan\nlat = 0.0\nheight = 1.0\n", "camera.lon = nan"),
        ("schema = 1\n[camera]\nlon = 0.0\nlat = 0.0\nheight = 1.0\n[lod]\nprovider = \"nope\"\n",
         "no enabled LOD provider named 'nope'"),
    ],
)  # fmt: skip
def test_bad_projects_are_one_line_for_render_and_the_window(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    res = gv("render", str(path), "-o", str(tmp_path / "x.png"), cache=tmp_path / "cache")
    assert message in one_error_line(res)
    assert not (tmp_path / "x.png").exists()
    # `globeview PROJECT.toml` checks the file before any window (here: there is no display).
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.pop("QT_QPA_PLATFORM", None)
    env.pop("GLOBEVIEW_DEBUG", None)
    env["GLOBEVIEW_CACHE_DIR"] = str(tmp_path / "cache")
    res = zygote.run(
        [str(GLOBEVIEW), str(path)], capture_output=True, text=True, env=env, timeout=120
    )
    assert message in one_error_line(res)


@pytest.mark.slow
def test_a_project_is_opened_alone_and_without_view_options(project, tmp_path):
    path, _, cache = project
    res = gv("render", str(path), "--camera", "0,0,1e7", "-o", str(tmp_path / "x.png"), cache=cache)
    assert "--camera does not apply to a project" in one_error_line(res)
    res = gv("render", str(path), str(path), "-o", str(tmp_path / "x.png"), cache=cache)
    assert "a project opens alone" in one_error_line(res)


def test_the_render_summary_counts_tours_apart_from_layers():
    from globeview.cli.project import left_out

    tour = "tour 'bad': keyframe 2: lat 95.0 is not within [-90, 90]"
    assert left_out([tour]) == "1 tour left out"
    assert left_out(["DEM layer 'gone': no such file", tour, tour]) == (
        "1 layer(s) missing, 2 tours left out"
    )


@pytest.mark.gl
@pytest.mark.slow
def test_a_bad_tour_is_not_counted_as_a_missing_layer(project, tmp_path):
    path, _, cache = project
    doc = tomllib.loads(path.read_text())
    doc["tours"] = [{"name": "bad", "keyframes": [{"lon": 1.0, "lat": 95.0, "height": 3e3}]}]
    moved = path.parent / "badtour.toml"
    moved.write_text(tomli_w.dumps(doc))
    out = tmp_path / "out.png"
    res = gv("render", str(moved), "-o", str(out), "--size", "64x48", cache=cache)
    assert res.returncode == 0, res.stderr
    assert "1 DEM(s), 0 overlay(s), 1 tour left out)" in res.stdout and out.is_file()
