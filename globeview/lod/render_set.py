"""What an LOD provider hands the renderer each frame, and what the renderer reports back.

`RenderSet.validate` is the host's check at the plugin boundary: a provider's render set is
validated every frame before the renderer touches it (vectorised numpy, a few tens of
microseconds for a full frame), so garbage from a plugin fails that plugin instead of the
renderer.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from numbers import Real
from typing import cast

import numpy as np

from globeview.lod.block_indices import BLOCK_CELLS, BLOCKS, N_BLOCK_STRIDES, pattern_counts
from globeview.lod.tile_indices import IndexVariant, index_count

#: Deepest quadtree level a key may have: the tile pool packs keys into int64 codes with
#: x, y < 2^29 (tile_pool.key_codes), and level 28 has 2^29 columns.
MAX_KEY_LEVEL = 28
#: Most tiles one render set may hold: 21x the GPU pool's default 768 slots (a set larger
#: than the pool is drawn coarser, see renderer.py, which costs about 2 s a frame for 65 536
#: tiles on llvmpipe), and 16 384 tiles of 65^2 nodes are 69 million vertices, more than
#: any sane frame. Bounds what a buggy provider (10^7 keys) can cost the frame.
MAX_TILES = 16_384
#: Most distinct index variants per render set (each is built once and cached on the GPU).
MAX_VARIANTS = 1024
#: Stats the renderer reads as numbers.
_NUMERIC_STATS = ("lod_ms", "tiles_culled_frustum", "tiles_culled_horizon")
_POLES = (None, "north", "south", "both")


class InvalidRenderSet(ValueError):
    """A render set an LOD provider returned is malformed (one-line message saying what)."""


@dataclass
class RenderSet:
    """The tiles to draw this frame and how to triangulate each.

    Attributes:
        keys: (N, 3) int64 rows (level, x, y) of tiles on the ellipsoidal quadtree.
        variant_ids: (N,) int index into ``variants`` for each tile: which shared index
            buffer (stride, skirts, pole fan, stitched edges) draws it.
        variants: the distinct index variants used.
        custom_indices: optional per-tile triangle lists (uint32, over the tile's vertex
            layout, see tile_mesh.py) for providers that triangulate each tile themselves;
            maps row number in ``keys`` -> indices, and overrides ``variant_ids`` there.
        error_px: (N,) the screen-space error (pixels) each tile is drawn with, as the
            provider estimated it; the frame's max goes to the stats.
        stats: provider counters for the frame (e.g. tiles culled by frustum / horizon).
        block_strides: optional (N, 8, 8) int8 stride index (0..3: strides 1, 2, 4, 8) of
            each 8 x 8-cell block of a 65-node tile (row 0 the northern blocks), or -1 in
            every block of a row drawn by its variant as before. A row with block strides is
            drawn with the blocks' triangulation (`globeview.lod.block_indices`: edges
            between blocks at the larger stride, skirts on all four tile edges at the edge
            blocks' strides) instead of its variant; pole tiles may not have them.
        block_tau_px: optional tau (pixels) under which the renderer chooses the block
            strides of the set's resident tiles itself (`lod.block_strides`, from the blocks'
            errors it measured when it built them) where ``block_strides`` is None: the
            default provider's request; None: none chosen (every row drawn by its variant).

    What a render set promises, and what the host checks (the plugin contract):

    - The host checks every set with `validate` before drawing (shapes, key ranges,
      variants, custom index lists, ``error_px``, the numeric stats); a set that fails fails
      the provider's contribution and the frame is drawn by chunked-sse instead.
    - It should be a *cut* of the quadtree: no tile twice, and no tile together with one of
      its ancestors. The host does not check this (it would cost a sort per frame); tiles
      that overlap are all drawn and z-fight where their surfaces differ.
    - It need not cover the globe: a region without a tile is simply not drawn (culled
      tiles are left out), and the order of the rows does not matter (the renderer sorts
      by distance).
    - Cracks between neighbours of different levels or strides are the provider's to hide:
      skirts (`IndexVariant` has them by default) or stitched ``edge_strides``.
    - The host never writes into a set, so a provider may hand out a cached one again; it
      may draw a transformed copy: coarser when the set exceeds the GPU pool (siblings
      replaced by their parent, stat ``tiles_coarsened``), or with loaded ancestors standing
      in for tiles still loading. Both keep a cut a cut.
    """

    keys: np.ndarray
    variant_ids: np.ndarray
    variants: list[IndexVariant]
    custom_indices: dict[int, np.ndarray] = field(default_factory=dict)
    error_px: np.ndarray | None = None
    stats: dict[str, float] = field(default_factory=dict)
    block_strides: np.ndarray | None = None
    block_tau_px: float | None = None

    def __post_init__(self) -> None:
        keys = _as_int64(self.keys, "keys")
        if keys.size == 0:
            keys = keys.reshape(0, 3)
        elif keys.ndim != 2 or keys.shape[1] != 3:
            raise ValueError(f"keys must be (N, 3) rows (level, x, y), not shape {keys.shape}")
        self.keys = keys
        self.variant_ids = _as_int64(self.variant_ids, "variant_ids").reshape(-1)
        if len(self.variant_ids) != len(self.keys):
            raise ValueError("one variant id per tile")

    def __len__(self) -> int:
        return len(self.keys)

    @classmethod
    def empty(cls) -> RenderSet:
        return cls(np.empty((0, 3), np.int64), np.empty(0, np.int64), [])

    def index_counts(self, tile_size: int) -> np.ndarray:
        """(N,) int64 indices each tile is drawn with (3 per triangle): its variant's over a
        tile of ``tile_size`` nodes per side, or its ``custom_indices`` list. The renderer
        draws exactly these (`GlobeRenderer.draw_terrain`), so the frame's ``triangles``
        stat is ``index_counts(size).sum() // 3``. The set must be valid (`validate`)."""
        per_variant = np.array(
            [index_count(int(tile_size), v) for v in self.variants], dtype=np.int64
        )
        counts = per_variant[self.variant_ids] if len(self) else np.empty(0, np.int64)
        if self.block_strides is not None and len(self):
            rows = np.flatnonzero(self.block_strides[:, 0, 0] >= 0)
            if len(rows):
                counts = counts.copy()
                counts[rows] = pattern_counts(int(tile_size), self.block_strides[rows])
        if self.custom_indices:
            counts = counts.copy()
            for row, idx in self.custom_indices.items():
                counts[int(row)] = len(idx)
        return counts

    def triangles(self, tile_size: int) -> int:
        """Triangles the renderer draws for this set over tiles of ``tile_size`` nodes per
        side (skirts included, as the frame stats count them)."""
        return int(self.index_counts(tile_size).sum() // 3)

    def validate(self, tile_size: int, verts_per_tile: int | None = None) -> None:
        """Raise `InvalidRenderSet` unless the renderer can draw this set safely.

        Checks (all vectorised over the tiles): ``keys`` an (N, 3) integer array with
        N <= `MAX_TILES`, level in 0..`MAX_KEY_LEVEL`, x in [0, 2^(level+1)), y in
        [0, 2^level); ``variant_ids`` (N,) integers indexing ``variants``; every variant an
        `IndexVariant` whose stride (and edge strides, multiples of it) divides the tile's
        ``tile_size - 1`` cells, with a known pole; ``custom_indices`` rows in [0, N) holding
        1-D integer triangle lists (a multiple of 3 long) within the tile's
        ``verts_per_tile`` vertices; ``error_px`` None or (N,) real numbers, not NaN;
        ``stats`` a dict whose renderer-read entries are finite numbers; ``block_strides``
        None or (N, 8, 8) int8 in -1..3 with each row all -1 or all 0..3, none on a pole
        tile, and tiles of 65 nodes; ``block_tau_px`` None or a positive finite number.
        """
        n_cells = tile_size - 1
        keys, ids = self.keys, self.variant_ids
        if not isinstance(keys, np.ndarray) or keys.ndim != 2 or keys.shape[1:] != (3,):
            raise InvalidRenderSet(f"keys must be an (N, 3) array, not {_describe(keys)}")
        n = keys.shape[0]
        if n > MAX_TILES:
            raise InvalidRenderSet(f"{n} tiles, more than the {MAX_TILES} a frame may have")
        if keys.dtype.kind not in "iu":
            raise InvalidRenderSet(f"keys must be integers, not {keys.dtype}")
        if not isinstance(ids, np.ndarray) or ids.shape != (n,) or ids.dtype.kind not in "iu":
            raise InvalidRenderSet(
                f"variant_ids must be ({n},) integers (one per tile), not {_describe(ids)}"
            )
        variants = self.variants
        if not isinstance(variants, list | tuple):
            raise InvalidRenderSet(f"variants must be a list, not {type(variants).__name__}")
        if len(variants) > MAX_VARIANTS:
            raise InvalidRenderSet(f"{len(variants)} index variants (at most {MAX_VARIANTS})")
        if n:
            level, x, y = keys[:, 0].astype(np.int64), keys[:, 1], keys[:, 2]
            bad = (level < 0) | (level > MAX_KEY_LEVEL)
            if bad.any():
                i = int(np.argmax(bad))
                raise InvalidRenderSet(
                    f"tile {i}: level {int(keys[i, 0])} outside 0..{MAX_KEY_LEVEL}"
                )
            rows = np.left_shift(1, level)
            bad = (x < 0) | (x >= 2 * rows) | (y < 0) | (y >= rows)
            if bad.any():
                i = int(np.argmax(bad))
                lv, kx, ky = (int(v) for v in keys[i])
                raise InvalidRenderSet(
                    f"tile {i}: ({lv}, {kx}, {ky}) outside level {lv}'s {2 << lv} x {1 << lv} tiles"
                )
            lo, hi = int(ids.min()), int(ids.max())
            if lo < 0 or hi >= len(variants):
                raise InvalidRenderSet(
                    f"variant id {lo if lo < 0 else hi} does not index the {len(variants)} variants"
                )
        for v in variants:
            _check_variant(v, n_cells)
        self._validate_custom(n, verts_per_tile)
        self._validate_blocks(n, n_cells)
        err = self.error_px
        if err is not None:
            if not isinstance(err, np.ndarray) or err.shape != (n,) or err.dtype.kind not in "iuf":
                raise InvalidRenderSet(f"error_px must be ({n},) numbers, not {_describe(err)}")
            if np.isnan(err).any():
                raise InvalidRenderSet("error_px holds NaN")
        if not isinstance(self.stats, dict):
            raise InvalidRenderSet(f"stats must be a dict, not {type(self.stats).__name__}")
        for k in _NUMERIC_STATS:
            stat = self.stats.get(k, 0.0)
            if not isinstance(stat, Real) or isinstance(stat, bool) or not math.isfinite(stat):
                raise InvalidRenderSet(f"stats[{k!r}] must be a finite number, not {stat!r:.40}")

    def _validate_blocks(self, n: int, n_cells: int) -> None:
        tau = self.block_tau_px
        if tau is not None and (
            not isinstance(tau, Real) or isinstance(tau, bool) or not 0.0 < tau < math.inf
        ):
            raise InvalidRenderSet(f"block_tau_px must be a positive number, not {tau!r:.40}")
        bs = self.block_strides
        if bs is None:
            return
        shape = (n, BLOCKS, BLOCKS)
        if not isinstance(bs, np.ndarray) or bs.shape != shape or bs.dtype != np.int8:
            raise InvalidRenderSet(f"block_strides must be {shape} int8, not {_describe(bs)}")
        if not n:
            return
        flat = bs.reshape(n, -1)
        lo, hi = flat.min(axis=1), flat.max(axis=1)
        bad = (lo < -1) | (hi >= N_BLOCK_STRIDES) | ((lo < 0) & (hi >= 0))
        if bad.any():
            i = int(np.argmax(bad))
            raise InvalidRenderSet(
                f"tile {i}: block strides must be all -1 or all 0..{N_BLOCK_STRIDES - 1}"
            )
        patterned = hi >= 0
        if patterned.any() and n_cells != BLOCKS * BLOCK_CELLS:
            raise InvalidRenderSet(f"block strides need tiles of {BLOCKS * BLOCK_CELLS} cells")
        y, rows = self.keys[:, 2], np.left_shift(1, self.keys[:, 0].astype(np.int64))
        pole = patterned & ((y == 0) | (y == rows - 1))
        if pole.any():
            raise InvalidRenderSet(f"tile {int(np.argmax(pole))}: a pole tile has block strides")

    def _validate_custom(self, n: int, verts_per_tile: int | None) -> None:
        custom = self.custom_indices
        if not isinstance(custom, dict):
            raise InvalidRenderSet(f"custom_indices must be a dict, not {type(custom).__name__}")
        if not custom:
            return
        if len(custom) > n:
            raise InvalidRenderSet(f"{len(custom)} custom index lists for {n} tiles")
        chunks = []
        for row, idx in custom.items():
            if not isinstance(row, int | np.integer) or not 0 <= row < n:
                raise InvalidRenderSet(f"custom_indices row {row!r:.40} is not a tile 0..{n - 1}")
            if not isinstance(idx, np.ndarray) or idx.ndim != 1 or idx.dtype.kind not in "iu":
                raise InvalidRenderSet(
                    f"custom_indices[{row}] must be a 1-D integer array, not {_describe(idx)}"
                )
            if len(idx) % 3:
                raise InvalidRenderSet(f"custom_indices[{row}] length {len(idx)} is not 3k")
            chunks.append(idx)
        both = np.concatenate(chunks) if chunks else np.empty(0, np.int64)
        if len(both) and (
            int(both.min()) < 0
            or (verts_per_tile is not None and int(both.max()) >= verts_per_tile)
        ):
            raise InvalidRenderSet(
                f"custom_indices outside the tile's {verts_per_tile} vertices "
                f"({int(both.min())}..{int(both.max())})"
            )


def _as_int64(values: object, name: str) -> np.ndarray:
    """``values`` as an int64 array; ValueError for non-integral numbers (NaN, 2.5) and for
    non-numbers, instead of numpy's silent cast (NaN becomes -2^63 with a RuntimeWarning)."""
    a = np.asarray(values)
    if a.dtype.kind in "iu":
        return a.astype(np.int64, copy=False)
    if a.dtype.kind == "b" or (a.size == 0 and a.dtype.kind == "f"):
        return a.astype(np.int64)
    if a.dtype.kind == "f":
        if not np.isfinite(a).all() or (a != np.round(a)).any() or np.abs(a).max() >= 2**62:
            raise ValueError(f"{name} must be integers, not values such as NaN or 2.5")
        return a.astype(np.int64)
    raise ValueError(f"{name} must be integers, not {a.dtype}")


def _describe(a: object) -> str:
    """A short description of what a provider handed over, for messages."""
    if isinstance(a, np.ndarray):
        return f"a {a.dtype} array of shape {a.shape}"
    return type(a).__name__


def _check_variant(v: object, n_cells: int) -> None:
    """Raise InvalidRenderSet unless ``v`` is an IndexVariant the tile can be drawn with."""
    if not isinstance(v, IndexVariant):
        raise InvalidRenderSet(f"a variant is a {type(v).__name__}, not an IndexVariant")
    s = v.stride
    if not isinstance(s, int | np.integer) or isinstance(s, bool) or s < 1 or n_cells % s:
        raise InvalidRenderSet(f"stride {s!r:.40} does not divide the tile's {n_cells} cells")
    if v.pole not in _POLES:
        raise InvalidRenderSet(f"pole {v.pole!r:.40} is not one of {_POLES}")
    if v.edge_strides is not None:
        es = v.edge_strides
        if not isinstance(es, tuple) or len(es) != 4:
            raise InvalidRenderSet(f"edge_strides {es!r:.60} is not 4 strides")
        for e in es:
            ok = isinstance(e, int | np.integer) and not isinstance(e, bool)
            if not ok or e < 1 or e % s or n_cells % e:
                raise InvalidRenderSet(
                    f"edge stride {e!r:.40} is not a multiple of stride {s} dividing "
                    f"{n_cells} cells"
                )
    flags = v.skirt_edges
    if flags is not None and (
        not isinstance(flags, tuple) or len(flags) != 4 or not all(type(f) is bool for f in flags)
    ):
        raise InvalidRenderSet(f"skirt_edges {flags!r:.60} is not 4 bools")
    try:
        hash(v)  # the index pool caches variants by value
    except TypeError as exc:
        raise InvalidRenderSet(f"variant is not hashable ({exc})") from None


#: Most entries of a provider's ``RenderSet.stats`` passed on to ``--stats`` and the window
#: (a hostile provider hands over 10^6 keys); longest key and text value kept.
MAX_PROVIDER_STATS = 64
MAX_STAT_KEY_CHARS = 64
MAX_STAT_TEXT_CHARS = 200
#: Most entries looked at to find the kept ones.
MAX_STATS_EXAMINED = 1024


def clean_provider_stats(stats: object) -> tuple[dict[str, float | int | bool | str], int]:
    """A provider's free-form ``RenderSet.stats`` made safe to print and write as JSON:
    at most `MAX_PROVIDER_STATS` entries with string keys (clipped), each a bool, an integer,
    a finite float or a short string (clipped); numpy scalars become Python ones. Returns
    (the kept entries, how many were dropped). Never raises: whatever a plugin's dict does,
    the frame goes on (everything counts as dropped then)."""
    total = dict.__len__(stats) if isinstance(stats, dict) else 0  # C-level: cannot raise
    try:
        kept: dict[str, float | int | bool | str] = {}
        # Look at a bounded number of entries: 10^6 garbage values must not cost each frame.
        items = dict.items(stats) if isinstance(stats, dict) else ()
        for k, v in itertools.islice(items, MAX_STATS_EXAMINED):
            if len(kept) >= MAX_PROVIDER_STATS:
                break
            if type(k) is not str:  # exactly str: a subclass could run code in __str__
                continue
            value = _json_scalar(v)
            if value is not None:
                kept[k[:MAX_STAT_KEY_CHARS]] = value
        return kept, total - len(kept)
    except Exception:  # noqa: BLE001  plugin data: drop it, never fail the frame
        return {}, total


def _json_scalar(v: object) -> float | int | bool | str | None:
    """``v`` as a JSON scalar, or None when it is not one (or not finite)."""
    if isinstance(v, np.generic):
        v = v.item()
    # Exact types (type(v) is ...): a subclass (an IntEnum, a str subclass) is no JSON scalar.
    t = type(v)
    if t is bool:
        return cast(bool, v)
    if t is int:
        return cast(int, v) if abs(cast(int, v)) < 2**63 else None
    if t is float:
        return cast(float, v) if math.isfinite(cast(float, v)) else None
    if t is str:
        return cast(str, v)[:MAX_STAT_TEXT_CHARS]
    return None


def level_histogram(keys: np.ndarray) -> dict[str, int]:
    """How many tiles of each quadtree level a frame drew: ``{"7": 12, "8": 30}`` (JSON
    object keys are strings), levels ascending."""
    if len(keys) == 0:
        return {}
    levels, counts = np.unique(np.asarray(keys)[:, 0], return_counts=True)
    return {str(int(lv)): int(c) for lv, c in zip(levels, counts, strict=True)}


@dataclass
class FrameStats:
    """Figures of one rendered frame (what `globeview render --stats` writes).

    Besides the host's own figures: ``levels``, the drawn tiles per quadtree level, and
    ``provider_stats``, the LOD provider's own ``RenderSet.stats`` (cleaned, see
    `clean_provider_stats`; ``provider_stats_dropped`` entries were not JSON scalars or past
    the limit). `as_dict` namespaces them under ``"provider"`` so a plugin's counter can
    never overwrite a host figure.
    """

    triangles: int = 0
    tiles_drawn: int = 0
    tiles_culled_frustum: int = 0
    tiles_culled_horizon: int = 0
    tiles_loading: int = 0
    tiles_uploaded: int = 0
    lod_ms: float = 0.0
    draw_ms: float = 0.0
    frame_ms: float = 0.0
    max_sse_px: float = 0.0
    lod_provider: str = ""
    extra: dict[str, float] = field(default_factory=dict)
    levels: dict[str, int] = field(default_factory=dict)
    provider_stats: dict[str, float | int | bool | str] = field(default_factory=dict)
    provider_stats_dropped: int = 0

    def as_dict(self) -> dict[str, object]:
        """The figures as a JSON-able dict: the host's figures and ``extra`` at the top level,
        ``"levels": {"7": 12, ...}`` and ``"provider": {"name": ..., "stats": {...}}`` (plus
        ``"stats_dropped": n`` when entries were dropped)."""
        nested = ("extra", "levels", "provider_stats", "provider_stats_dropped")
        d: dict[str, object] = {k: v for k, v in self.__dict__.items() if k not in nested}
        d.update(self.extra)
        d["levels"] = dict(self.levels)
        provider: dict[str, object] = {
            "name": self.lod_provider,
            "stats": dict(self.provider_stats),
        }
        if self.provider_stats_dropped:
            provider["stats_dropped"] = self.provider_stats_dropped
        d["provider"] = provider
        return d
