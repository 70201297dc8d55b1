"""`globeview movie`: fly a tour (a tour file, a project's tour over the project's layers, or
cameras given on the command line) over DEMs headless (EGL) and write it as an MP4 or a GIF,
every frame with all its tiles loaded.

The movie is written to a temporary file beside ``--out`` and renamed at the end: a bad
argument, a full disk, a read-only folder or Ctrl-C leaves nothing behind (one line, exit
!= 0). On a terminal a progress bar with the ETA runs on stderr (tqdm, as `globeview
ingest`'s)."""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

from globeview.cli.dem_options import add_dem_options, check_dem_options
from globeview.cli.view_options import add_scene_options, checked

if TYPE_CHECKING:
    from globeview.app.globe import Globe
    from globeview.model.tour import Tour

#: Seconds each leg between cameras given on the command line takes, by default.
DEFAULT_LEG_S = 3.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "tour",
        metavar="TOUR|CAMERAS",
        help="a tour file (.json or .toml, saved by the window or globeview.Tour), a project "
        "(PROJECT.toml with a tour: its own layers, camera and display are filmed), or cameras "
        "'LON,LAT,HEIGHT[,HEADING,PITCH[,ROLL]];...' (degrees, metres above WGS84) flown "
        "--seconds apart (one camera: held for --seconds); put -- before a list that starts "
        "with '-'",
    )
    parser.add_argument(
        "sources",
        nargs="*",
        metavar="STORE|URL|DEM",
        help="tile store folders, store URLs or DEM files (ingested into the cache once); "
        "none: the embedded data",
    )
    parser.add_argument("--out", "-o", required=True, help="the movie to write: .mp4 or .gif")
    parser.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT in pixels (even, for MP4)")
    parser.add_argument("--fps", type=float, default=30.0, help="frames per second (1..240)")
    parser.add_argument(
        "--seconds",
        type=float,
        default=DEFAULT_LEG_S,
        help=f"seconds between CAMERAS, or that one camera is held (default "
        f"{DEFAULT_LEG_S:g}); a tour file has its own",
    )
    # --fov, --tau, --exaggeration, display flags, --layer: as `globeview render`'s.
    add_scene_options(parser)
    parser.add_argument(
        "--lod", default="chunked-sse", help="LOD provider plugin (see `globeview plugins list`)"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_dem_options(parser)


def parse_tour(text: str, seconds: float) -> Tour:
    """A tour file's tour, or the ';'-separated cameras each ``seconds`` after the last; one
    camera is held for ``seconds`` (the first keyframe's seconds are a hold, `Keyframe`), so
    the movie has ``fps * seconds`` frames of that view."""
    from pathlib import Path

    from globeview.cli.view_options import parse_floats
    from globeview.errors import GlobeviewError
    from globeview.model.camera import check_lonlat_hpr
    from globeview.model.tour import SUFFIXES, Keyframe, Tour, load_tour
    from globeview.validate import check_number

    if Path(text).suffix.lower() in SUFFIXES or Path(text).exists():
        return load_tour(text)
    if not any(c.isdigit() for c in text):
        raise GlobeviewError(f"{text}: no such tour file (.json or .toml), and not cameras")
    leg = checked("--seconds", check_number, "seconds", seconds, 0.0, 86_400.0, " s")
    cameras = [c for c in text.split(";") if c.strip()]
    tour = Tour()
    for i, cam in enumerate(cameras):
        vals = parse_floats(cam.strip(), "CAMERAS", (3, 5, 6))
        vals += [0.0, -90.0, 0.0][len(vals) - 3 :]
        pose = checked(f"CAMERAS: camera {i + 1}", check_lonlat_hpr, *vals)
        tour.add(Keyframe.from_pose(pose, leg if i or len(cameras) == 1 else 0.0))
    if tour.duration == 0.0 and len(cameras) > 1:
        raise GlobeviewError("--seconds 0 gives the cameras no time to fly between them")
    return tour


def check_args(args: argparse.Namespace) -> dict:
    """Everything typed, checked before any DEM is read: one line on the first bad one."""
    from globeview.app.movie import MOVIE_SUFFIXES, check_fps, check_movie_size
    from globeview.cli.render import (
        check_cache_writable,
        check_inputs,
        parse_background,
        parse_size,
    )
    from globeview.fileio import check_output_file
    from globeview.model.camera import FOV_RANGE_DEG
    from globeview.validate import check_exaggeration, check_number, check_tau

    out = check_output_file(args.out, "--out", MOVIE_SUFFIXES)
    size = checked("--size", check_movie_size, parse_size(args.size), out.suffix.lower())
    values = {
        "out": out,
        "size": size,
        "fps": checked("--fps", check_fps, args.fps),
        "fov": checked("--fov", check_number, "field of view", args.fov, *FOV_RANGE_DEG, " deg"),
        "tau": checked("--tau", check_tau, args.tau),
        "exaggeration": checked("--exaggeration", check_exaggeration, args.exaggeration),
        "tour": parse_tour(args.tour, args.seconds),
        "background": parse_background(args.background) if args.background else None,
    }
    check_inputs(args)  # the sources and the --layer files
    check_dem_options(args)
    check_cache_writable(args.sources, args.crs, args.vdatum)
    return values


def make_globe(args: argparse.Namespace, v: dict) -> Globe:
    """The globe the movie is filmed on, set up as `globeview render` sets up its scene."""
    from globeview.app.globe import Globe
    from globeview.model.camera import Camera

    globe = Globe(embedded=not args.sources, lod=args.lod)  # an unknown --lod: before ingest
    for src in args.sources:
        globe.add_dem(src, crs=args.crs, vdatum=args.vdatum)
    if args.sources and (not args.no_borders or args.imagery):
        globe.overlay_host.open_embedded(imagery=args.imagery)
        if args.no_borders:
            globe.remove_overlay(globe.overlays[-1])
    elif not args.sources and (args.no_borders or args.imagery):
        for layer in globe.overlays:
            globe.remove_overlay(layer)
        if args.imagery:
            globe.overlay_host.open_embedded(imagery=True)
            if args.no_borders:
                globe.remove_overlay(globe.overlays[-1])
    for layer in args.layer:
        globe.add_overlay(layer)
    if v["background"] is not None:
        globe.display.background = v["background"]
    tour: Tour = v["tour"]
    globe.model.camera = Camera.from_lonlat(*tour.keyframes[0].pose, fovy_deg=v["fov"])
    globe.tau_px = v["tau"]
    globe.display.exaggeration = v["exaggeration"]
    globe.display.hillshade = args.hillshade
    globe.display.fog = not args.no_fog
    return globe


#: The options a project sets itself (its layers, camera, LOD and display), with their
#: defaults: given with a project they are refused, not silently overridden.
_PROJECT_SETS: dict[str, object] = {
    "seconds": DEFAULT_LEG_S,
    "fov": 45.0,
    "tau": 2.0,
    "exaggeration": 1.0,
    "hillshade": False,
    "no_fog": False,
    "imagery": False,
    "no_borders": False,
    "lod": "chunked-sse",
    "layer": [],
    "background": None,
    "crs": None,
    "vdatum": None,
}


def is_project(text: str) -> bool:
    """Whether the TOUR argument is a project file (a ``.toml`` with a ``schema`` key;
    a tour file has ``format = "globeview-tour"`` instead)."""
    import tomllib
    from pathlib import Path

    from globeview.model.project import MAX_BYTES, is_project_path

    p = Path(text)
    if not is_project_path(p) or not p.is_file() or p.stat().st_size > MAX_BYTES:
        return False
    try:
        return "schema" in tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False  # load_tour says what is wrong with it


def project_globe(args: argparse.Namespace) -> tuple[dict, Globe]:
    """``globeview movie PROJECT.toml -o out.mp4``: the project's globe (layers, camera,
    LOD, display) and its tour; one line for DEMs given too, an option the project sets,
    or a project without a tour."""
    from globeview.app.globe import Globe
    from globeview.app.movie import MOVIE_SUFFIXES, check_fps, check_movie_size
    from globeview.cli.project import check_project, refuse_options
    from globeview.cli.render import parse_size
    from globeview.errors import GlobeviewError
    from globeview.fileio import check_output_file

    if args.sources:
        raise GlobeviewError(f"a project films its own layers: {args.tour} was given with DEMs")
    refuse_options(args, _PROJECT_SETS)
    out = check_output_file(args.out, "--out", MOVIE_SUFFIXES)
    size = checked("--size", check_movie_size, parse_size(args.size), out.suffix.lower())
    fps = checked("--fps", check_fps, args.fps)
    check_project(args.tour)  # not a project, newer schema, unknown plugin: before any DEM
    globe = Globe.open_project(args.tour)
    if not globe.tour.keyframes:
        globe.close()
        raise GlobeviewError(
            f"{args.tour} has no tour to film (record one in the window's Tour dock and "
            "Save Project, or Globe.add_keyframe then save_project)"
        )
    return {"out": out, "size": size, "fps": fps, "tour": globe.tour}, globe


def run(args: argparse.Namespace) -> int:
    import time

    if is_project(args.tour):
        v, globe = project_globe(args)
    else:
        v = check_args(args)
        globe = make_globe(args, v)
    tour, size, fps = v["tour"], v["size"], v["fps"]
    t0 = time.perf_counter()
    with progress_bar(not args.quiet and sys.stderr.isatty()) as tell:
        out = globe.movie(tour, v["out"], size=size, fps=fps, progress=tell)
    frames = len(tour.frame_times(fps))
    print(
        f"wrote {out} ({size[0]}x{size[1]}, {frames} frames, {tour.duration:g} s of tour at "
        f"{fps:g} fps) in {time.perf_counter() - t0:.1f} s"
    )
    globe.close()
    return 0


@contextlib.contextmanager
def progress_bar(enabled: bool) -> Iterator[Callable[[int, int], None]]:
    """A tqdm bar with ETA on stderr (as `globeview ingest` draws), fed by the movie's
    ``progress(done, total)`` callback; a callback that does nothing when not ``enabled``."""
    if not enabled:
        yield lambda done, total: None
        return
    from tqdm import tqdm

    with tqdm(total=0, unit="frame", desc="movie", dynamic_ncols=True) as bar:

        def tell(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        yield tell
