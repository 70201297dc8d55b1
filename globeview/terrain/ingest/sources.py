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

Datasets as users get them (issue #25) are thousands of tiles, beyond a shell's argument
list: a source may also be

- a **glob** (``'srtm/*.hgt'``, ``'copdem/**/*_DEM.tif'``; quoted, so the shell leaves it),
  expanded by `glob.glob` with ``recursive=True`` into the regular files it matches, sorted
  (folders it matches are not entered): a pattern matching nothing is one error line;
- a **list** ``@tiles.txt``: one path (or glob, or folder) a line, relative paths from the
  list's folder, blank lines and ``#`` comments skipped; a list that cannot be read, or
  holds no path, is one error line (a listed file that is missing is `check_dem_path`'s).
"""

from __future__ import annotations

import glob
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

from globeview.errors import DemError
from globeview.terrain.store.identify import identify

__all__ = ["FOLDER_SUFFIXES", "expand_sources", "is_glob"]

#: Characters that make a source a glob pattern (when no file has that name).
GLOB_CHARS = frozenset("*?[")

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


def is_glob(text: str) -> bool:
    """Whether a source is a glob pattern: it holds ``* ? [`` and no file has that name."""
    return bool(GLOB_CHARS & set(text)) and not os.path.lexists(text)


def _glob_files(pattern: str) -> list[Path]:
    """The regular files a glob matches, sorted (DemError when it matches none)."""
    hits = sorted(glob.glob(pattern, recursive=True))
    files = [Path(h) for h in hits if os.path.isfile(h)]
    if not files:
        what = "no files" if not hits else "only folders"
        raise DemError(f"{pattern} matches {what} (a glob: quote it so the shell leaves it)")
    return files


def _list_entries(spec: str) -> list[str]:
    """The paths named in a list file ``@FILE`` (relative ones from its folder)."""
    path = Path(spec[1:])
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DemError(f"list of sources not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        why = exc.strerror if isinstance(exc, OSError) else "not UTF-8 text"
        raise DemError(f"cannot read the list of sources {path}: {why}") from None
    base = path.parent
    entries = []
    for line in text.splitlines():
        item = line.strip()
        if item and not item.startswith("#"):
            entries.append(os.path.normpath(item if os.path.isabs(item) else base / item))
    if not entries:
        raise DemError(f"the list of sources {path} names no file")
    return entries


def _expand_one(source: str | os.PathLike[str], in_list: bool = False) -> Iterator[Path]:
    """The DEM files one source stands for: a folder's, a glob's, a list's, or itself."""
    text = str(source)
    if text.startswith("@") and not in_list and not os.path.lexists(text):
        for entry in _list_entries(text):
            yield from _expand_one(entry, in_list=True)
    elif is_glob(text):
        yield from _glob_files(text)
    elif os.path.isdir(text):
        yield from _folder_dems(Path(text))
    else:
        yield Path(text)


def expand_sources(paths: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """``paths`` with every folder replaced by its DEM files, every glob by the files it
    matches and every ``@list`` by what it names (see the module docstring), in the order
    given; a file named twice (directly, through a folder, a glob or a list, compared by
    resolved path) is kept once, where it first appears. Paths that are not folders are
    passed on unchecked (`check_dem_path` words what is wrong with them)."""
    out: list[Path] = []
    seen: set[str] = set()
    for p in paths:
        for f in _expand_one(p):
            try:
                key = str(f.resolve())
            except (OSError, RuntimeError):  # a link loop: check_dem_path says so
                key = str(f)
            if key not in seen:
                seen.add(key)
                out.append(f)
    return out
