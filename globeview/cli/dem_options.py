"""``--crs`` and ``--vdatum``, the options of every command that reads DEM files (`info`,
`ingest`, `render`, `height`): one wording and one check for all of them.

Both apply to DEM files only: a tile store already holds ellipsoidal heights on WGS84."""

from __future__ import annotations

import argparse

#: What ``--crs`` means, in every command's help.
CRS_HELP = (
    "CRS of the DEM files when they lack one or declare a wrong one, e.g. EPSG:32610 "
    "(EPSG:n, WKT or a PROJ string)"
)
#: What ``--vdatum`` means, in every command's help.
VDATUM_HELP = (
    "vertical datum of the DEM files: ellipsoid, egm96 or egm2008 (default: from the CRS, SRTM "
    ".hgt and mean-sea-level DEMs EGM96, Copernicus DEM tiles EGM2008, else assumed EGM96; "
    "EGM2008 needs its grid: see ingest --geoid-grid); stores hold ellipsoidal heights"
)


def add_dem_options(parser: argparse.ArgumentParser) -> None:
    """Register ``--crs`` and ``--vdatum`` on a subcommand's parser (``args.crs``,
    ``args.vdatum``: the texts given, or None)."""
    parser.add_argument("--crs", default=None, metavar="CRS", help=CRS_HELP)
    parser.add_argument("--vdatum", default=None, metavar="DATUM", help=VDATUM_HELP)


def check_dem_options(args: argparse.Namespace) -> None:
    """A bad ``--vdatum`` (a typo) as one line before any work; ``--crs`` is parsed
    where a DEM is opened (`globeview.terrain.dem.reader.open_dem`: one line for an unknown CRS)."""
    if args.vdatum is not None:
        from globeview.terrain.dem.vdatum import parse_vdatum

        parse_vdatum(args.vdatum)
