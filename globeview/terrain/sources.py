"""The one way to open a source: what the user typed, as a `TileStore`.

A source is the text a user gives the window (File > Open, drag and drop, File > Open URL),
``render``, ``height``, ``info`` or ``bench``:

- a store a store backend claims (`globeview.terrain.store.backend`): a folder holding
  ``manifest.json``, an ``http(s)://`` URL, or whatever an installed backend reads (an
  ``s3://`` URL, a Zarr store...): opened as it is (`TileStore.open`);
- any other ``scheme://`` text: refused in one line saying what to type instead;
- a folder that is not a store: refused in one line;
- anything else is a DEM file: checked (`check_dem_path`), ingested once into the user's
  cache (`store_path_for`: an unchanged file opens instantly the next time) and opened.

`open_source` does it for all of them with the same checks and the same words, and
`check_source` runs the cheap part (the form of a URL, a DEM path that exists) before any
slow work, so a command given several sources refuses a bad one before it ingests the
others. Every failure is a one-line `GlobeviewError` (`DemError`, `StoreError`).
"""

from __future__ import annotations

import errno
import hashlib
import os
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from globeview.errors import GlobeviewError, StoreError
from globeview.fileio import describe_os_error
from globeview.paths import cache_dir
from globeview.terrain.store.backend import (
    StoreBackend,
    find_backend,
    report_failure,
    url_scheme,
)
from globeview.terrain.store.identify import identify
from globeview.terrain.store.tile_store import TileStore

__all__ = [
    "cache_message",
    "check_source",
    "check_store_url",
    "is_store_url",
    "open_ingested",
    "open_source",
    "opened_as",
    "source_kind",
    "store_path_for",
]

#: Errors of a cache folder that cannot be written (a read-only mount, no permission, full).
_CACHE_ERRNOS = (errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EDQUOT)


def is_store_url(text: str) -> bool:
    """Whether ``text`` is meant as a URL (any ``scheme://``), to be checked with
    `check_store_url` rather than opened as a path."""
    return url_scheme(text) is not None


def check_store_url(text: str) -> str:
    """The URL of a store as it will be opened: checked by the store backend that claims it
    (the built-in HTTP backend: http(s) only, a host, a port in range, no user info, spaces
    in the path percent-encoded, a trailing slash dropped). Raises a one-line
    `GlobeviewError` for a text that is no URL and for a scheme no backend reads."""
    raw = str(text).strip()
    shown = raw if len(raw) <= 80 else raw[:77] + "..."
    scheme = url_scheme(raw)
    if scheme is None:
        raise GlobeviewError(f"not a URL: {shown!r} (a store URL starts with https://)")
    found = find_backend(raw)
    if found is None:
        hint = (
            "; open a local store by its folder path instead"
            if scheme == "file"
            else "; serve the store over HTTP, as any static web server does"
        )
        raise GlobeviewError(
            f"{scheme}:// URLs are not supported (stores are read over http:// or https://){hint}"
        )
    return _checked_by(*found, raw)


def _checked_by(name: str, backend: StoreBackend, text: str) -> str:
    """``text`` as the backend's optional ``check`` gives it back (one `GlobeviewError` line
    for a text of the wrong form); a backend without one takes the text as typed, and one
    whose check fails otherwise is reported and left to its ``open``."""
    check = getattr(backend, "check", None)
    if check is None:
        return text
    try:
        return str(check(text))
    except GlobeviewError:
        raise
    except Exception as exc:  # noqa: BLE001  a failing backend is reported, like a plugin
        report_failure(name, "check", exc)
        return text


def source_kind(text: str) -> Literal["store", "dem"]:
    """ "store" when a store backend claims ``text``, "dem" for a path to be read as a DEM
    file (not checked further: `check_dem_path`). A URL no backend reads and a folder that is
    not a store are one-line errors."""
    if find_backend(text) is not None:
        return "store"
    _refuse_unclaimed(text)
    return "dem"


def _refuse_unclaimed(text: str) -> None:
    """One line for a text no store backend claims that cannot be a DEM file either: a URL
    (no backend reads its scheme) or a folder (not a store)."""
    if is_store_url(text):
        check_store_url(text)  # raises: no backend reads that scheme
    p = Path(text)
    if p.is_dir():
        raise StoreError(
            f"{p} is a directory, not a DEM file, and not a globeview tile store (it has no "
            "manifest.json)"
        )


def check_source(text: str) -> str:
    """What can be checked of a source before any slow work: a store URL's form
    (`check_store_url`), a DEM file that exists and is a readable file (`check_dem_path`), a
    folder that is a store. Returns the source as it will be opened (a URL normalised)."""
    if source_kind(text) == "store":
        return check_store_url(text) if is_store_url(text) else text
    from globeview.terrain.dem.reader import check_dem_path  # deferred: GDAL's CRS set-up

    check_dem_path(Path(text))
    return text


