"""`globeview info`: describe DEM rasters (bounds, resolution, nodata, value range)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register `info`'s arguments on its subparser."""
    parser.add_argument(
        "dems",
        nargs="*",
        metavar="DEM",
        help="raster files GDAL can read (default: the embedded DEMs)",
    )
    parser.add_argument(
        "--crs",
        metavar="CRS",
        help="CRS of the rasters when they lack one or declare a wrong one, e.g. EPSG:32610",
    )
    parser.add_argument(
        "--vdatum",
        metavar="DATUM",
        help="declare the rasters' vertical datum: ellipsoid or egm96 (default: from the CRS,"
        " else EGM96)",
    )
    parser.add_argument("--json", action="store_true", help="print a JSON list instead of text")
    parser.add_argument(
        "--embedded", action="store_true", help="describe the DEMs shipped in data/"
    )


def run(args: argparse.Namespace) -> int:
    """Print a summary (or JSON) per DEM. DemError propagates to the CLI's one-line handler."""
    import json

    from globeview.terrain.dem import embedded_dem_paths, open_dem

    paths = [*args.dems]
    if args.embedded or not paths:
        paths = [*map(str, embedded_dem_paths()), *paths]
    infos = []
    for p in paths:
        with open_dem(p, crs=args.crs, vdatum=args.vdatum) as dem:
            infos.append(dem.info)
    if args.json:
        print(json.dumps([i.to_dict() for i in infos], indent=2))
    else:
        print("\n\n".join(i.summary() for i in infos))
    return 0
