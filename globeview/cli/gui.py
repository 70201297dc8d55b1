"""`globeview gui`: open the desktop window (the default when no subcommand is given)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "files",
        nargs="*",
        metavar="DEM|STORE|URL",
        help="DEM files, tile store folders or store URLs (https://HOST/path/store) to open "
        "on top of the embedded data",
    )


def run(args: argparse.Namespace) -> int:
    import os
    import sys

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

    return run_app(args.files)