def open_source(
    text: str | os.PathLike[str],
    *,
    crs: str | None = None,
    vdatum: str | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    progress: bool = False,
) -> TileStore:
    """The `TileStore` of a source (see the module's docstring): a store as it is, a DEM
    file ingested into the cache once.

    Args:
        text: a DEM path, a store folder, a store URL, or what an installed backend reads.
        crs, vdatum: the DEM file's CRS and vertical datum when it lacks them or declares
            wrong ones (``--crs``, ``--vdatum``; None: from the file). They key a store of
            their own in the cache. A store already holds ellipsoidal heights on WGS84: they
            do not apply to it.
        on_progress: ``on_progress(done, total)`` after each task of an ingest (a progress
            bar); an exception it raises aborts the ingest (cancel), leaving no store.
        progress: show ingest's terminal progress bar.

    Raises:
        GlobeviewError: one line (DemError, StoreError) for a source that cannot be opened.
    """
    text = os.fspath(text)
    found = find_backend(text)
    if found is not None:
        store = TileStore.open(_checked_by(*found, text))
        where = text if is_store_url(text) else os.path.abspath(text)
        _OPENED[store] = SourceOrigin(where, "store", None, None)
        return store
    _refuse_unclaimed(text)
    store = _open_dem(Path(text), crs, vdatum, on_progress, progress)
    _OPENED[store] = SourceOrigin(os.path.abspath(text), "dem", crs, vdatum)
    return store


@dataclass(frozen=True)
class SourceOrigin:
    """What a store was opened from (`opened_as`): ``text`` the absolute path of a DEM file
    or store folder, or a store URL as typed; ``kind`` "dem" or "store"; the ``crs`` and
    ``vdatum`` given for a DEM file (None: the file's own)."""

    text: str
    kind: str
    crs: str | None
    vdatum: str | None


#: The origin of every store `open_source` opened in this process (a project file names
#: the sources, not the cache's stores). Weak: a store closed and dropped is forgotten.
_OPENED: weakref.WeakKeyDictionary[TileStore, SourceOrigin] = weakref.WeakKeyDictionary()


def opened_as(store: TileStore) -> SourceOrigin | None:
    """What `open_source` opened ``store`` from, or None (a store opened otherwise)."""
    return _OPENED.get(store)


def _open_dem(
    path: Path,
    crs: str | None,
    vdatum: str | None,
    on_progress: Callable[[int, int], None] | None,
    progress: bool,
) -> TileStore:
    """A DEM file's cached store, ingested first when missing or stale."""
    # Deferred: the ingest's and the DEM reader's imports (~0.13 CPU-s) are for DEM files
    # only; the window's launch opens its embedded stores without them (issue #27).
    from globeview.terrain.dem.reader import check_dem_path
    from globeview.terrain.ingest.driver import ingest

    check_dem_path(path)  # a link loop cannot even be resolved to a cache key
    out = store_path_for(path, crs=crs, vdatum=vdatum)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # $GLOBEVIEW_CACHE_DIR under a file, a read-only home, ...
        raise StoreError(
            f"cannot ingest {path.name}: cannot create the store cache {out.parent} "
            f"({exc.strerror or exc}); set GLOBEVIEW_CACHE_DIR to a writable folder"
        ) from None
    _drop_stem_keyed_store(path)
    try:
        ingest([path], out, crs=crs, vdatum=vdatum, progress=progress, on_progress=on_progress)
    except OSError as exc:
        if exc.errno in _CACHE_ERRNOS:
            problem = describe_os_error(exc, exc.filename or "")
            raise StoreError(f"cannot ingest {path.name}: {cache_message(problem)}") from None
        raise
    return TileStore.open(out)


def open_ingested(path: Path) -> TileStore:
    """The cache's store of DEM file ``path`` opened as it is, without checking that it is
    current (the caller knows: `globeview.terrain.embedded`'s stamps), and recorded as
    `open_source` records a DEM's store (`opened_as`). Raises `StoreError` (one line) for a
    store that does not open."""
    store = TileStore.open(store_path_for(path))
    _OPENED[store] = SourceOrigin(os.path.abspath(path), "dem", None, None)
    return store


def cache_message(problem: str) -> str:
    """The one line for a tile cache that cannot be written, ``problem`` saying why."""
    return (
        f"cannot write the tile cache {cache_dir()} ({problem}); set GLOBEVIEW_CACHE_DIR to "
        "a writable folder"
    )


def store_path_for(source: Path, *, crs: str | None = None, vdatum: str | None = None) -> Path:
    """Where the store of an ingested DEM lives in the cache: ``stores/STEM-HASH``, HASH a
    short digest of the resolved absolute path, so a/dem.tif and b/dem.tif get two stores
    (keyed by the stem alone, the second replaced the first while it was open).

    An explicit ``crs`` or ``vdatum`` makes other heights of the same file, so it keys a
    store of its own too: re-opening a DEM with another datum never rebuilds the store a
    window still draws from.
    """
    resolved = Path(source).expanduser().resolve()
    key = os.fsencode(resolved)
    if crs is not None or vdatum is not None:
        key += f"|crs={crs}|vdatum={vdatum}".encode()
    digest = hashlib.sha256(key).hexdigest()[:12]
    return cache_dir() / "stores" / f"{resolved.stem}-{digest}"


def _drop_stem_keyed_store(source: Path) -> None:
    """Remove the cache's format-2 store of ``source`` (keyed by the file stem alone, before
    stores were keyed by path): globeview owns the cache, and only a store positively
    identified as globeview's, holding store files only, is removed."""
    old = cache_dir() / "stores" / Path(source).stem
    if identify(old).kind == "legacy":
        from globeview.terrain.ingest.safety import remove_store_dir  # deferred, as above

        remove_store_dir(old)
