"""Which files an ingest reads: DEM files named directly, and the DEM files in folders.

`globeview ingest tiles/ --out store` takes a folder of DEM tiles (an SRTM download, a
national lidar delivery): `expand_sources` replaces each folder by the DEM files directly in
it, sorted by name, so the manifest records files (a file changed in place is an incremental
update, a file added or removed a new source set and a full build).

A folder's DEM files are chosen by extension (`FOLDER_SUFFIXES`), not by trying to open
every file: a delivery holds thousands of tiles beside their sidecars (.aux.xml, .prj,
.md5, READMEs), and opening each with GDAL to see whether it is a raster would cost a
dataset open per sidecar and accept things like a world-file's image. Subfolders are not
entered (a folder of tiles is flat; a tree is passed as its folders). Hidden files are
skipped. A VRT in a folder is skipped too: it is usually a mosaic of the tiles beside it,
which would be read twice; name it on its own to ingest it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from globeview.errors import DemError
from globeview.terrain.store.identify import identify

__all__ = ["FOLDER_SUFFIXES", "expand_sources"]

#: Extensions (lower case) of the DEM files `expand_sources` takes from a folder: GeoTIFF,
#: SRTM .hgt, USGS/ASCII/ERDAS/netCDF/ESRI/DTED/Surfer/BT grids that GDAL reads as one band.
FOLDER_SUFFIXES = frozenset(
    {
        ".tif",
        ".tiff",
        ".hgt",
        ".dem",
        ".asc",
        ".img",
        ".nc",
        ".bil",
        ".flt",
        ".dt0",
        ".dt1",
        ".dt2",
        ".grd",
        ".bt",
    }
)


def _folder_dems(folder: Path) -> list[Path]:
    """The DEM files directly in ``folder``, sorted by name (DemError when there is none)."""
    # A globeview store is a folder of GeoTIFFs too: its chunk files are not DEMs to ingest.
    if identify(folder).is_globeview:
        raise DemError(f"{folder} is a globeview tile store, not a folder of DEM files")
    try:
        entries = sorted(os.scandir(folder), key=lambda e: e.name)
    except OSError as exc:
        raise DemError(f"cannot list the folder {folder}: {exc.strerror}") from None
    found = []
    for e in entries:
        if e.name.startswith(".") or Path(e.name).suffix.lower() not in FOLDER_SUFFIXES:
            continue
        try:
            if e.is_file():  # follows links: a link to a tile is a tile
                found.append(Path(e.path))
        except OSError:
            continue
    if not found:
        kinds = " ".join(sorted(FOLDER_SUFFIXES))
        raise DemError(
            f"{folder} is a folder with no DEM files in it (looked for {kinds}; subfolders "
            "are not searched)"
        )
    return found


def expand_sources(paths: Sequence[Path]) -> list[Path]:
    """``paths`` with every folder replaced by its DEM files (see the module docstring), in
    the order given; a file named twice (directly or through a folder, compared by resolved
    path) is kept once, where it first appears. Paths that are not folders are passed on
    unchecked (`check_dem_path` words what is wrong with them)."""
    out: list[Path] = []
    seen: set[str] = set()
    for p in paths:
        files = _folder_dems(p) if p.is_dir() else [p]
        for f in files:
            try:
                key = str(f.resolve())
            except (OSError, RuntimeError):  # a link loop: check_dem_path says so
                key = str(f)
            if key not in seen:
                seen.add(key)
                out.append(f)
    return out
