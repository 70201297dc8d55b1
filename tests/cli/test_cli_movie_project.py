"""`globeview movie PROJECT.toml -o out` (issue #26 items 4 and 5): the project's tour filmed
over the project's own layers and display, its first frame the picture `globeview render
PROJECT.toml` draws at the project's camera (the tour's start); a project without a tour,
with DEMs given too, or with an option the project sets is one line, exit 2, nothing
written."""

from __future__ import annotations

import os
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest
from PIL import Image

from .run_cli import globeview, one_error_line

pytestmark = [pytest.mark.gl, pytest.mark.slow]

DEM = Path(__file__).resolve().parents[2] / "data" / "N44W072.hgt"
#: As tests/cli/test_cli_movie.py: coding differs from the still by ~2.5; the views by ~40.
CODEC_TOLERANCE = 5.0
TOUR = (
    '[[tours]]\nname = "washington"\n'
    "[[tours.keyframes]]\nlon = -71.6\nlat = 44.0\nheight = 40000.0\n"
    "[[tours.keyframes]]\nlon = -71.35\nlat = 44.2\nheight = 9000.0\nheading = 40.0\n"
    "pitch = -35.0\nseconds = 2.0\n"
)


@pytest.fixture(scope="module")
def cache(tmp_path_factory, seed_dem_store) -> Path:
    """The module's cache folder, holding DEM's store (copied, not ingested again)."""
    return seed_dem_store(tmp_path_factory.mktemp("movie-project-cache"), DEM)


def project(folder: Path, tour: str = TOUR) -> Path:
    """A project on data/N44W072.hgt (named relative to it) with hillshade, at the tour's
    first camera, and ``tour``."""
    rel = Path(os.path.relpath(DEM, folder)).as_posix()
    path = folder / "p.toml"
    path.write_text(
        "schema = 1\n[camera]\nlon = -71.6\nlat = 44.0\nheight = 40000.0\n"
        f'[display]\nhillshade = true\n[[dems]]\nname = "wm"\npath = "{rel}"\n{tour}'
    )
    return path


def test_a_projects_tour_is_filmed_over_its_layers(cache: Path, tmp_path: Path) -> None:
    path = project(tmp_path)
    out = tmp_path / "m.gif"
    res = globeview(
        "movie", str(path), "-o", str(out), "--size", "48x32", "--fps", "2", cache=cache
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith(f"wrote {out} (48x32, 4 frames, 2 s of tour at 2 fps)")
    reader = imageio_ffmpeg.read_frames(str(out))
    w, h = next(reader)["size"]
    frames = [np.frombuffer(b, np.uint8).reshape(h, w, 3) for b in reader]
    assert (w, h) == (48, 32) and len(frames) == 4
    png = tmp_path / "still.png"
    res = globeview("render", str(path), "--size", "48x32", "-o", str(png), cache=cache)
    assert res.returncode == 0, res.stderr
    still = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert float(np.abs(frames[0].astype(int) - still).mean()) < CODEC_TOLERANCE
    assert float(np.abs(frames[-1].astype(int) - still).mean()) > 3 * CODEC_TOLERANCE


@pytest.mark.parametrize(
    ("tour", "extra", "word"),
    [
        ("", [], "has no tour to film"),
        (TOUR, [str(DEM)], "a project films its own layers"),
        (TOUR, ["--hillshade"], "--hillshade does not apply to a project"),
    ],
)
def test_bad_project_movies_are_one_line(cache, tmp_path, tour, extra, word) -> None:
    path = project(tmp_path, tour)
    out = tmp_path / "m.mp4"
    res = globeview("movie", str(path), *extra, "-o", str(out), "--size", "48x32", cache=cache)
    assert word in one_error_line(res)
    assert not out.exists()


def test_a_tour_with_a_bad_keyframe_is_a_warning_and_no_movie(cache, tmp_path) -> None:
    path = project(tmp_path, TOUR.replace("lat = 44.2", "lat = 95.0"))
    out = tmp_path / "m.mp4"
    res = globeview("movie", str(path), "-o", str(out), "--size", "48x32", cache=cache)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    warning, error = res.stderr.strip().splitlines()
    assert warning.startswith("globeview: warning: p.toml: tour 'washington': keyframe 2: lat")
    assert error.startswith("globeview: error: ") and "has no tour to film" in error
    assert not out.exists()
