"""`globeview movie` (issue #26 item 5) as a user runs it: the MP4 is read back by ffmpeg's own
decoder (imageio-ffmpeg) with the right frame count and size, its first and last frames are
the pictures `globeview render` draws at the first and last cameras, and bad input is one
line, exit 2, nothing written. (Full and read-only disks, Ctrl-C:
tests/fault/test_fault_movie.py.)"""

from __future__ import annotations

import json
import re
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest
import zygote
from PIL import Image

from .run_cli import globeview, one_error_line

pytestmark = [pytest.mark.gl, pytest.mark.slow]

DEM = str(Path(__file__).resolve().parents[2] / "data" / "N44W072.hgt")
#: From high over the south-west of the tile looking down, to Mount Washington at an angle.
FIRST = "-71.6,44.0,40000,0,-90"
LAST = "-71.35,44.2,9000,40,-35"
CAMERAS = f"{FIRST};{LAST}"
#: Mean absolute difference (0..255) allowed between a decoded frame and the still: H.264 at
#: CRF 18 with 4:2:0 colour measured 2.5 at 96x64 (the API's test); the two views differ ~40.
CODEC_TOLERANCE = 5.0


@pytest.fixture(scope="module")
def cache(tmp_path_factory, seed_dem_store) -> Path:
    """The module's cache folder, holding DEM's store (copied, not ingested again)."""
    return seed_dem_store(tmp_path_factory.mktemp("movie-cache"), Path(DEM))


def decoded(path: Path) -> tuple[tuple[int, int], list[np.ndarray]]:
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    return (w, h), [np.frombuffer(b, np.uint8).reshape(h, w, 3) for b in reader]


def mean_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a[..., :3].astype(int) - b[..., :3].astype(int)).mean())


def still(cache: Path, camera: str, out: Path) -> np.ndarray:
    res = globeview(
        "render", DEM, "--camera", camera, "--size", "96x64", "-o", str(out), cache=cache
    )
    assert res.returncode == 0, res.stderr
    return np.asarray(Image.open(out).convert("RGB"))


