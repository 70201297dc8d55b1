"""`globeview ingest`: build a tile-pyramid store (chunked GeoTIFFs per level, a VRT per level
and a manifest) from DEMs, as a Dask task graph: on the local scheduler with ``--workers N``
threads (default: every core), or on an existing ``dask.distributed`` cluster with
``--scheduler tcp://HOST:PORT`` (the store folder must then be on a filesystem the workers
share)."""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from typing import Any

from globeview.cli.dem_options import add_dem_options

#: Most local workers `--workers` takes: more threads than any machine has cores only adds
#: memory (each task holds a window of the raster), and a typo of 10^6 must not start them.
MAX_WORKERS = 4096

#: Dask's local schedulers `--scheduler` also names (threads: the default).
LOCAL_SCHEDULERS = ("threads", "processes")

#: ``tcp://HOST:PORT``: a host name, an IPv4 address or a bracketed IPv6 address, and a port.
_SCHEDULER = re.compile(r"^tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9.-]{0,252}):(\d{1,5})$")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the ingest options on a subcommand parser."""
    parser.add_argument(
        "sources",
        nargs="+",
        metavar="SRC",
        help="DEM rasters (any GDAL format), folders of DEM tiles (the .tif/.hgt/... files "
        "directly in them; subfolders are not searched), quoted globs ('srtm/*.hgt', "
        "'copdem/**/*_DEM.tif') or @LIST (a text file naming one source a line)",
    )
    parser.add_argument(
        "--out", default=None, metavar="STORE", help="store directory to write (not with --plan)"
    )
    parser.add_argument(
        "--plan",
        action="store_true",
        help="print what the build would do (sources, chunks and source reads per level, "
        "tasks, bytes, estimated core-hours) without building or writing anything",
    )
    parser.add_argument(
        "--footprints",
        choices=("auto", "name", "header"),
        default="auto",
        help="where --plan takes a source's footprint from: its SRTM (N44W072.hgt) or "
        "Copernicus (Copernicus_DSM_COG_10_N44_00_W072_00_DEM.tif) name, else its header "
        "(auto, the default: no file opened for named tiles); name; or header (every file "
        "opened)",
    )
    parser.add_argument(
        "--geoid-grid",
        action="append",
        default=[],
        metavar="[egm2008=]PATH",
        help="a geoid grid globeview does not ship, for sources on that datum (Copernicus "
        "DEM heights are EGM2008: us_nga_egm08_25.tif from https://cdn.proj.org); the build "
        "converts each source's heights with its own datum's grid; repeatable (default: "
        "$GLOBEVIEW_GEOID_GRIDS, then PROJ's data folders)",
    )
    parser.add_argument(
        "--tile-n", type=int, default=6, help="tiles have 2^N+1 samples a side (default 6: 65)"
    )
    parser.add_argument(
        "--max-level", type=int, default=None, help="finest level (default: from the resolution)"
    )
    parser.add_argument("--wavelet", default="bior2.2", help="low-pass wavelet for coarser levels")
    add_dem_options(parser)
    parser.add_argument(
        "--workers",
        metavar="N",
        default=None,
        help="local Dask workers (threads) building tiles at once, 1.."
        f"{MAX_WORKERS} (default: every core); not with --scheduler",
    )
    parser.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        default=None,
        help="run the ingest graph on this existing dask.distributed scheduler (the --out "
        "folder must be on a filesystem its workers share); 'threads' (the default) or "
        "'processes' for a local pool of --workers",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--force", action="store_true", help="rebuild even if up to date")


def parse_workers(text: str | None) -> int | None:
    """``--workers N``: an integer in 1..`MAX_WORKERS` (None: not given, every core)."""
    from globeview.errors import GlobeviewError

    if text is None:
        return None
    try:
        n = int(str(text).strip())
    except ValueError:
        raise GlobeviewError(f"--workers must be a whole number >= 1, not {text!r:.40}") from None
    if not 1 <= n <= MAX_WORKERS:
        raise GlobeviewError(f"--workers must be in 1..{MAX_WORKERS}, not {n}")
    return n


def parse_scheduler(text: str | None) -> str | None:
    """``--scheduler tcp://HOST:PORT`` (port 1..65535), or ``threads``/``processes`` (dask's
    local schedulers), returned stripped (None: not given). Only the form is checked here;
    whether a scheduler answers there is the ingest's (a one-line error after a timeout)."""
    from globeview.errors import GlobeviewError

    if text is None:
        return None
    if str(text).strip() in LOCAL_SCHEDULERS:
        return str(text).strip()
    m = _SCHEDULER.match(str(text).strip())
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        raise GlobeviewError(
            "--scheduler must be a dask.distributed address tcp://HOST:PORT (or threads, "
            f"processes), not {text!r:.80}"
        )
    return str(text).strip()


