"""Chunk sets from footprints: which chunks of store format 7 a build writes, level by level,
and which sources each chunk reads (issue #25, design §4.2).

The plan is the writer's input: `plan_chunks` returns a `ChunkPlan` whose `LevelPlan` per
level holds

- ``codes``: the planned chunks, a sorted unique int64 array of `layout.chunk_code`
  ((cy << 32) | cx on the global chunk grid of `terrain.store.layout`);
- ``src_ptr``, ``src_idx``: a CSR of the sources a chunk task fills NaN nodes from: chunk
  ``codes[j]`` reads the rows ``src_idx[src_ptr[j]:src_ptr[j+1]]`` of the `FootprintTable`,
  already in the build's fill order (`fill_order`: finest pixel first, ties in input order;
  the order ``tasks.fill_from_sources`` walks), and only sources of natural level <= L
  (finer sources reach level L through the wavelet of level L+1's chunks, as today).

How a level's set is made, vectorised over sources (no loop per source or chunk):

1. each source's natural level (`footprints.natural_levels`), clamped as the build does
   (`ChunkPlan.source_levels`: the finest natural level becomes L_max, the others
   min(level, L_max));
2. at level L, every source of level >= L contributes the chunks whose closed node window
   ((C+1)^2 nodes, the chunk task's) comes within one node spacing and one source pixel of
   its footprint (`tasks.fill_reads_source`'s test: the same chunks, columns folded across
   the antimeridian), expanded with ``np.repeat`` arithmetic and made unique;
3. with the parents of level L+1's chunks (one chunk below c0);
4. sources coarser than L add no chunks: they are paired with the level's chunks they
   reach (a global base under regional detail fills the detail's NaN nodes).

Counts are upper bounds: the build drops chunks whose sources hold no data there after its
scans. `PLAN_MAX_CHUNKS` guards memory (one line naming --max-level).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from globeview.errors import StoreError
from globeview.terrain.ingest.footprints import FootprintTable
from globeview.terrain.quadtree import node_spacing
from globeview.terrain.store.layout import (
    chunk_code,
    chunk_grid_shape,
    chunk_levels_c0,
    chunk_nodes,
    chunk_tiles,
    decode_chunk_code,
    shard_roots,
)

__all__ = [
    "PLAN_MAX_CHUNKS",
    "ChunkPlan",
    "LevelPlan",
    "chunks_at_least",
    "clamp_levels",
    "estimated_files",
    "fill_order",
    "plan_chunks",
]

#: Most chunks (or source-chunk pairs) a plan may hold: ~2 GB of plan arrays, a store of
#: ~200 TB; beyond it the plan is refused in one line naming --max-level.
PLAN_MAX_CHUNKS = 50_000_000


@dataclass(frozen=True)
class LevelPlan:
    """The chunks of one level and the sources each reads (see the module docstring)."""

    level: int
    codes: np.ndarray  # int64, sorted unique chunk codes
    src_ptr: np.ndarray  # int64, len(codes) + 1
    src_idx: np.ndarray  # int32 rows of the FootprintTable, fill order within a chunk

    @property
    def chunks(self) -> int:
        return int(self.codes.size)

    @property
    def source_reads(self) -> int:
        """Source-chunk pairs: how many source reads the level's chunk tasks make at most."""
        return int(self.src_idx.size)

    def sources_of(self, cy: int, cx: int) -> np.ndarray:
        """FootprintTable rows chunk (cy, cx) reads, in fill order (empty when none or when
        the chunk is not planned)."""
        code = int(chunk_code(cy, cx))
        j = int(np.searchsorted(self.codes, code))
        if j >= self.codes.size or int(self.codes[j]) != code:
            return self.src_idx[:0]
        return self.src_idx[self.src_ptr[j] : self.src_ptr[j + 1]]


