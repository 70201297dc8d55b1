"""The embedded default terrain: the DEMs shipped in data/, each opened as a source
(`globeview.terrain.sources.open_source`: ingested once into a tile store in the user's cache;
re-ingesting an unchanged source is a no-op).

The window opens them at every launch, where that no-op (importing the ingest, hashing the
DEMs) cost ~0.2 CPU-s (issue #27). So after a full open each DEM's size and modification time,
the terrain code's digest and its store's ``manifest.json`` digest are kept in
``<cache>/embedded-stamps.json``; a later open that finds all of them unchanged opens the stores
as they are (`sources.open_ingested`). Any difference, or a file that cannot be read, takes the
full path again.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

from globeview.fileio import atomic_write_bytes
from globeview.paths import cache_dir
from globeview.terrain.compose.band_tables import code_digest, store_digest
from globeview.terrain.dem.data import embedded_dem_paths
from globeview.terrain.sources import open_ingested, open_source, store_path_for
from globeview.terrain.store.identify import identify
from globeview.terrain.store.tile_store import TileStore

__all__ = ["STAMPS_NAME", "embedded_stores", "embedded_stores_ready"]

log = logging.getLogger(__name__)

#: The stamps' file in the cache folder.
STAMPS_NAME = "embedded-stamps.json"


def embedded_stores(progress: bool = False) -> list[TileStore]:
    """Stores of the embedded DEMs: the global base first, then the regional samples."""
    paths = embedded_dem_paths()
    stores = _stamped_stores(paths)
    if stores is not None:
        return stores
    stores = [open_source(p, progress=progress) for p in paths]
    stamps = {str(p): _stamp(p, st) for p, st in zip(paths, stores, strict=True)}
    if all(s is not None for s in stamps.values()):
        _write({**_read(), **stamps})  # other checkouts' data folders keep theirs
    return stores


def embedded_stores_ready() -> bool:
    """Whether every embedded DEM already has a store in the cache (no ingest to wait for)."""
    return all(identify(store_path_for(p)).is_current for p in embedded_dem_paths())


def _stamp(dem: Path, store: TileStore) -> dict[str, object] | None:
    """What must be unchanged to open ``dem``'s ``store`` as it is; None: not known."""
    try:
        st = os.stat(dem)
    except OSError:
        return None
    manifest = store_digest(store)
    if manifest is None:
        return None
    return {
        "size": st.st_size,
        "mtime_ns": st.st_mtime_ns,
        "code": code_digest(),
        "manifest": manifest,
    }


def _stamped_stores(paths: list[Path]) -> list[TileStore] | None:
    """The stores opened as they are if every stamp still holds, else None."""
    kept = _read()
    if not all(str(p) in kept for p in paths):
        return None
    stores: list[TileStore] = []
    try:
        for p in paths:
            stores.append(open_ingested(p))
            if _stamp(p, stores[-1]) != kept[str(p)]:
                raise ValueError(f"{p.name} changed since it was stamped")
    except Exception as exc:  # noqa: BLE001  the full open says what is wrong, in one line
        log.debug("embedded stores opened in full (%s)", exc)
        for st in stores:
            st.close()
        return None
    return stores


def _read() -> dict[str, object]:
    """The stamps kept, by DEM path (empty: none, or a file that is not what was written)."""
    try:
        kept = json.loads((cache_dir() / STAMPS_NAME).read_text())
    except (OSError, ValueError):
        return {}
    return kept if isinstance(kept, dict) else {}


def _write(stamps: dict[str, object]) -> None:
    try:
        atomic_write_bytes(cache_dir() / STAMPS_NAME, json.dumps(stamps, indent=1).encode())
    except OSError as exc:  # a cache that cannot be written: the next open is a full one
        log.debug("embedded stamps not kept (%s)", exc)
