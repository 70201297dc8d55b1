"""Tile stores: the manifest schema (`schema`), level chunk files (`level_chunks`), reading
(`tile_store.TileStore`) through a store backend (local folders, HTTP, third parties)."""