def parallel_kwargs(args: argparse.Namespace, ingest_fn: Callable[..., object]) -> dict[str, Any]:
    """The ingest's ``workers``/``scheduler`` keywords from the checked options."""
    import inspect

    from globeview.errors import GlobeviewError

    workers = parse_workers(args.workers)
    scheduler = parse_scheduler(args.scheduler)
    if workers is not None and scheduler is not None and scheduler not in LOCAL_SCHEDULERS:
        raise GlobeviewError(
            "--workers is for the local scheduler; a --scheduler cluster has its own workers"
        )
    kwargs = {"workers": workers, "scheduler": scheduler}
    accepted = inspect.signature(ingest_fn).parameters
    given = {k: v for k, v in kwargs.items() if v is not None}
    missing = [k for k in given if k not in accepted]
    if missing:  # an ingest without the Dask graph (never in a release)
        raise GlobeviewError(f"--{missing[0]} is not supported by this ingest")
    return given


def run_plan(args: argparse.Namespace) -> int:
    """``--plan``: print the plan (nothing written). Errors are GlobeviewErrors (exit 2)."""
    from globeview.cli.dem_options import check_dem_options
    from globeview.terrain.dem.vdatum import parse_geoid_grids
    from globeview.terrain.ingest.report import format_plan, make_plan

    check_dem_options(args)
    report = make_plan(
        args.sources,
        tile_n=args.tile_n,
        max_level=args.max_level,
        crs=args.crs,
        vdatum=args.vdatum,
        how=args.footprints,
        geoid_grids=parse_geoid_grids(args.geoid_grid),
        progress=not args.quiet and sys.stderr.isatty(),
    )
    print(format_plan(report))
    return 0


def run(args: argparse.Namespace) -> int:
    """Build the store; prints a one-line summary. Errors are GlobeviewErrors (exit 2)."""
    from globeview.errors import GlobeviewError

    if args.plan:  # --out may be given (the build's command line with --plan): not written
        return run_plan(args)
    if args.out is None:
        raise GlobeviewError("the following arguments are required: --out (or --plan)")
    if args.footprints != "auto":
        # The build reads every source's header anyway (and checks named tiles against it).
        raise GlobeviewError("--footprints is for --plan")
    from globeview.terrain.dem.vdatum import parse_geoid_grids
    from globeview.terrain.ingest.driver import ingest

    grids = parse_geoid_grids(args.geoid_grid)  # one line for a bad grid, before any work

    parallel = parallel_kwargs(args, ingest)  # checked before any source is read
    result = ingest(
        args.sources,
        args.out,
        tile_n=args.tile_n,
        max_level=args.max_level,
        wavelet=args.wavelet,
        crs=args.crs,
        vdatum=args.vdatum,
        force=args.force,
        geoid_grids=grids,
        # A bar only on a terminal: piped or logged, tqdm's redraws would be many lines.
        progress=not args.quiet and sys.stderr.isatty(),
        **parallel,
    )
    for dropped, kept in result.duplicates:  # said even with --quiet: a source left out
        print(f"{dropped}: the same data as {kept}: using the first")
    if result.up_to_date:
        print(f"{result.path}: store is up to date")
    elif not args.quiet:
        rebuilt, total = result.chunks_rebuilt, result.chunks_total
        # An incremental update (a source changed): say how little was rebuilt.
        part = f", rebuilt {rebuilt} of {total} chunks" if rebuilt < total else ""
        print(
            f"{result.path}: levels 0..{result.max_level} written in {result.seconds:.1f} s{part}"
        )
    if not result.up_to_date and (result.masked_samples or result.fill_samples):
        # Said even with --quiet: the store holds less than the source, and why.
        from globeview.terrain.dem.reader import MAX_HEIGHT_M, MIN_HEIGHT_M

        print(
            f"{result.path}: read as nodata: {result.masked_samples} samples non-finite or "
            f"outside {MIN_HEIGHT_M:.0f}..{MAX_HEIGHT_M:.0f} m, {result.fill_samples} "
            "undeclared fill samples"
        )
    return 0
