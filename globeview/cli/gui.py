"""`globeview gui`: open the desktop window (the default when no subcommand is given), with
the files given and, like `globeview render`, a view, an LOD provider, a tool and settings
(``--camera``, ``--lod``, ``--tool``, ``--set``: the same definitions and checks,
cli/view_options.py)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from globeview.cli.view_options import add_view_options, check_plugin_options, parse_camera

if TYPE_CHECKING:
    from globeview.ui.start import WindowStart


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "files",
        nargs="*",
        metavar="FILE|STORE|URL",
        help="DEM files, tile store folders or store URLs (https://HOST/path/store) to open "
        "on top of the embedded data, and overlay files (GeoJSON, imagery or thematic "
        "rasters, any file an installed layer type opens) shown over it; each is told apart "
        "by its content, as File > Open and drag and drop do",
    )
    add_view_options(parser, window=True)


def check_start(args: argparse.Namespace) -> WindowStart:
    """The `WindowStart` of the command line, every value checked before the window exists
    (one `GlobeviewError` line, exit 2): the camera as `render` checks it, the LOD provider,
    tool and settings against the installed plugins (discovered with the settings file the
    window uses; only the plugins named are imported)."""
    from globeview.plugins.registry import PluginRegistry
    from globeview.ui.start import WindowStart  # no Qt: the display is checked later

    camera = parse_camera(args.camera) if args.camera else None
    sets = [(text, "--set") for text in args.set_values]
    if args.lod is not None or args.tool is not None or sets:
        check_plugin_options(PluginRegistry().discover(), args.lod, args.tool, sets)
    return WindowStart(camera, args.lod, args.tool, tuple(sets))


def run(args: argparse.Namespace) -> int:
    import os
    import sys

    start = check_start(args)  # bad input is one line whether or not a window can open
    # Checked before Qt is imported: without a display Qt would abort with a platform-plugin
    # traceback instead of a message.
    if not any(os.environ.get(k) for k in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM")):
        print(
            "globeview: no display (DISPLAY/WAYLAND_DISPLAY unset): the window cannot open; "
            "use `globeview render` to draw the globe to a PNG headless",
            file=sys.stderr,
        )
        return 1
    from globeview.ui.app import run as run_app

    return run_app(args.files, start=start)