@dataclass(frozen=True)
class ChunkPlan:
    """A build's chunk sets: ``levels[L]`` for L in 0..max_level.

    tile_n, k (tiles a chunk side), chunk_nodes (C, node intervals a chunk side) as in
    `terrain.store.layout`; source_levels: each source's clamped natural level (int64, table
    order); fill_order: table rows finest first (ties in input order)."""

    tile_n: int
    max_level: int
    levels: tuple[LevelPlan, ...]
    source_levels: np.ndarray
    fill_order: np.ndarray

    @property
    def k(self) -> int:
        return chunk_tiles(self.tile_n)

    @property
    def chunk_nodes(self) -> int:
        return chunk_nodes(self.tile_n)

    @property
    def chunks(self) -> int:
        return sum(lp.chunks for lp in self.levels)

    def level_nodes(self, level: int) -> int:
        """Node count the level's planned chunks store (upper bound: full chunks)."""
        c = self.chunk_nodes
        lp = self.levels[level]
        if level < chunk_levels_c0(self.tile_n):  # one chunk holding the whole level
            rows = (1 << (level + self.tile_n)) + 1
            return lp.chunks * rows * (1 << (level + 1 + self.tile_n))
        return lp.chunks * c * c

    def chunk_sets(self) -> list[set[tuple[int, int]]]:
        """Each level's planned chunks as a set of (cy, cx), index = level (the shape of
        ``driver._Builder.planned``)."""
        out = []
        for lp in self.levels:
            cy, cx = decode_chunk_code(lp.codes)
            out.append(set(zip(cy.tolist(), cx.tolist(), strict=True)))
        return out

    def shards_by_root(self) -> dict[int, int]:
        """Metadata shards the plan's chunks need, by root level: the top one (level 0) and
        one a root chunk (`layout.shard_roots`) with planned chunks under it."""
        roots = shard_roots(self.max_level, self.tile_n)
        out = {0: 1}
        for i, root in enumerate(roots):
            end = roots[i + 1] if i + 1 < len(roots) else self.max_level + 1
            found: list[np.ndarray] = []
            for lv in range(root, end):
                cy, cx = decode_chunk_code(self.levels[lv].codes)
                s = lv - root
                found.append(chunk_code(cy >> s, cx >> s))
            out[root] = int(np.unique(np.concatenate(found)).size) if found else 0
        return out

    def shards(self) -> int:
        """Metadata shards the plan's chunks need (`shards_by_root`'s total)."""
        return sum(self.shards_by_root().values())


def clamp_levels(natural: np.ndarray, max_level: int | None) -> tuple[np.ndarray, int]:
    """(each source's level, L_max) as the build clamps them (``driver._clamp_levels``):
    L_max is ``max_level`` or the finest natural level; sources of the finest natural level
    get L_max (past it they supply the extra levels, resampled), others min(level, L_max)."""
    top = int(natural.max())
    l_max = top if max_level is None else int(max_level)
    return np.where(natural == top, l_max, np.minimum(natural, l_max)).astype(np.int64), l_max


# -- chunk ranges -----------------------------------------------------------------------------


