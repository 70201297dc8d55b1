"""The quadtree-clod provider's cache of per-tile CLOD data, packed in slot arrays.

A frame reads only the few nodes and blocks its refinement touches (`mesh.clod_frame` indexes
these arrays by slot), so nothing per tile is copied or stacked per frame: the tile's
`mesh.TileClod` is written into its slot once, at first use, and stays there while it is
used. Lookups are vectorised: per *generation* (one exaggeration and displacement: what the
data depends on besides the tile) a sorted array of packed tile codes with their slots, and
the least recently used slots are reused when the cache is full.

Units and frames are `mesh.TileClod`'s (each tile's ENU frame, metres).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable

import numpy as np

from globeview.plugins.builtin.clod.mesh import TileClod, n_block_levels


def tile_codes(keys: np.ndarray) -> np.ndarray:
    """(N,) int64 codes of (N, 3) keys (level, x, y): level << 58 | y << 29 | x (x, y <
    2^29 at every level a render set may have)."""
    k = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    return (k[:, 0] << 58) | (k[:, 2] << 29) | k[:, 1]


class ClodTiles:
    """At most ``capacity`` tiles' CLOD data of one tile size, in slot arrays.

    Per slot: ``pos`` (size, size, 3) node positions, ``err`` (size, size) vertex errors,
    ``emax[j]`` / ``radius[j]`` (2^j, 2^j) per block level, ``origin`` (3,) and ``basis``
    (3, 3) of the tile's ENU frame (`mesh.TileClod`). Arrays grow by doubling up to the
    capacity (a full cache of 65 x 65 tiles is ~170 kB a tile, as the per-tile objects were).
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self.size = 0
        self.n_used = 0  # slots 0..n_used-1 have been filled at least once
        self._clock = 0
        self._gens: dict[Hashable, int] = {}
        self._gen_keys: dict[int, Hashable] = {}
        self._next_gen = 0
        # Per generation id: sorted codes and their slots.
        self._index: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.slot_gen = np.empty(0, dtype=np.int64)
        self.slot_code = np.empty(0, dtype=np.int64)
        self.last_used = np.empty(0, dtype=np.int64)
        self.pos = np.empty((0, 0, 0, 3))
        self.err = np.empty((0, 0, 0))
        self.emax: list[np.ndarray] = []
        self.radius: list[np.ndarray] = []
        self.origin = np.empty((0, 3))
        self.basis = np.empty((0, 3, 3))

    def __len__(self) -> int:
        return sum(len(c) for c, _ in self._index.values())

    def clear(self) -> None:
        self.__init__(self.capacity)  # type: ignore[misc]

    # -- storage -------------------------------------------------------------------------------
    def _alloc(self, size: int, cap: int) -> None:
        """(Re)allocate the slot arrays for ``cap`` slots of tiles of ``size`` nodes, keeping
        the slots filled so far."""
        n_levels = n_block_levels(size)
        keep = self.n_used if size == self.size else 0

        def grown(old: np.ndarray, shape: tuple[int, ...], fill: int | None = None) -> np.ndarray:
            # Data slots are written before they are read: no fill (pages untouched).
            out = np.empty((cap, *shape), dtype=old.dtype)
            if fill is not None:
                out[keep:] = fill
            out[:keep] = old[:keep]
            return out

        if size != self.size:
            self.pos = np.empty((0, size, size, 3))
            self.err = np.empty((0, size, size))
            self.emax = [np.empty((0, 1 << j, 1 << j)) for j in range(n_levels)]
            self.radius = [np.empty((0, 1 << j, 1 << j)) for j in range(n_levels)]
            self._gens, self._gen_keys, self._index, self.n_used = {}, {}, {}, 0
            self.size = size
        self.pos = grown(self.pos, (size, size, 3))
        self.err = grown(self.err, (size, size))
        self.emax = [grown(a, a.shape[1:]) for a in self.emax]
        self.radius = [grown(a, a.shape[1:]) for a in self.radius]
        self.origin = grown(self.origin, (3,))
        self.basis = grown(self.basis, (3, 3))
        self.slot_gen = grown(self.slot_gen, (), -1)
        self.slot_code = grown(self.slot_code, (), 0)
        self.last_used = grown(self.last_used, (), -1)

    def _free_slots(self, m: int, current: int) -> np.ndarray:
        """``m`` slots to fill: unused ones first, then the least recently used of those not
        used this frame (the caller marks this frame's hits first), dropped from their index.
        A frame needing more tiles than the capacity grows the arrays beyond it."""
        cap, used = len(self.last_used), self.n_used
        stale = int(np.count_nonzero(self.last_used[:used] != self._clock))
        if used + m > cap:
            if used + m <= self.capacity:  # room to grow: no eviction yet
                want = min(self.capacity, max(2 * cap, used + m, 16))
            else:  # evict the stale, and grow beyond the capacity only if they are too few
                want = max(self.capacity, used + m - stale)
            if want > cap:
                self._alloc(self.size, want)
                cap = want
        fresh = np.arange(used, min(cap, used + m))
        self.n_used = used + len(fresh)
        short = m - len(fresh)
        if short <= 0:
            return fresh
        # The least recently used of the slots filled before (fresh ones are not candidates).
        old = np.argsort(self.last_used[:used], kind="stable")[:short]
        for g in np.unique(self.slot_gen[old]).tolist():
            if g < 0:
                continue
            codes, slots = self._index[g]
            keep = ~np.isin(slots, old)
            if keep.any() or g == current:
                self._index[g] = (codes[keep], slots[keep])
            else:  # a generation with no tile left (e.g. a past displacement) is forgotten
                del self._index[g]
                del self._gens[self._gen_keys.pop(g)]
        self.slot_gen[old] = -1
        return np.concatenate([fresh, old])

    def _put(self, slot: int, data: TileClod) -> None:
        self.pos[slot] = data.pos
        self.err[slot] = data.err
        for j, (e, r) in enumerate(zip(data.emax, data.radius, strict=True)):
            self.emax[j][slot] = e
            self.radius[j][slot] = r
        self.origin[slot] = data.origin
        self.basis[slot] = data.basis

    # -- lookup --------------------------------------------------------------------------------
    def slots(
        self,
        keys: np.ndarray,
        size: int,
        generation: Hashable,
        build: Callable[[list[tuple[int, int, int]]], list[TileClod]],
    ) -> np.ndarray:
        """(N,) slots holding the data of tiles ``keys`` (N, 3) for ``generation`` (what the
        data depends on besides the tile: exaggeration, displacement), calling ``build`` once
        with the keys of the tiles not cached (it returns their data in that order). ``keys``
        must be distinct (a render set's are)."""
        if size != self.size:
            self._alloc(size, 0)
        self._clock += 1
        gid = self._gens.get(generation)
        if gid is None:
            gid = self._gens[generation] = self._next_gen
            self._gen_keys[gid] = generation
            self._next_gen += 1
        codes = tile_codes(keys)
        sorted_codes, sorted_slots = self._index.get(gid, (np.empty(0, np.int64),) * 2)
        out = np.full(len(codes), -1, dtype=np.int64)
        if len(sorted_codes):
            at = np.minimum(np.searchsorted(sorted_codes, codes), len(sorted_codes) - 1)
            hit = sorted_codes[at] == codes
            out[hit] = sorted_slots[at[hit]]
        miss = np.flatnonzero(out < 0)
        self.last_used[out[out >= 0]] = self._clock
        if len(miss):
            free = self._free_slots(len(miss), gid)
            k = np.asarray(keys, dtype=np.int64).reshape(-1, 3).take(miss, axis=0)
            built = build([(int(a), int(b), int(c)) for a, b, c in k.tolist()])
            for slot, data in zip(free.tolist(), built, strict=True):
                self._put(slot, data)
            out[miss] = free
            self.slot_gen[free] = gid
            self.slot_code[free] = codes[miss]
            self.last_used[free] = self._clock
            sorted_codes, sorted_slots = self._index.get(gid, (np.empty(0, np.int64),) * 2)
            all_codes = np.concatenate([sorted_codes, codes[miss]])
            all_slots = np.concatenate([sorted_slots, free])
            order = np.argsort(all_codes, kind="stable")
            self._index[gid] = (all_codes[order], all_slots[order])
        return out
