"""The ingest's last step before its commit: the store's coverage into its top shard.

`with_coverage` opens the store just built (its building folder, manifest written) the way a
reader does, reads the coverage level's tiles (`globeview.terrain.store.coverage`) and writes
the top metadata shard again with that raster in it (`shards.add_coverage`): the bits a
layer's blend mask is made from, so a store read over a network needs no chunk of that level
before its first frame (issue #25 item 4, design 6). Exactly what a reader of a store without
them would compute, from the same code. The caller writes the manifest again (it names the
top shard by its sha256).
"""

from __future__ import annotations

import contextlib
from pathlib import Path

from globeview.terrain.store.coverage import coverage_level, read_coverage
from globeview.terrain.store.schema import FileRef
from globeview.terrain.store.shards import add_coverage
from globeview.terrain.store.tile_store import TileStore

__all__ = ["with_coverage"]


def with_coverage(folder: Path) -> FileRef:
    """Write the top shard of the store in ``folder`` again with its coverage; returns the
    new top shard's `FileRef` (the old file removed when the name changed)."""
    with TileStore.open(folder) as st:
        level = coverage_level(st.bounds, st.tile_n, st.max_level)
        coverage = read_coverage(st, level)
        old = st.manifest.shards.top
        n_strides = len(st.strides)
        name, sha, size = add_coverage(
            folder, old.file, st.tile_n, st.max_level, n_strides, coverage
        )
    if name != old.file:
        with contextlib.suppress(FileNotFoundError):
            (folder / old.file).unlink()
    return FileRef(name, sha, size)
