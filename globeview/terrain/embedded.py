"""The embedded default terrain: the DEMs shipped in data/, each ingested once into a tile
store in the user's cache directory (re-ingesting an unchanged source is a no-op)."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from globeview.errors import StoreError
from globeview.paths import cache_dir
from globeview.terrain.dem.data import embedded_dem_paths
from globeview.terrain.dem.reader import check_dem_path
from globeview.terrain.store.identify import identify
from globeview.terrain.store.tile_store import TileStore


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


def open_or_ingest(source: Path, progress: bool = False) -> TileStore:
    """Open the cached store of ``source``, ingesting it first if it is missing or stale."""
    from globeview.terrain.ingest.driver import ingest

    check_dem_path(Path(source))  # a link loop cannot even be resolved to a cache key
    out = store_path_for(source)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StoreError(
            f"cannot create the store cache {out.parent}: {exc.strerror or exc}"
        ) from None
    _drop_stem_keyed_store(source)
    ingest([source], out, progress=progress)
    return TileStore.open(out)


def _drop_stem_keyed_store(source: Path) -> None:
    """Remove the cache's format-2 store of ``source`` (keyed by the file stem alone, before
    stores were keyed by path): globeview owns the cache, and only a store positively
    identified as globeview's, holding store files only, is removed."""
    from globeview.terrain.ingest.safety import remove_store_dir

    old = cache_dir() / "stores" / Path(source).stem
    if identify(old).kind == "legacy":
        remove_store_dir(old)


def embedded_stores(progress: bool = False) -> list[TileStore]:
    """Stores of the embedded DEMs: the global base first, then the regional samples."""
    return [open_or_ingest(p, progress=progress) for p in embedded_dem_paths()]


def embedded_stores_ready() -> bool:
    """Whether every embedded DEM already has a store in the cache (no ingest to wait for)."""
    return all(identify(store_path_for(p)).is_current for p in embedded_dem_paths())
