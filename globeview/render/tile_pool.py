"""GPU residency of terrain tiles: one vertex buffer and texture arrays with a slot per tile.

All GL objects are created once (capacity fixed at construction); loading a tile writes its
slot, so the steady-state frame creates no GL object. Lookups of many keys at once are
vectorised (tile keys are packed into int64 codes kept in a sorted array).

When the terrain's layers change, the resident tiles are *retired* (`TilePool.retire`), not
forgotten: they are no longer resident (`slots_of` does not find them), but a retired tile
stays in its slot, findable by `stale_slots_of`, until a new tile is written there, so the
window can keep drawing the old surface where the new layers' tiles have not loaded yet
(issue #25 item 4: adding a layer does not blank the view).
"""

from __future__ import annotations

from collections.abc import Callable

import moderngl
import numpy as np

from globeview.lod.block_indices import SKIRTED, pattern_indices
from globeview.lod.block_strides import N_BLOCKS, N_FACTS, block_facts
from globeview.lod.tile_indices import IndexVariant, grid_indices
from globeview.render.gpu_objects import gpu_objects
from globeview.render.tile_build import ReadyTile
from globeview.render.tile_mesh import FLOATS_PER_VERTEX, TileMesh, vertices_per_tile

KeyArray = np.ndarray  # (N, 3) int64: level, x, y


def key_codes(keys: np.ndarray) -> np.ndarray:
    """Pack (level, x, y) rows into sortable int64 codes (level < 32, x, y < 2^29)."""
    k = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    return (k[:, 0] << 58) | (k[:, 2] << 29) | k[:, 1]


#: Most indices the pool holds before it starts afresh (`IndexPool.patterns`): 8 Mi
#: indices, 32 MB, some thousands of block patterns.
INDEX_POOL_CAP = 1 << 23


