"""Store backends: where a tile store's files are read from, behind one protocol.

A store backend turns what the user typed (a folder path, an ``https://`` URL, a third
party's ``s3://bucket/store``) into `StoreFiles`: the store's manifest, its rasters (level
VRTs and chunk files) opened with rasterio, their sha256, for messages their names. `TileStore`
does everything else the same way for every backend: it checks the manifest against the
schema, reads tiles block by block, caches and prefetches them.

Backends are found through the entry-point group `ENTRY_POINT_GROUP`
(``globeview.store_backends``), the built-ins too (``local``, ``http``: pyproject.toml), as
xarray finds its ``BackendEntrypoint``\\s: each entry point loads a class (or a factory)
whose instance answers `StoreBackend.can_open` for a text; `find_backend` asks them in
descending `StoreBackend.priority` (then by name) and takes the first that says yes. A
backend that raises in ``can_open`` (or a bug in ``open``: anything but a one-line
`GlobeviewError`) is reported in one warning line, its traceback in the log, and skipped,
like a failed plugin: it never takes the opening down.

The protocol for a third party: docs/plugins.md, "Store backends".
"""

from __future__ import annotations

import functools
import importlib.metadata as md
import logging
import re
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar, Protocol, runtime_checkable

import rasterio
from rasterio.errors import RasterioError

from globeview.errors import StoreError
from globeview.terrain.store.schema import STORE_FORMAT, StoreHeader

__all__ = [
    "ENTRY_POINT_GROUP",
    "RASTER_ERRORS",
    "StoreBackend",
    "StoreFiles",
    "TileNotReady",
    "claimants",
    "find_backend",
    "raise_interrupt",
    "record_error",
    "report_failure",
    "store_backends",
    "take_error",
    "url_scheme",
]

#: The entry-point group of store backends (pyproject.toml ``[project.entry-points."..."]``).
ENTRY_POINT_GROUP = "globeview.store_backends"

log = logging.getLogger("globeview.terrain.store")

# Errors GDAL raises through rasterio on a bad file: rasterio's own and the CPLE_* family.
try:
    from rasterio._err import CPLE_BaseError as _CPLE
except ImportError:  # pragma: no cover - rasterio's private module moved
    _CPLE = RasterioError
#: What `StoreFiles.open_raster` (rasterio) raises for bytes that are not a usable raster.
RASTER_ERRORS: tuple[type[BaseException], ...] = (RasterioError, _CPLE)


class TileNotReady(StoreError):
    """A read on a thread that must not wait on the network (`StoreFiles.forbid_network_on`)
    needed bytes that are not here yet: the caller shows the tile as loading and asks again
    later (the store fetches it in the background)."""