def test_mp4_has_the_frames_and_the_stills_of_render(cache: Path, tmp_path: Path) -> None:
    out = tmp_path / "m.mp4"
    res = globeview(
        "movie", "-o", str(out), "--size", "96x64", "--fps", "4", "--seconds", "2",
        "--", CAMERAS, DEM, cache=cache,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""  # no bar off a terminal, no ffmpeg chatter
    assert res.stdout.startswith(f"wrote {out} (96x64, 8 frames, 2 s of tour at 4 fps)")
    size, frames = decoded(out)
    assert size == (96, 64) and len(frames) == 8
    first = still(cache, FIRST, tmp_path / "first.png")
    last = still(cache, LAST, tmp_path / "last.png")
    assert mean_diff(frames[0], first) < CODEC_TOLERANCE
    assert mean_diff(frames[-1], last) < CODEC_TOLERANCE
    assert mean_diff(frames[0], last) > 3 * CODEC_TOLERANCE  # the comparison can fail
    assert sorted(p.name for p in tmp_path.iterdir()) == ["first.png", "last.png", "m.mp4"]


def test_one_camera_is_held_for_the_seconds(cache: Path, tmp_path: Path) -> None:
    """A single camera with --seconds is a hold (the first keyframe's seconds, as
    docs/python_api.md says): fps * seconds frames of that view, not one frame of 0 s."""
    out = tmp_path / "held.mp4"
    res = globeview(
        "movie", "-o", str(out), "--size", "96x64", "--fps", "4", "--seconds", "2",
        "--", FIRST, DEM, cache=cache,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith(f"wrote {out} (96x64, 8 frames, 2 s of tour at 4 fps)")
    size, frames = decoded(out)
    assert size == (96, 64) and len(frames) == 8
    assert mean_diff(frames[0], frames[-1]) < CODEC_TOLERANCE


def test_gif_from_a_json_tour(cache: Path, tmp_path: Path) -> None:
    tour = {
        "format": "globeview-tour",
        "version": 1,
        "name": "two",
        "keyframes": [
            {"lon": -71.6, "lat": 44.0, "height": 40000, "pitch": -90},
            {"lon": -71.35, "lat": 44.2, "height": 9000, "heading": 40, "seconds": 1.5},
        ],
    }
    path = tmp_path / "t.json"
    path.write_text(json.dumps(tour))
    out = tmp_path / "m.gif"
    res = globeview(
        "movie", str(path), DEM, "-o", str(out), "--size", "40x30", "--fps", "4", cache=cache
    )
    assert res.returncode == 0, res.stderr
    size, frames = decoded(out)
    assert size == (40, 30) and len(frames) == 6


def _tour_file(tmp_path: Path, text: str) -> str:
    path = tmp_path / "tour.json"
    path.write_text(text)
    return str(path)


NAN_TOUR = (
    '{"format": "globeview-tour", "version": 1, "keyframes": ['
    '{"lon": -71.6, "lat": 44.0, "height": 40000}, {"lon": -71.3, "lat": NaN, "height": 9000}]}'
)
NEWER_TOUR = '{"format": "globeview-tour", "version": 7, "keyframes": []}'


@pytest.mark.parametrize(
    ("args", "word"),
    [
        (["--fps", "0"], "--fps 0 is out of range"),
        (["--fps", "-2"], "--fps -2 is out of range"),
        (["--size", "0x0"], "--size 0x0 is out of range"),
        (["--size", "97x64"], "even width and height"),
        (["--size", "big"], "--size must look like"),
        (["--seconds", "-1"], "--seconds"),
        (["--tour", "<nan>"], "keyframe 2: latitude must be a finite number"),
        (["--tour", "<newer>"], "newer than this globeview reads"),
        (["--tour", "<png>"], "is not a globeview tour"),
        (["--tour", "-71.6,nan,40000"], "CAMERAS: camera 1: latitude"),
        (["--out", "x.avi"], "must end in .mp4 or .gif"),
        (["--lod", "no-such-lod"], "no-such-lod"),
        (["--layer", "missing.geojson"], "--layer missing.geojson: no such file"),
        (["--background", "1,2,3"], "--background"),
        (["--out", "no/such/folder/x.mp4"], "does not exist"),
    ],
)
def test_bad_input_is_one_line_and_nothing_written(
    cache: Path, tmp_path: Path, args: list[str], word: str
) -> None:
    opts = dict(zip(args[::2], args[1::2], strict=True))
    tour = opts.pop("--tour", CAMERAS)
    if tour == "<nan>":
        tour = _tour_file(tmp_path, NAN_TOUR)
    elif tour == "<newer>":
        tour = _tour_file(tmp_path, NEWER_TOUR)
    elif tour == "<png>":
        tour = str(tmp_path / "not_a_tour.png")
        Image.new("RGB", (4, 4)).save(tour)
    out = opts.pop("--out", "m.mp4")
    before = sorted(p.name for p in tmp_path.iterdir())
    flat = [x for kv in opts.items() for x in kv]
    res = globeview(
        "movie", "-o", str(tmp_path / out), "--size", "96x64", *flat, "--", tour, DEM, cache=cache
    )
    assert word in one_error_line(res)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_terminal_gets_a_progress_bar_with_eta(cache: Path, tmp_path: Path) -> None:
    """On a terminal (a pseudo-terminal here) stderr shows tqdm's bar: frames done of the
    total, elapsed<remaining; the last line is still the 'wrote' summary on stdout."""
    import fcntl
    import os
    import pty
    import struct
    import subprocess
    import termios

    from .run_cli import GLOBEVIEW

    out = tmp_path / "m.gif"
    main, child = pty.openpty()
    # A terminal 100 columns wide (a fresh pty has 0, where tqdm draws nothing).
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(cache)}
    argv = [str(GLOBEVIEW), "movie", "-o", str(out), "--size", "40x30", "--fps", "3"]
    with zygote.popen(
        [*argv, "--", CAMERAS, DEM], stdout=subprocess.PIPE, stderr=child, env=env
    ) as proc:
        os.close(child)
        stdout, _ = proc.communicate(timeout=300)
        chunks = []
        while True:
            try:
                data = os.read(main, 4096)
            except OSError:  # EIO: the child's end is closed and everything was read
                break
            if not data:
                break
            chunks.append(data)
        os.close(main)
    bar = b"".join(chunks).decode("utf-8", "replace")
    assert proc.returncode == 0, bar
    assert "movie:" in bar and "9/9" in bar and "frame/s" in bar, bar
    assert re.search(r"\[\d\d:\d\d<\d\d:\d\d", bar), bar  # elapsed<ETA
    assert stdout.decode().startswith(f"wrote {out} (40x30, 9 frames")
