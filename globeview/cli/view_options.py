"""The view and plugin options `globeview render` and `globeview gui` share: ``--camera``,
``--lod``, ``--tool``, ``--set``, defined once and checked the same way, before any work
(bad input is one `GlobeviewError` line, exit 2); and the scene options `render` and `movie`
share (``--fov``, ``--tau``, ``--exaggeration``, the display flags, ``--layer``).

Like the subcommand modules, this imports only argparse at top level; the checks import the
model and the plugin registry when they run (no GL, no Qt).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")


def add_view_options(parser: argparse.ArgumentParser, *, window: bool = False) -> None:
    """Add ``--camera``, ``--lod``, ``--tool`` and ``--set`` to ``parser``: `render`'s, or the
    window's (``window``: no default LOD provider, the window keeps its own; the tool is
    activated in the window instead of being given ``--points``)."""
    where = "the window opens on" if window else "rendered from"
    parser.add_argument(
        "--camera",
        help=f"the view {where}: LON,LAT,HEIGHT[,HEADING,PITCH[,ROLL]] in degrees and metres "
        "(heading 0 = north, pitch -90 = straight down); default: "
        + ("the whole globe" if window else "the whole globe, or the last source's footprint"),
    )
    parser.add_argument(
        "--lod",
        default=None if window else "chunked-sse",
        help="LOD provider plugin (see `globeview plugins list`)"
        + ("; default: chunked-sse" if window else ""),
    )
    parser.add_argument(
        "--tool",
        metavar="NAME",
        help="activate the tool NAME (built-in or installed, see `globeview plugins list`)"
        + (" once the window is up" if window else " and give it --points; its overlay is drawn"),
    )
    parser.add_argument(
        "--set",
        dest="set_values",
        action="append",
        default=[],
        metavar="NAME.KEY=VALUE",
        help="a setting of a contribution (LOD provider, tool, layer type) for this "
        + ("session" if window else "render")
        + " only, checked against its type and range (e.g. collapse.ratio=0.3); repeatable; "
        "`globeview plugins set` stores one",
    )


def add_scene_options(parser: argparse.ArgumentParser) -> None:
    """Add what a picture of the globe is drawn with, `render`'s and `movie`'s alike: the
    field of view (degrees), the screen-space error (pixels), the vertical exaggeration, the
    display flags, the background and the overlay files (``--layer``)."""
    parser.add_argument("--fov", type=float, default=45.0, help="vertical field of view, deg")
    parser.add_argument("--tau", type=float, default=2.0, help="screen-space error, pixels")
    parser.add_argument("--exaggeration", type=float, default=1.0, help="vertical exaggeration")
    parser.add_argument("--hillshade", action="store_true", help="light from the north-west")
    parser.add_argument("--no-fog", action="store_true", help="no haze toward the horizon")
    parser.add_argument("--background", help="R,G,B background colour in 0..1")
    parser.add_argument(
        "--layer",
        action="append",
        default=[],
        metavar="[TYPE:]FILE[::LAYER]",
        help="overlay a file with the layer type that opens it (by extension, then content; "
        "TYPE:FILE chooses one, e.g. thematic:x.tif; see `globeview plugins list`); "
        "FILE::LAYER opens one layer of a multi-layer file, e.g. roads.gpkg::highways; "
        "repeatable",
    )
    parser.add_argument(
        "--imagery", action="store_true", help="drape the embedded Blue Marble imagery"
    )
    parser.add_argument(
        "--no-borders", action="store_true", help="hide the embedded country borders"
    )


# -- parsing ----------------------------------------------------------------------------------
def parse_floats(text: str, name: str, lengths: tuple[int, ...]) -> list[float]:
    """Comma-separated numbers as people write them (`validate.parse_float`: not Python's
    "1_0" for 10), as many as one of ``lengths``; one line naming ``name`` otherwise."""
    from globeview.errors import GlobeviewError
    from globeview.validate import parse_float

    try:
        vals = [parse_float(v) for v in text.split(",")]
    except ValueError:
        raise GlobeviewError(f"{name} must be comma-separated numbers, not {text!r}") from None
    if len(vals) not in lengths:
        raise GlobeviewError(f"{name} takes {' or '.join(map(str, lengths))} numbers")
    return vals


def checked(option: str, check: Callable[..., T], *values: Any) -> T:
    """``check(*values)``, its ValueError turned into a one-line error naming ``option``
    (the model's checks say what is wrong and the valid range; the CLI adds the option)."""
    from globeview.errors import GlobeviewError

    try:
        return check(*values)
    except ValueError as exc:
        msg = str(exc)
        bare = option.lstrip("-")
        if msg.startswith(bare + " "):  # "tau must be ..." -> "--tau must be ..."
            raise GlobeviewError(option + msg[len(bare) :]) from None
        raise GlobeviewError(f"{option}: {msg}") from None


def parse_camera(text: str) -> tuple[float, ...]:
    """--camera LON,LAT,HEIGHT[,HEADING,PITCH[,ROLL]] -> the six values (degrees, metres),
    validated like `Camera.from_lonlat`."""
    from globeview.model.camera import check_lonlat_hpr

    vals = parse_floats(text, "--camera", (3, 5, 6))
    vals += [0.0, -90.0, 0.0][len(vals) - 3 :]
    return checked("--camera", check_lonlat_hpr, *vals)


def check_plugin_options(
    registry: Any, lod: str | None, tool: str | None, sets: list[tuple[str, str]]
) -> list:
    """``--lod``, ``--tool`` and ``--set`` (texts with the option each came from) checked
    against the discovered plugins, importing only those that declare the tool and the
    settings: one line for an LOD provider or tool no enabled plugin offers, an unknown
    setting or a bad value. Returns the checked (`SettingTarget`, value) pairs."""
    from globeview.app.lod_host import check_lod_name
    from globeview.plugins.settings import resolve_plugin_args

    if lod is not None:
        check_lod_name(registry, lod)
    return resolve_plugin_args(registry, tool, sets)