class IndexPool:
    """One element buffer holding every index variant used so far, and the triangle lists of
    block patterns (`RenderSet.block_strides`); both are appended on first use (the buffer
    grows by doubling, which is rare and not per frame). Patterns are cached by their bytes,
    so a still camera builds none; when they would pass ``cap`` indices the pool forgets
    everything and starts afresh (variants are rebuilt as they are asked for again)."""

    def __init__(
        self,
        ctx: moderngl.Context,
        size: int,
        initial_bytes: int = 1 << 22,
        cap: int = INDEX_POOL_CAP,
    ) -> None:
        self.ctx = ctx
        self.size = size
        self.cap = int(cap)
        self.buffer = gpu_objects(ctx).buffer(reserve=initial_bytes, dynamic=True)
        self._used = 0  # indices written
        self._variants: dict[IndexVariant, tuple[int, int]] = {}
        self._patterns: dict[bytes, tuple[int, int]] = {}
        self.patterns_built = 0  # block patterns built so far (tests, benchmarks)
        self._custom_first = None
        self.on_realloc: Callable[[], None] | None = None

    def patterns(
        self, block_strides: np.ndarray, edges: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(first index, index count) (M,) each of block patterns (M, 8, 8) int8 with tile
        edges ``edges`` (M, 4, 8) int8 (None: all skirted; `block_indices.pattern_indices`)
        in the buffer, building the new ones in one vectorised gather.

        Ask for a frame's patterns before its variants (`get`): making room for them may
        start the pool afresh, which moves every variant."""
        bs = np.ascontiguousarray(block_strides, dtype=np.int8).reshape(-1, 64)
        if edges is None:
            edges = np.full((len(bs), 4, 8), SKIRTED, dtype=np.int8)
        both = np.concatenate([bs, np.asarray(edges, dtype=np.int8).reshape(-1, 32)], axis=1)
        keys = [row.tobytes() for row in both]
        new = sorted({k for k in keys if k not in self._patterns})
        if new:
            fresh = np.frombuffer(b"".join(new), dtype=np.int8).reshape(-1, 96)
            idx, bounds = pattern_indices(
                self.size, fresh[:, :64].reshape(-1, 8, 8), fresh[:, 64:].reshape(-1, 4, 8)
            )
            if self._used + len(idx) > self.cap and self._used:
                self._restart()
                return self.patterns(block_strides, edges)
            first = self._append(idx)
            for k, lo, hi in zip(new, bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
                self._patterns[k] = (first + lo, hi - lo)
            self.patterns_built += len(new)
        table = np.array([self._patterns[k] for k in keys], dtype=np.int64).reshape(-1, 2)
        return table[:, 0], table[:, 1]

    def _restart(self) -> None:
        """Forget every list (the buffer is kept and overwritten from the start)."""
        self._used = 0
        self._variants.clear()
        self._patterns.clear()

    def get(self, variant: IndexVariant) -> tuple[int, int]:
        """(first index, index count) of a variant in the buffer."""
        hit = self._variants.get(variant)
        if hit is not None:
            return hit
        idx = grid_indices(self.size, variant)
        first = self._append(idx)
        self._variants[variant] = (first, len(idx))
        return first, len(idx)

    def _append(self, idx: np.ndarray) -> int:
        need = (self._used + len(idx)) * 4
        if need > self.buffer.size:
            old = self.buffer.read(size=self._used * 4)
            self.buffer.release()
            self.buffer = gpu_objects(self.ctx).buffer(reserve=max(need * 2, 1 << 22), dynamic=True)
            self.buffer.write(old)
            if self.on_realloc is not None:
                self.on_realloc()
        first = self._used
        self.buffer.write(idx.astype(np.uint32).tobytes(), offset=first * 4)
        self._used += len(idx)
        return first


class TilePool:
    """Slots for resident tiles: vertices in one buffer, albedo and normals in texture arrays.

    Both arrays are RGBA8 with a layer per slot and a texel per node: ``albedo_tex`` holds
    the ramp colour of each node's height (baked at upload, `colour_ramp.tile_texels`),
    ``normal_tex`` its unit ECEF normal as ``n * 0.5 + 0.5`` and, in alpha, its height over
    the tile's coast scale ``coast_scale[slot]`` (metres, `colour_ramp.coast_texels`: sharp
    coasts; the renderer passes it per draw). The fragment shader reads one texel of each
    (two fetches): RGBA8 is llvmpipe's fast sampling path, where the float32 height texture
    and the dependent ramp lookup it replaced were not.

    Args:
        ctx: the moderngl context.
        size: nodes per tile side (2^n + 1).
        capacity: number of slots (tiles resident at once).
    """

    def __init__(self, ctx: moderngl.Context, size: int, capacity: int = 768) -> None:
        self.ctx = ctx
        self.size = size
        self.capacity = capacity
        self.verts_per_tile = vertices_per_tile(size)
        self.vbo = gpu_objects(ctx).buffer(
            reserve=capacity * self.verts_per_tile * FLOATS_PER_VERTEX * 4
        )
        self.albedo_tex = gpu_objects(ctx).texture_array((size, size, capacity), 4, dtype="f1")
        # Normals as 8-bit unsigned (n * 0.5 + 0.5): llvmpipe samples RGBA8 on its fast path,
        # half floats noticeably slower; 1/255 steps are ~0.5 degree, finer than shading needs
        # (issue #29: half floats left the lattice measure of tile_normals.py as it was).
        self.normal_tex = gpu_objects(ctx).texture_array((size, size, capacity), 4, dtype="f1")
        for tex in (self.albedo_tex, self.normal_tex):
            tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            tex.repeat_x = False
            tex.repeat_y = False
        # Per-slot state (numpy, so frame lookups vectorise).
        self.codes = np.full(capacity, -1, dtype=np.int64)
        self.centers = np.zeros((capacity, 3), dtype=np.float64)
        self.coast_scale = np.ones(capacity, dtype=np.float64)  # metres (see above)
        self.last_used = np.zeros(capacity, dtype=np.int64)
        # Per-slot block facts (`lod.block_strides`; NaN: not measured), for block strides.
        self.block_facts = np.full((capacity, N_FACTS, N_BLOCKS), np.nan, dtype=np.float32)
        self._block_stats: dict[int, np.ndarray] = {}  # uploaded, facts not made yet
        self.generation = np.zeros(capacity, dtype=np.int64)
        # Retired tiles (`retire`): their codes, -1 where a slot holds none.
        self.stale_codes = np.full(capacity, -1, dtype=np.int64)
        self._sorted_codes = np.empty(0, dtype=np.int64)
        self._sorted_slots = np.empty(0, dtype=np.int64)
        self._stale_sorted = (np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64))
        self._frame = 0

    # -- lookups -----------------------------------------------------------------------------
    def slots_of(self, keys: KeyArray) -> np.ndarray:
        """Slot of each key, or -1 where not resident."""
        return _lookup(self._sorted_codes, self._sorted_slots, key_codes(keys))

    def stale_slots_of(self, keys: KeyArray) -> np.ndarray:
        """Slot of each key's retired tile (`retire`), or -1 where there is none."""
        return _lookup(*self._stale_sorted, key_codes(keys))

    def drawable_slots(self, keys: KeyArray) -> np.ndarray:
        """Slot of each key: its resident tile, else its retired one, else -1."""
        slots = self.slots_of(keys)
        if len(self._stale_sorted[0]) and (slots < 0).any():
            slots = np.where(slots >= 0, slots, self.stale_slots_of(keys))
        return slots

    def touch(self, slots: np.ndarray) -> None:
        self._frame += 1
        self.last_used[slots[slots >= 0]] = self._frame

    @property
    def resident_count(self) -> int:
        """Tiles resident (retired ones not counted)."""
        return int(np.count_nonzero(self.codes >= 0))

    @property
    def stale_count(self) -> int:
        """Retired tiles still in their slots (`retire`)."""
        return int(np.count_nonzero(self.stale_codes >= 0))

    # -- loading -----------------------------------------------------------------------------
    def load(
        self,
        keys: KeyArray,
        build: Callable[[tuple[int, int, int]], TileMesh | ReadyTile],
        protect: KeyArray | None = None,
        partial: bool = False,
    ) -> int:
        """Make the given keys resident, building meshes with ``build(key)``; returns how many
        tiles were uploaded. Evicts least-recently-used slots not among ``keys`` (nor among
        ``protect``: tiles the frame still draws).

        More missing keys than evictable slots is a RuntimeError (the renderer coarsens a
        render set to the capacity first, see `renderer.coarsen_to_fit`), unless ``partial``:
        then as many as fit are loaded (tiles finished in the background that the frame can
        do without) and the rest are left out."""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        missing = keys[self.slots_of(keys) < 0]
        if len(missing) == 0:
            return 0
        missing = np.unique(missing, axis=0)
        protected = np.zeros(self.capacity, dtype=bool)
        have = self.slots_of(keys if protect is None else np.concatenate([keys, protect]))
        protected[have[have >= 0]] = True
        # Empty slots first, then the least recently drawn, retired tiles among them (a
        # retired tile drawn this frame was touched like a resident one).
        empty = (self.codes < 0) & (self.stale_codes < 0)
        order = np.argsort(np.where(empty, -1, self.last_used), kind="stable")
        free = order[~protected[order]]
        if len(missing) > len(free) and partial:
            missing = missing[: len(free)]
        if len(missing) > len(free):
            raise RuntimeError(
                f"tile pool too small: {len(missing)} tiles to load, {len(free)} slots free"
            )
        for key, slot in zip(missing, free[: len(missing)], strict=False):
            self._upload(int(slot), build((int(key[0]), int(key[1]), int(key[2]))))
            self.codes[slot] = key_codes(key[None, :])[0]
            self.stale_codes[slot] = -1
            self.last_used[slot] = self._frame
        self._measure_blocks(missing, free[: len(missing)])
        self._reindex()
        return len(missing)

    def _measure_blocks(self, keys: np.ndarray, slots: np.ndarray) -> None:
        """The block facts of tiles ``keys`` just uploaded into ``slots`` whose tiles came
        with block stats (`ReadyTile.blocks`), in one batch (`lod.block_strides.block_facts`)."""
        stats = self._block_stats
        self._block_stats = {}
        rows = [i for i, slot in enumerate(slots.tolist()) if slot in stats]
        if rows:
            got = np.stack([stats[int(slots[i])] for i in rows])
            self.block_facts[slots[rows]] = block_facts(keys[rows], got)

    def invalidate(self) -> None:
        """Forget every tile, resident or retired."""
        self.codes[:] = -1
        self.stale_codes[:] = -1
        self._reindex()

    def retire(self) -> None:
        """The resident tiles become retired (e.g. after a layer was added, hidden or
        removed): no longer resident, but kept in their slots for `stale_slots_of` until a
        tile is loaded there. A slot's older retired tile is replaced by its newer one."""
        live = self.codes >= 0
        self.stale_codes[live] = self.codes[live]
        self.codes[:] = -1
        self._reindex()

    def forget_stale(self) -> None:
        """Forget the retired tiles (their slots become free): once a view is complete they
        would only stand in later for tiles of layers that are gone."""
        if (self.stale_codes >= 0).any():
            self.stale_codes[:] = -1
            self._reindex()

    def _reindex(self) -> None:
        self._sorted_codes, self._sorted_slots = _sorted_index(self.codes)
        self._stale_sorted = _sorted_index(self.stale_codes)

    def _upload(self, slot: int, tile: TileMesh | ReadyTile) -> None:
        """Write a tile into ``slot``: a `ReadyTile` as it is (its texels baked where it was
        built), a bare `TileMesh` with its texels baked here."""
        ready = tile if isinstance(tile, ReadyTile) else ReadyTile.from_mesh(tile)
        stride = self.verts_per_tile * FLOATS_PER_VERTEX * 4
        self.vbo.write(ready.vertices, offset=slot * stride)
        s = self.size
        self.albedo_tex.write(ready.albedo, viewport=(0, 0, slot, s, s, 1))
        self.normal_tex.write(ready.normal, viewport=(0, 0, slot, s, s, 1))
        self.centers[slot] = ready.center
        self.coast_scale[slot] = ready.coast_scale
        self.block_facts[slot] = np.nan
        if ready.blocks is not None and ready.blocks.shape == (N_BLOCKS, 5):
            self._block_stats[slot] = ready.blocks
        if ready.release is not None:
            ready.release()  # its arrays are on the GPU now (a worker's shared slot)
        self.generation[slot] += 1


def _sorted_index(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sorted codes, their slots) of the slots holding a code (>= 0) in ``codes``."""
    live = np.nonzero(codes >= 0)[0]
    order = np.argsort(codes[live])
    return codes[live][order], live[order]


def _lookup(sorted_codes: np.ndarray, slots: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Slot of each of ``codes`` in a `_sorted_index`, or -1 where absent."""
    if len(sorted_codes) == 0:
        return np.full(len(codes), -1, dtype=np.int64)
    pos = np.minimum(np.searchsorted(sorted_codes, codes), len(sorted_codes) - 1)
    return np.where(sorted_codes[pos] == codes, slots[pos], -1)
