"""`globeview ingest`: build a tile-pyramid store (GeoTIFF per level + manifest) from DEMs."""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the ingest options on a subcommand parser."""
    parser.add_argument("sources", nargs="+", metavar="SRC", help="DEM rasters (any GDAL format)")
    parser.add_argument("--out", required=True, metavar="STORE", help="store directory to write")
    parser.add_argument(
        "--tile-n", type=int, default=6, help="tiles have 2^N+1 samples a side (default 6: 65)"
    )
    parser.add_argument(
        "--max-level", type=int, default=None, help="finest level (default: from the resolution)"
    )
    parser.add_argument("--wavelet", default="bior2.2", help="low-pass wavelet for coarser levels")
    parser.add_argument("--crs", default=None, help="CRS of the sources, e.g. EPSG:4326")
    parser.add_argument(
        "--vdatum",
        default=None,
        metavar="DATUM",
        help="vertical datum of the sources: ellipsoid or egm96 (default: from the CRS, SRTM"
        " .hgt and mean-sea-level DEMs EGM96, else assumed EGM96); stores hold ellipsoidal"
        " heights",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--force", action="store_true", help="rebuild even if up to date")


def run(args: argparse.Namespace) -> int:
    """Build the store; prints a one-line summary. Errors are GlobeviewErrors (exit 2)."""
    from globeview.terrain.ingest import ingest

    result = ingest(
        args.sources,
        args.out,
        tile_n=args.tile_n,
        max_level=args.max_level,
        wavelet=args.wavelet,
        crs=args.crs,
        vdatum=args.vdatum,
        force=args.force,
        # A bar only on a terminal: piped or logged, tqdm's redraws would be many lines.
        progress=not args.quiet and sys.stderr.isatty(),
    )
    if result.up_to_date:
        print(f"{result.path}: store is up to date")
    elif not args.quiet:
        print(f"{result.path}: levels 0..{result.max_level} written in {result.seconds:.1f} s")
    if not result.up_to_date and (result.masked_samples or result.fill_samples):
        # Said even with --quiet: the store holds less than the source, and why.
        from globeview.terrain.dem import MAX_HEIGHT_M, MIN_HEIGHT_M

        print(
            f"{result.path}: read as nodata: {result.masked_samples} samples non-finite or "
            f"outside {MIN_HEIGHT_M:.0f}..{MAX_HEIGHT_M:.0f} m, {result.fill_samples} "
            "undeclared fill samples"
        )
    return 0
