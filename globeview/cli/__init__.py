"""The `globeview` command line.

Each subcommand lives in its own module with ``add_arguments(parser)`` and ``run(args)``.
Those modules import only argparse at top level and the heavy layers inside ``run``, so
`globeview info` never loads GL or Qt.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from globeview import __version__
from globeview.errors import GlobeviewError

# subcommand name -> module under globeview.cli, with a one-line help
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "info": ("info", "describe DEM rasters (bounds, resolution, nodata, value range)"),
    "ingest": ("ingest", "build a tile-pyramid store from one or more DEMs"),
    "render": ("render", "render the globe headless to a PNG (EGL, no display needed)"),
    "plugins": ("plugins", "list, validate, enable and disable plugins"),
    "bench": ("bench", "benchmarks: camera flights, the papers' experiments, budgets, soak"),
    "gui": ("gui", "open the desktop window (the default with no subcommand)"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="globeview",
        description="A desktop virtual globe for terrain. With no subcommand, opens the window.",
    )
    parser.add_argument("--version", action="version", version=f"globeview {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        mod = importlib.import_module(f"globeview.cli.{module}")
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        if "gui" not in SUBCOMMANDS:
            # Until the window exists, the bare command describes the embedded data.
            args = parser.parse_args(["info", "--embedded"])
        else:
            args = parser.parse_args(["gui", *argv])
    try:
        return int(args._run(args) or 0)
    except GlobeviewError as exc:
        print(f"globeview: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("globeview: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # Output piped into a reader that closed early (e.g. `| head`): not an error.
        sys.stderr.close()
        return 0
