"""Background tile loading for interactive use.

Building a tile (reading its heights, meshing, averaging normals) takes milliseconds; a fast
camera move can ask for a hundred new tiles in one frame. In the window the renderer therefore
builds tiles on worker threads (numpy and GDAL release the GIL), uploads a few finished ones
per frame, and until a tile is ready draws its nearest resident ancestor instead — never a
hole, never an overlap (the ancestor replaces every requested tile below it). Headless renders
load synchronously so every image is complete.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from globeview.lod.render_set import RenderSet
from globeview.lod.tile_indices import IndexVariant
from globeview.render.tile_mesh import TileMesh

Key = tuple[int, int, int]


class TileLoader:
    """Builds tile meshes on worker threads; the render thread collects finished ones."""

    def __init__(self, build: Callable[[Key], TileMesh], workers: int = 2) -> None:
        self._build = build
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="gv-tiles")
        self._lock = threading.Lock()
        self._pending: dict[Key, Future] = {}
        self.failed: dict[Key, BaseException] = {}

    @property
    def pending(self) -> int:
        return len(self._pending)

    def request(self, keys: np.ndarray) -> None:
        """Queue the tiles of ``keys`` (N, 3) that are not being built yet (coarse first)."""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        order = np.argsort(keys[:, 0], kind="stable")
        with self._lock:
            # A loop over the few tiles that are new this frame, not over every drawn tile.
            for k in keys[order]:
                key = (int(k[0]), int(k[1]), int(k[2]))
                if key not in self._pending and key not in self.failed:
                    self._pending[key] = self._pool.submit(self._build, key)

    def take_ready(self, limit: int) -> list[tuple[Key, TileMesh]]:
        """Up to ``limit`` finished meshes (removed from the queue)."""
        out: list[tuple[Key, TileMesh]] = []
        with self._lock:
            for key, fut in list(self._pending.items()):
                if len(out) >= limit:
                    break
                if fut.done():
                    del self._pending[key]
                    exc = fut.exception()
                    if exc is None:
                        out.append((key, fut.result()))
                    else:
                        self.failed[key] = exc
        return out

    def cancel_all(self) -> None:
        """Forget queued work (e.g. after the terrain layers changed)."""
        with self._lock:
            for fut in self._pending.values():
                fut.cancel()
            self._pending.clear()
            self.failed.clear()

    def shutdown(self) -> None:
        self.cancel_all()
        self._pool.shutdown(wait=False, cancel_futures=True)


def substitute_missing(
    render_set: RenderSet, resident: Callable[[np.ndarray], np.ndarray]
) -> tuple[RenderSet, np.ndarray]:
    """Replace tiles that are not resident by their nearest resident ancestor.

    ``resident(keys) -> bool array``. Every requested tile below a chosen ancestor is dropped
    (the ancestor covers it), so the result has no overlaps; a missing tile with no resident
    ancestor leaves a gap until something loads. Returns the new render set and the keys
    that were missing (to request).
    """
    keys = render_set.keys
    have = resident(keys)
    if have.all():
        return render_set, np.empty((0, 3), np.int64)
    missing = keys[~have]
    # Walk each missing tile up until a resident ancestor turns up (one vectorised step per
    # level).
    anc = missing.copy()
    found = np.zeros(len(anc), dtype=bool)
    while not found.all() and (anc[~found, 0] > 0).any():
        step = ~found & (anc[:, 0] > 0)
        anc[step] = np.stack([anc[step, 0] - 1, anc[step, 1] >> 1, anc[step, 2] >> 1], axis=1)
        found[step] = resident(anc[step])
    subs = np.unique(anc[found], axis=0)

    # Drop requested tiles that lie under a chosen ancestor (and the missing ones).
    keep = have.copy()
    for level in np.unique(subs[:, 0]):
        at = subs[subs[:, 0] == level]
        codes = at[:, 1] * (1 << 31) + at[:, 2]
        deeper = keys[:, 0] >= level
        shift = keys[:, 0] - level
        ax = np.where(deeper, keys[:, 1] >> np.maximum(shift, 0), -1)
        ay = np.where(deeper, keys[:, 2] >> np.maximum(shift, 0), -1)
        keep &= ~(deeper & np.isin(ax * (1 << 31) + ay, codes))

    rows = np.nonzero(keep)[0]
    variants = list(render_set.variants)
    pole = (subs[:, 2] == 0).astype(np.int64) + 2 * (subs[:, 2] == (1 << subs[:, 0]) - 1)
    poles = (None, "north", "south", "both")
    sub_ids = np.empty(len(subs), dtype=np.int64)
    for code in np.unique(pole):
        variants.append(IndexVariant(stride=4, skirts=True, pole=poles[int(code)]))
        sub_ids[pole == code] = len(variants) - 1
    new_index = {int(r): i for i, r in enumerate(rows)}
    custom = {new_index[r]: idx for r, idx in render_set.custom_indices.items() if r in new_index}
    err = None
    if render_set.error_px is not None:
        # A stand-in tile is coarser than asked for: its error is unknown here (inf).
        err = np.concatenate([render_set.error_px[rows], np.full(len(subs), np.inf)])
    out = RenderSet(
        np.concatenate([keys[rows], subs]),
        np.concatenate([render_set.variant_ids[rows], sub_ids]),
        variants,
        custom_indices=custom,
        error_px=err,
        stats=dict(render_set.stats),
    )
    return out, missing
