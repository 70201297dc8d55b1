"""A project keeps its tour (issue #26 items 4 and 5 together): `Globe.save_project` writes
`Globe.tour` into the project's ``[[tours]]``, `Globe.open_project` restores it (a tour with
a bad keyframe is one problem line, the rest opens), a reopened project films the same
movie, and `add_keyframe(bookmark=...)` takes a bookmark's view."""

from __future__ import annotations

import tomllib
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

import globeview
from globeview.errors import GlobeviewError
from globeview.model.tour import Keyframe, Tour

#: Mount Washington, looking north-east at an angle (lon, lat, height, heading, pitch).
WASHINGTON = (-71.3036, 44.2705, 9000.0, 40.0, -35.0)
#: High over the south-west of the White Mountains, looking down.
HIGH = (-71.6, 44.0, 40_000.0, 0.0, -90.0)
#: As tests/api/test_api_movie.py: H.264/GIF coding differs from the still by at most ~2.5.
CODEC_TOLERANCE = 5.0
HEAD = "schema = 1\n[camera]\nlon = -71.3\nlat = 44.27\nheight = 40000.0\n"


@pytest.fixture(scope="module")
def dem_file(tmp_path_factory, white_mountains) -> Path:
    """The White Mountains (thinned) as a GeoTIFF, beside the projects' folders."""
    import rasterio

    heights, transform, crs = white_mountains
    path = tmp_path_factory.mktemp("dems") / "wm.tif"
    profile = {"driver": "GTiff", "width": heights.shape[1], "height": heights.shape[0]}
    profile |= {"count": 1, "dtype": heights.dtype, "crs": crs, "transform": transform}
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(heights, 1)
    return path


def _first_frame(globe, out: Path) -> np.ndarray:
    globe.movie(None, out, size=(48, 32), fps=2)
    reader = imageio_ffmpeg.read_frames(str(out))
    w, h = next(reader)["size"]
    return np.frombuffer(next(reader), np.uint8).reshape(h, w, 3)


@pytest.mark.slow
def test_a_saved_tour_reopens_equal_and_films_the_same_first_frame(
    tmp_path, api_cache, dem_file, registry
):
    globe = globeview.Globe(registry=registry)
    reopened = None
    try:
        globe.add_dem(dem_file, name="wm")
        globe.add_bookmark("washington", WASHINGTON)
        globe.add_keyframe(pose=HIGH)
        key = globe.add_keyframe(2.0, bookmark="washington")
        assert key.pose[:5] == pytest.approx(WASHINGTON) and key.seconds == 2.0
        path = globe.save_project(tmp_path / "p.toml")
        doc = tomllib.loads(path.read_text())
        assert doc["schema"] == 1
        assert [t["name"] for t in doc["tours"]] == ["Tour"]  # an unnamed tour gets a name
        assert len(doc["tours"][0]["keyframes"]) == 2

        reopened = globeview.Globe.open_project(path, registry=registry)
        assert reopened.project_problems == []
        assert reopened.tour == Tour(globe.tour.keyframes, "Tour")
        assert reopened.tour is not globe.tour
        a = _first_frame(globe, tmp_path / "a.gif")
        b = _first_frame(reopened, tmp_path / "b.gif")
        diff = float(np.abs(a.astype(int) - b.astype(int)).mean())
        assert diff < CODEC_TOLERANCE
        # The comparison can fail: the view of the tour's end is another picture.
        reopened.fly_to(*WASHINGTON)
        end = reopened.render((48, 32))[..., :3]
        assert float(np.abs(a.astype(int) - end.astype(int)).mean()) > 3 * CODEC_TOLERANCE
    finally:
        globe.close()
        if reopened is not None:
            reopened.close()


def test_a_globe_without_a_tour_saves_no_tours(tmp_path, registry):
    path = globeview.Globe(registry=registry).save_project(tmp_path / "p.toml")
    assert "tours" not in tomllib.loads(path.read_text())
    assert globeview.Globe.open_project(path, registry=registry).tour == Tour()


def test_a_tour_with_a_bad_keyframe_is_one_line_and_the_rest_opens(tmp_path, registry):
    path = tmp_path / "p.toml"
    path.write_text(
        HEAD
        + '[[bookmarks]]\nname = "here"\nlon = 1.0\nlat = 2.0\nheight = 3000.0\n'
        + '[[tours]]\nname = "bad"\n'
        + "[[tours.keyframes]]\nlon = 1.0\nlat = 2.0\nheight = 3000.0\n"
        + "[[tours.keyframes]]\nlon = 1.0\nlat = 95.0\nheight = 3000.0\nseconds = 2.0\n"
        + '[[tours]]\nname = "good"\n'  # hand-written: format and version may be left out
        + "[[tours.keyframes]]\nlon = 1.0\nlat = 2.0\nheight = 3000.0\n"
        + "[[tours.keyframes]]\nlon = 3.0\nlat = 4.0\nheight = 5000.0\nseconds = 2.5\n"
    )
    globe = globeview.Globe.open_project(path, registry=registry)
    assert len(globe.project_problems) == 1
    line = globe.project_problems[0]
    assert line.startswith("tour 'bad': keyframe 2: ") and "lat" in line and "\n" not in line
    assert globe.bookmarks.names == ["here"]
    assert globe.camera.lon == pytest.approx(-71.3)
    assert globe.tour.name == "good" and globe.tour.duration == 2.5


def test_a_second_good_tour_is_named_as_left_out(tmp_path, registry):
    tour = "[[tours]]\nname = 'T{}'\n[[tours.keyframes]]\nlon = 1.0\nlat = 2.0\nheight = 3.0\n"
    path = tmp_path / "p.toml"
    path.write_text(HEAD + tour.format(1) + tour.format(2))
    globe = globeview.Globe.open_project(path, registry=registry)
    assert globe.tour.name == "T1"
    assert globe.project_problems == ["tour 'T2': a globe shows one tour; left out"]


def test_a_keyframe_from_a_bookmark(registry):
    globe = globeview.Globe(registry=registry)
    globe.add_bookmark("washington", WASHINGTON)
    globe.add_keyframe()
    key = globe.add_keyframe(3.0, bookmark="washington")
    assert key == Keyframe(*WASHINGTON, roll=0.0, seconds=3.0)
    assert globe.tour.keyframes[-1] == key and globe.tour.duration == 3.0
    with pytest.raises(GlobeviewError, match=r"no bookmark named 'nowhere' \(\['washington'\]\)"):
        globe.add_keyframe(1.0, bookmark="nowhere")
    with pytest.raises(GlobeviewError, match="a pose or a bookmark, not both"):
        globe.add_keyframe(1.0, pose=HIGH, bookmark="washington")
    with pytest.raises(GlobeviewError, match="seconds"):
        globe.add_keyframe(-1.0, bookmark="washington")
    assert len(globe.tour.keyframes) == 2
