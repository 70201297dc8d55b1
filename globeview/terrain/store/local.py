"""The built-in store backend for store folders on a local (or mounted) disk.

`LocalBackend` claims a path (not a URL) naming a folder that holds ``manifest.json``;
`TileStore.open` also falls back to it for any other path nobody claims, so a folder that is
not a store gets this backend's one-line refusals ("tile store not found", "... is not a
globeview tile store (no manifest.json)").
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, ClassVar

import rasterio

from globeview.errors import StoreError
from globeview.terrain.store.backend import StoreFiles, url_scheme
from globeview.terrain.store.identify import MANIFEST_NAME, identify

__all__ = ["LocalBackend", "LocalFiles"]


class LocalFiles(StoreFiles):
    """A store folder on disk."""

    check_on_open: ClassVar[bool] = True

    def __init__(self, folder: Path) -> None:
        self.folder = self.path = Path(folder)
        self.location = str(self.folder)
        #: The manifest's bytes when the store was opened (`gone`: updated since?).
        self.opened: bytes | None = None

    def updated(self) -> bool:
        """Whether the store's manifest changed since this reader opened it (an update
        committed a new generation: `terrain.store.generations`)."""
        try:
            return self.opened is not None and (
                (self.folder / MANIFEST_NAME).read_bytes() != self.opened
            )
        except OSError:
            return False

    def gone(self, path: Path, missing: str = "is missing") -> StoreError:
        """The one line for a store file that is not there: the store was updated and this
        reader's generation collected (two updates later), or the store is damaged."""
        if self.updated():
            return StoreError(f"{path}: the store was updated; reopen it")
        sep = "" if missing.startswith(":") else " "
        return StoreError(f"{path}{sep}{missing}; re-run globeview ingest --force")

    def read_manifest(self, name: str) -> bytes:
        """The manifest's bytes; StoreError when the folder or its manifest is missing."""
        if not self.folder.is_dir():
            raise StoreError(f"tile store not found: {self.folder}")
        mpath = self.folder / name
        if not mpath.is_file():
            raise StoreError(f"{self.folder} is not a globeview tile store (no {name})")
        try:
            data = mpath.read_bytes()
        except OSError as exc:
            raise StoreError(f"{mpath}: unreadable manifest ({type(exc).__name__})") from None
        if name == MANIFEST_NAME:
            self.opened = data
        return data

    def is_ours(self, manifest: dict[str, Any]) -> bool:
        """The folder's identity (`identify`: a symlink to a store reads as the store); it
        also knows format-2 stores written before the format marker (which `TileStore.open`
        then refuses as built before vertical datums)."""
        return identify(self.folder.resolve()).is_globeview

    def describe(self, name: str) -> str:
        return str(self.folder / name)

    def exists(self, name: str) -> bool:
        return (self.folder / name).is_file()

    def open_raster(self, name: str, sha256: str | None) -> rasterio.DatasetReader:
        """Open a store raster; StoreError naming it when missing (rasterio's error when
        damaged)."""
        path = self.folder / name
        if not path.is_file():
            raise self.gone(path, ": level file is missing")
        return rasterio.open(path)

    def read_small(self, name: str, sha256: str, size: int) -> bytes:
        """A small store file's bytes (a metadata shard); StoreError naming it when missing
        or unreadable."""
        path = self.folder / name
        try:
            return path.read_bytes()
        except FileNotFoundError:
            raise self.gone(path) from None
        except OSError as exc:
            raise StoreError(f"cannot read {path}: {exc.strerror}") from None

    def size(self, name: str) -> int:
        """A store file's size in bytes (StoreError naming it when missing)."""
        try:
            return (self.folder / name).stat().st_size
        except OSError:
            raise self.gone(self.folder / name) from None

    def sha256(self, name: str) -> str:
        """The sha256 of a store file (StoreError naming it when unreadable)."""
        h = hashlib.sha256()
        try:
            with (self.folder / name).open("rb") as f:
                while chunk := f.read(1 << 20):
                    h.update(chunk)
        except OSError as exc:
            raise StoreError(f"cannot read {self.folder / name}: {exc.strerror}") from None
        return h.hexdigest()


class LocalBackend:
    """Store folders on disk (entry point ``local`` of ``globeview.store_backends``)."""

    priority = 0

    def can_open(self, text: str) -> bool:
        """A path (not a URL: ``name://...`` never names a folder here) of a folder holding a
        manifest."""
        if url_scheme(text) is not None:
            return False
        return (Path(text) / MANIFEST_NAME).is_file()

    def open(self, text: str, options: object = None) -> LocalFiles:
        return LocalFiles(Path(text))
