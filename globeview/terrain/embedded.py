"""The embedded default terrain: the DEMs shipped in data/, each opened as a source
(`globeview.terrain.sources.open_source`: ingested once into a tile store in the user's cache;
re-ingesting an unchanged source is a no-op)."""

from __future__ import annotations

from globeview.terrain.dem.data import embedded_dem_paths
from globeview.terrain.sources import open_source, store_path_for
from globeview.terrain.store.identify import identify
from globeview.terrain.store.tile_store import TileStore


def embedded_stores(progress: bool = False) -> list[TileStore]:
    """Stores of the embedded DEMs: the global base first, then the regional samples."""
    return [open_source(p, progress=progress) for p in embedded_dem_paths()]


def embedded_stores_ready() -> bool:
    """Whether every embedded DEM already has a store in the cache (no ingest to wait for)."""
    return all(identify(store_path_for(p)).is_current for p in embedded_dem_paths())