class StoreFiles:
    """A store's files, wherever they are: what `TileStore` reads through.

    A backend's `StoreBackend.open` returns one. Subclass this class and implement the four
    abstract methods (`read_manifest`, `describe`, `open_raster`, `sha256`); the others have
    defaults that fit files on a local disk. Every error is a one-line `StoreError`.

    Attributes:
        location: the store for people (a folder, a URL with its password masked).
        path: the store's path (its folder; a URL's path part), so ``path.name`` names it.
        base_url: the store's URL when it is read over a network, else None.
        is_remote: its bytes come over a network: they may not be here yet (`TileStore`
            prefetches their bytes, `forbid_network_on` threads get `TileNotReady`).
        offline: a remote store opened from cached metadata (its server unreachable).
        max_requests: reads a byte prefetch (`warm`) may have in flight at once.
        check_on_open: `TileStore.open` checks every level file at once (cheap on a local
            disk); otherwise each file is checked when it is first read.
    """

    location: str = ""
    path: Path = Path()
    base_url: str | None = None
    is_remote: ClassVar[bool] = False
    offline: bool = False
    max_requests: int = 1
    check_on_open: ClassVar[bool] = False

    def read_manifest(self, name: str) -> bytes:
        """The bytes of the store's manifest (``name`` is ``manifest.json``); StoreError one
        line when absent ("... is not a globeview tile store (no manifest.json)") or
        unreadable."""
        raise NotImplementedError

    def describe(self, name: str) -> str:
        """A file of the store for messages (its path or URL)."""
        raise NotImplementedError

    def open_raster(self, name: str, sha256: str | None) -> rasterio.DatasetReader:
        """Open a raster of the store (a level VRT, a chunk file) with rasterio; ``sha256``
        is its digest from the manifest (a remote backend keys caches with it). StoreError
        naming it when missing; rasterio's error when the bytes are not a raster."""
        raise NotImplementedError

    def sha256(self, name: str) -> str:
        """The sha256 (hex) of a whole file of the store (`TileStore.verify`)."""
        raise NotImplementedError

    # -- with defaults ---------------------------------------------------------------------

    def read_small(self, name: str, sha256: str, size: int) -> bytes:
        """The whole bytes of a small store file (a metadata shard) whose sha256 and size the
        store records (a remote backend caches it by its sha256; the caller checks the
        digest). StoreError naming it when missing or unreadable.

        Default: `read_manifest` of that name (backends read any file of the store with it);
        override it to cache by sha256 or to say more when the file is missing."""
        try:
            return self.read_manifest(name)
        except StoreError:
            raise StoreError(
                f"{self.describe(name)}: cannot read this file of the store; re-run globeview "
                "ingest --force"
            ) from None

    def size(self, name: str) -> int:
        """The size in bytes of a file of the store (`TileStore.verify`'s quick check)."""
        return len(self.read_small(name, "", 0))

    def exists(self, name: str) -> bool:
        """Whether a file of the store is there (asked only when `check_on_open`)."""
        return True

    def is_ours(self, manifest: dict[str, Any]) -> bool:
        """Whether a parsed manifest is a globeview store's (its format marker); `TileStore`
        then checks its version and every field."""
        return StoreHeader.peek(manifest).format == STORE_FORMAT

    def explain(self, name: str, exc: BaseException) -> BaseException:
        """The error to raise for a failed read of store file ``name`` (``exc``): a backend
        that can tell that the store was updated since it was opened (and this reader's
        generation collected) says so in one line; default: ``exc`` as it is."""
        return exc

    def close_raster(self, ds: rasterio.DatasetReader) -> None:
        """Close a dataset `open_raster` returned, from any thread."""
        ds.close()

    def warm(self, name: str, offset: int, size: int) -> None:
        """Fetch bytes [offset, offset + size) of a file into the backend's caches without
        decoding them (`TileStore.prefetch_bytes`, remote stores only)."""

    def forbid_network_on(self, thread_ident: int) -> None:
        """Reads on this thread (a window's UI thread) must never wait on the network: raise
        `TileNotReady` for bytes not at hand instead."""

    def close(self) -> None:
        """Cancel reads under way (the store is closing)."""


@runtime_checkable
class StoreBackend(Protocol):
    """What an entry point of `ENTRY_POINT_GROUP` loads: a class (or factory) called with no
    arguments, whose instance has:

    - ``priority`` (int, optional, default 0): backends are asked in descending priority,
      ties by entry-point name; the built-ins have 0 (a backend that should win over one of
      them for the same texts says more);
    - ``can_open(text) -> bool``: whether this backend reads the store ``text`` names;
      cheap, no I/O beyond a stat (asked for every source opened, DEM files included);
    - ``open(text, options=None) -> StoreFiles``: the store's files; a one-line
      `GlobeviewError` (StoreError) for a store it cannot open. ``options`` is what the
      caller passes to `TileStore.open` (``remote_options``; the HTTP backend's
      `RemoteOptions`), None by default;
    - optionally ``check(text) -> str``: the text as it will be opened, or a one-line
      `GlobeviewError` for one of the wrong form, without I/O (the window's URL dialog calls
      it as the user types; ``render`` and ``info`` before any work). Without it the text is
      opened as typed.
    """

    def can_open(self, text: str) -> bool: ...

    def open(self, text: str, options: Any = None) -> StoreFiles: ...


# Errors of the last failed read of a file object on this thread. GDAL swallows what a
# Python file object (rasterio's opener=) raises and reports a generic I/O error, so a
# backend's file objects record the real error here and `TileStore` raises it instead.
_errors = threading.local()


def record_error(exc: BaseException) -> None:
    """Keep ``exc`` as this thread's last read error (a backend's file object, inside GDAL's
    callbacks, where it must never raise)."""
    _errors.error = exc


def take_error() -> BaseException | None:
    """This thread's last read error since the last call (and forget it); None if none."""
    err = getattr(_errors, "error", None)
    _errors.error = None
    return err