def _ranges(
    t: FootprintTable, rows: np.ndarray, level: int, tile_n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(cy0, ny, cx0, nx) of the chunks of ``level`` each source in ``rows`` reaches: chunk
    rows cy0..cy0+ny-1 (clipped to the grid) and columns cx0..cx0+nx-1 modulo the grid's
    columns (nx = every column when the footprint goes all the way round)."""
    nrows, ncols = chunk_grid_shape(level, tile_n)
    d = node_spacing(level, tile_n)
    side = chunk_nodes(tile_n) * d  # degrees a chunk side (node intervals)
    reach = d + t.reach[rows]
    t_lo = 90.0 - t.north[rows] - reach  # colatitude, degrees
    t_hi = 90.0 - t.south[rows] + reach
    cy0 = np.maximum(np.ceil(t_lo / side).astype(np.int64) - 1, 0)
    cy1 = np.minimum(np.floor(t_hi / side).astype(np.int64), nrows - 1)
    west, east = t.west[rows], t.east[rows]
    east = np.where(east < west, east + 360.0, east)  # across the antimeridian
    u_lo = west - reach + 180.0
    u_hi = east + reach + 180.0
    cx0 = np.ceil(u_lo / side).astype(np.int64) - 1
    nx = np.floor(u_hi / side).astype(np.int64) - cx0 + 1
    full = t.wraps[rows] | (nx >= ncols)
    cx0 = np.where(full, 0, cx0 % ncols)
    nx = np.where(full, ncols, nx)
    ny = np.maximum(cy1 - cy0 + 1, 0)
    return cy0, ny, cx0, nx


def _expand(
    cy0: np.ndarray, ny: np.ndarray, cx0: np.ndarray, nx: np.ndarray, ncols: int
) -> tuple[np.ndarray, np.ndarray]:
    """(codes, owner): every chunk of every range, and the index of the range it came from."""
    cnt = ny * nx
    total = int(cnt.sum())
    if total > PLAN_MAX_CHUNKS:
        raise _too_big(total)
    owner = np.repeat(np.arange(cnt.size, dtype=np.int64), cnt)
    off = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    w = nx[owner]
    cy = cy0[owner] + off // w
    cx = (cx0[owner] + off % w) % ncols
    return chunk_code(cy, cx), owner


def _too_big(n: int) -> StoreError:
    return StoreError(
        f"the plan would hold {n} chunks or source reads at one level, over the limit of "
        f"{PLAN_MAX_CHUNKS}; use a smaller --max-level"
    )


def _in_ranges(codes: np.ndarray, cy0: int, ny: int, cx0: int, nx: int, ncols: int) -> np.ndarray:
    """Which ``codes`` lie in one chunk range (columns modulo ``ncols``)."""
    cy, cx = decode_chunk_code(codes)
    return (cy >= cy0) & (cy < cy0 + ny) & ((cx - cx0) % ncols < nx)


# -- the plan ---------------------------------------------------------------------------------


def _coarse_pairs(
    t: FootprintTable, rows: np.ndarray, codes: np.ndarray, level: int, tile_n: int
) -> tuple[np.ndarray, np.ndarray]:
    """(chunk positions in ``codes``, source rows) of sources coarser than ``level``
    reaching the level's planned chunks: small ranges expanded and looked up, large ones
    (a global base at a fine level) tested against the planned chunks instead."""
    if rows.size == 0 or codes.size == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    _, ncols = chunk_grid_shape(level, tile_n)
    cy0, ny, cx0, nx = _ranges(t, rows, level, tile_n)
    small = ny * nx <= 4 * codes.size
    pos_parts: list[np.ndarray] = []
    src_parts: list[np.ndarray] = []
    if small.any():
        cand, owner = _expand(cy0[small], ny[small], cx0[small], nx[small], ncols)
        j = np.minimum(np.searchsorted(codes, cand), codes.size - 1)
        hit = codes[j] == cand
        pos_parts.append(j[hit])
        src_parts.append(rows[small][owner[hit]])
    for i in np.flatnonzero(~small):
        pos = np.flatnonzero(_in_ranges(codes, cy0[i], ny[i], cx0[i], nx[i], ncols))
        pos_parts.append(pos)
        src_parts.append(np.full(pos.size, rows[i], dtype=np.int64))
    return np.concatenate(pos_parts), np.concatenate(src_parts)


def _csr(
    n_chunks: int, pos: np.ndarray, src: np.ndarray, rank: np.ndarray, n_src: int
) -> tuple[np.ndarray, np.ndarray]:
    """CSR (ptr, idx) of source rows per chunk position, each chunk's sources by ``rank``."""
    key = pos * n_src + rank[src]
    order = np.argsort(key, kind="stable")
    counts = np.bincount(pos, minlength=n_chunks)
    ptr = np.zeros(n_chunks + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    return ptr, src[order].astype(np.int32)


def _parents(codes: np.ndarray, level: int, tile_n: int) -> np.ndarray:
    """Chunk codes at ``level`` of the chunk-tree parents of level+1's ``codes``."""
    if codes.size == 0:
        return codes
    if level < chunk_levels_c0(tile_n):
        return np.zeros(1, dtype=np.int64)
    cy, cx = decode_chunk_code(codes)
    return np.unique(chunk_code(cy >> 1, cx >> 1))


def _level(
    t: FootprintTable,
    levels: np.ndarray,
    rank: np.ndarray,
    level: int,
    tile_n: int,
    finer: np.ndarray,
) -> LevelPlan:
    """One level's plan: the chunks its own and finer sources reach plus level+1's parents,
    and the CSR of the sources (of level <= ``level``) each chunk reads."""
    _, ncols = chunk_grid_shape(level, tile_n)
    makers = np.flatnonzero(levels >= level)
    cy0, ny, cx0, nx = _ranges(t, makers, level, tile_n)
    cand, owner = _expand(cy0, ny, cx0, nx, ncols)
    codes = np.union1d(cand, _parents(finer, level, tile_n))
    if codes.size > PLAN_MAX_CHUNKS:
        raise _too_big(int(codes.size))
    is_own = levels[makers[owner]] == level
    pos_own = np.searchsorted(codes, cand[is_own])
    src_own = makers[owner[is_own]]
    coarse = np.flatnonzero(levels < level)
    pos_c, src_c = _coarse_pairs(t, coarse, codes, level, tile_n)
    ptr, idx = _csr(
        codes.size, np.concatenate([pos_own, pos_c]), np.concatenate([src_own, src_c]), rank, len(t)
    )
    return LevelPlan(level, codes, ptr, idx)


def chunks_at_least(t: FootprintTable, tile_n: int, max_level: int | None = None) -> list[int]:
    """A lower bound of each level's planned chunks (levels 0..L_max): the most chunks one
    source reaches there, its own or finer (`_ranges`: one rectangle each, no chunk set
    built). A build far too large for its disk (a --max-level 22 of a regional DEM plans
    ~10^7 chunks a level) is refused from these before `plan_chunks` spends minutes."""
    levels, l_max = clamp_levels(t.levels(tile_n), max_level)
    out: list[int] = []
    for lv in range(l_max + 1):
        makers = np.flatnonzero(levels >= lv)
        _, ny, _, nx = _ranges(t, makers, lv, tile_n)
        out.append(int((ny * nx).max()) if makers.size else 0)
    return out


#: Pixel sizes within this relative difference are equal for the fill order: the same
#: nominal resolution computed from two transforms may differ in its last bits.
SAME_RES_REL = 1e-6


def fill_order(res: np.ndarray) -> np.ndarray:
    """Indices of sources by pixel size ``res`` (degrees), finest first; sizes within
    `SAME_RES_REL` of the finest of their run are ties, kept in input order. This is which
    source wins where tiles overlap: the finer pixels, then the one given first."""
    r = np.asarray(res, dtype=np.float64).reshape(-1)
    by_res = np.argsort(r, kind="stable")
    group = np.zeros(r.size, dtype=np.int64)
    g, start = 0, float(r[by_res[0]]) if r.size else 0.0
    for i in by_res.tolist():
        if r[i] > start * (1.0 + SAME_RES_REL):
            g, start = g + 1, float(r[i])
        group[i] = g
    return np.lexsort((np.arange(r.size), group))


def plan_chunks(t: FootprintTable, tile_n: int, max_level: int | None = None) -> ChunkPlan:
    """The chunk sets of a build of the sources ``t`` at ``tile_n`` (levels 0..L_max, L_max
    = ``max_level`` or the finest natural level): see the module docstring. StoreError
    (one line) when there is no source or the plan is over `PLAN_MAX_CHUNKS`."""
    if len(t) == 0:
        raise StoreError("no source DEM given")
    levels, l_max = clamp_levels(t.levels(tile_n), max_level)
    order = fill_order(t.res)
    rank = np.empty(len(t), dtype=np.int64)
    rank[order] = np.arange(len(t))
    out: list[LevelPlan] = []
    finer = np.empty(0, dtype=np.int64)
    for lv in range(l_max, -1, -1):
        lp = _level(t, levels, rank, lv, tile_n, finer)
        out.append(lp)
        finer = lp.codes
    return ChunkPlan(tile_n, l_max, tuple(reversed(out)), levels, order)


def estimated_files(plan: ChunkPlan) -> int:
    """Files a build of ``plan`` writes, about: its chunks (at most), shards, level VRTs, the
    manifest and the sources file (per-shard facts packs and nested sub-VRTs not counted)."""
    return plan.chunks + plan.shards() + (plan.max_level + 1) + 2
