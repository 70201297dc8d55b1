"""`globeview height LON,LAT [LON,LAT ...] [STORE|DEM ...]`: the heights of the composed
terrain at points (issue #16).

For each point: the ellipsoidal height h (metres above WGS84, what the globe draws), the EGM96
geoid undulation N, the orthometric height H = h - N ("above sea level") and the layer that
answered; off every layer there is no terrain, and h and H are "-" (null in JSON), not the
ellipsoid's. With no sources the embedded data is queried, as `render` draws it; DEMs are
ingested into the cache as `render` does. ``--json`` prints a JSON list of objects.

A point is one argument ``LON,LAT`` in degrees; a negative longitude may be written as is
(``globeview height -71.3033,44.2705 data/N44W072.hgt``); the options (``--json``, ``--crs``
and ``--vdatum`` of the DEM files, as `render` has them) may stand anywhere.
"""

from __future__ import annotations

import argparse
import math
import re

from globeview.cli.dem_options import add_dem_options

#: argparse takes an argument starting with '-' for an option unless it looks like a negative
#: number; here anything shaped like a point (``-71.3,44.2``, ``-nan,1``) is such a number,
#: so that it is read as a point (and a bad one refused as a point). No option has a comma.
_NEGATIVE_ARG = re.compile(r"^-\d+$|^-\d*\.\d+$|^-[^-/\\][^/\\]*,[^/\\]*$")
#: A token shaped like a point (a comma, no path separator): parsed as one or refused.
_POINT_SHAPED = re.compile(r"^[^/\\]*,[^/\\]*$")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "items",
        nargs="+",
        metavar="LON,LAT|SOURCE",
        help="points as LON,LAT in degrees, then tile stores or DEM files "
        "(none: the embedded data)",
    )
    p.add_argument("--json", action="store_true", help="print a JSON list instead of a table")
    add_dem_options(p)
    # A point like -71.3,44.2 is a positional argument, not an unknown option (see above);
    # argparse has no public hook for that.
    p._negative_number_matcher = _NEGATIVE_ARG
    # argparse takes positionals in one run: `height PT --json DEM` left DEM "unrecognized".
    # The options are moved in front of the positionals, so they may stand anywhere.
    cls_parse = type(p).parse_known_args

    def parse_known_args(args=None, namespace=None):
        if args is not None:
            args = _options_first(list(args))
        return cls_parse(p, args, namespace)

    p.parse_known_args = parse_known_args


#: `height`'s options: the flag, and those taking a value (``--crs X`` or ``--crs=X``).
_FLAGS = ("--json",)
_VALUED = ("--crs", "--vdatum")


def _options_first(args: list[str]) -> list[str]:
    """The options (with their values) moved before the positionals, keeping their order (not
    past a ``--``)."""
    end = args.index("--") if "--" in args else len(args)
    front: list[str] = []
    rest: list[str] = []
    i = 0
    while i < end:
        a = args[i]
        if a in _FLAGS or ("=" in a and a.split("=", 1)[0] in _VALUED):
            front.append(a)
        elif a in _VALUED and i + 1 < end:
            front += [a, args[i + 1]]
            i += 1
        else:
            rest.append(a)
        i += 1
    return front + rest + args[end:]


def parse_point(text: str) -> tuple[float, float]:
    """``"LON,LAT"`` -> (lon, lat) degrees; a `GlobeviewError` for anything else (not two
    numbers as people write them, NaN/inf, latitude beyond ±90)."""
    from globeview.errors import GlobeviewError
    from globeview.validate import format_number, parse_float

    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        lon, lat = parse_float(parts[0]), parse_float(parts[1])
    except ValueError:
        raise GlobeviewError(f"point {text!r}: expected LON,LAT in degrees") from None
    if not (math.isfinite(lon) and math.isfinite(lat)):
        raise GlobeviewError(f"point {text!r}: longitude and latitude must be finite numbers")
    if abs(lat) > 90.0:
        # Every digit where %g would round it into the range ("latitude 90 is outside").
        raise GlobeviewError(f"point {text!r}: latitude {format_number(lat)} is outside -90..90")
    return lon, lat


def split_items(items: list[str]) -> tuple[list[tuple[float, float]], list[str]]:
    """Points and sources from the positional arguments: a token shaped like ``A,B`` that is
    not an existing path is a point (and must parse as one); anything else is a source."""
    import os

    from globeview.errors import GlobeviewError

    points: list[tuple[float, float]] = []
    sources: list[str] = []
    for tok in items:
        if _POINT_SHAPED.match(tok) and not os.path.exists(tok):
            points.append(parse_point(tok))
        else:
            sources.append(tok)
    if not points:
        raise GlobeviewError("no point given: write at least one LON,LAT (degrees) first")
    return points, sources


def _layer_names(sources: list[str], stores: list) -> list[str]:
    """Names the user recognises: a DEM's file name, a store's folder name, the embedded
    DEMs' file names."""
    from pathlib import Path

    if sources:
        return [
            Path(s).name if not Path(s).is_dir() else st.path.name
            for s, st in zip(sources, stores, strict=True)
        ]
    from globeview.terrain.dem.data import embedded_dem_paths

    return [p.name for p in embedded_dem_paths()]


#: The layer column of a point no layer covers (its h and H columns show "-").
NO_TERRAIN = "no terrain here"


def format_table(answers: list) -> str:
    """The answers as aligned columns: lon, lat, h, N, H (metres, two decimals) and the layer;
    where no layer answered, h and H are "-" and the layer column says there is no terrain."""
    rows = [("lon", "lat", "h (m ell.)", "N (m)", "H (m a.s.l.)", "layer")]
    for a in answers:
        rows.append(
            (
                f"{a.lon:.6f}",
                f"{a.lat:.6f}",
                "-" if a.ellipsoidal is None else f"{a.ellipsoidal:.2f}",
                f"{a.undulation:.2f}",
                "-" if a.orthometric is None else f"{a.orthometric:.2f}",
                a.layer if a.has_terrain else NO_TERRAIN,
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(5)]
    lines = ["  ".join(c.rjust(w) for c, w in zip(r[:5], widths)) + f"  {r[5]}" for r in rows]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from globeview.cli.dem_options import check_dem_options
    from globeview.cli.render import check_cache_writable, open_sources
    from globeview.errors import GlobeviewError
    from globeview.terrain.compose.height_query import query_heights
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.sources import check_source

    points, sources = split_items(args.items)
    check_dem_options(args)
    for src in sources:  # every argument checked before the first (slow) ingest
        check_source(src)
    check_cache_writable(sources, args.crs, args.vdatum)
    stores = open_sources(sources, args.crs, args.vdatum)
    if not stores:
        raise GlobeviewError("no terrain to query")
    stack = TerrainStack.from_stores(stores, _layer_names(sources, stores))
    lon = np.array([p[0] for p in points])
    lat = np.array([p[1] for p in points])
    answers = query_heights(stack, lon, lat)
    if args.json:
        print(json.dumps([a.to_dict() for a in answers], indent=2))
    else:
        print(format_table(answers))
    return 0