def raise_interrupt() -> None:
    """Raise a Ctrl-C that arrived inside a read GDAL completed anyway (recorded by the file
    object, `take_error`)."""
    err = take_error()
    if isinstance(err, KeyboardInterrupt | SystemExit):
        raise err


_SCHEME = re.compile(r"^\s*([A-Za-z][A-Za-z0-9+.-]*)://")


def url_scheme(text: str) -> str | None:
    """The lower-case scheme of ``text`` when it starts like a URL (``name://``), else None
    (a path, even ``C:\\x`` or ``./http:/x``)."""
    m = _SCHEME.match(str(text))
    return m.group(1).lower() if m else None


class _Entry:
    """A discovered backend: its entry-point name, priority and instance."""

    def __init__(self, name: str, priority: int, backend: StoreBackend) -> None:
        self.name = name
        self.priority = priority
        self.backend = backend


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    text = text.splitlines()[0] if text else ""
    text = text if len(text) <= 160 else text[:157] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def report_failure(name: str, what: str, exc: BaseException) -> None:
    """One warning line for a failing backend, which is then skipped (its traceback at debug
    level: the log)."""
    log.warning("store backend %s failed in %s and was skipped: %s", name, what, _one_line(exc))
    log.debug("store backend %s failed in %s", name, what, exc_info=exc)


def store_backends() -> list[tuple[str, StoreBackend]]:
    """The installed store backends as (entry-point name, instance), in the order they are
    asked (descending priority, then name). Read once per `sys.path` (a test adding a site
    folder sees its backends); a backend that fails to load is reported once and left out."""
    return [(e.name, e.backend) for e in _discover(tuple(sys.path))]


@functools.lru_cache(maxsize=8)
def _discover(_path: tuple[str, ...]) -> tuple[_Entry, ...]:
    entries: list[_Entry] = []
    seen: set[str] = set()
    for ep in sorted(_entry_points(), key=lambda ep: ep.name):
        if ep.name in seen:  # a name installed twice (two copies): the first wins
            continue
        seen.add(ep.name)
        try:
            backend = ep.load()()
            priority = getattr(backend, "priority", 0)
            if isinstance(priority, bool) or not isinstance(priority, int):
                raise TypeError(f"priority must be an int, not {priority!r}")
            if not callable(getattr(backend, "can_open", None)) or not callable(
                getattr(backend, "open", None)
            ):
                raise TypeError("a store backend needs can_open(text) and open(text, options)")
        except Exception as exc:  # noqa: BLE001  a broken backend is skipped, like a plugin
            report_failure(ep.name, "loading", exc)
            continue
        entries.append(_Entry(ep.name, priority, backend))
    entries.sort(key=lambda e: (-e.priority, e.name))
    return tuple(entries)


def claimants(text: str) -> Iterator[tuple[str, StoreBackend]]:
    """The backends (in `store_backends` order) whose ``can_open(text)`` is true, as (name,
    backend), asked lazily; a backend raising in ``can_open`` is reported (one line) and
    skipped."""
    for name, backend in store_backends():
        try:
            claims = bool(backend.can_open(text))
        except Exception as exc:  # noqa: BLE001  a failing backend is skipped, like a plugin
            report_failure(name, "can_open", exc)
            continue
        if claims:
            yield name, backend


def _entry_points() -> list[md.EntryPoint]:
    """The entry points of `ENTRY_POINT_GROUP`, read distribution by distribution: one
    installed distribution with unreadable metadata is skipped (a line in the log) instead of
    hiding every backend, the built-ins included (as the plugin registry reads its group)."""
    out: list[md.EntryPoint] = []
    try:
        dists = list(md.distributions())
    except Exception as exc:  # noqa: BLE001  broken installed metadata must not stop opening
        report_failure("discovery", "reading installed distributions", exc)
        return out
    for dist in dists:
        try:
            out.extend(ep for ep in dist.entry_points if ep.group == ENTRY_POINT_GROUP)
        except Exception as exc:  # noqa: BLE001  one broken distribution is skipped
            log.info("store backends of %s skipped: unreadable metadata: %s", dist, exc)
    return out


def find_backend(text: str) -> tuple[str, StoreBackend] | None:
    """The first backend that claims ``text`` (`claimants`), as (name, backend); None when
    none does."""
    return next(claimants(text), None)
