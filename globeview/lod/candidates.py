"""What a traversal hands its policy and gets back: one level's candidate tiles
(`TileCandidates`; with a `LodPolicy.per_tile` policy on the flat walk, the rows of several
levels at once), the tiles drawn (`Selection`), the tree a flat walk visited (`TreeRows`),
and the deepest level a walk visits (`MAX_LEVEL`).

They sit below both `globeview.lod.policy` (the interface a provider implements, which
reads them) and `globeview.lod.traversal` (the walk, which builds them and calls the
policy), so neither of those imports the other's module for its types.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Protocol

import numpy as np

from globeview.lod.culling import LATTICE
from globeview.lod.tile_cache import (
    COL_EAST,
    COL_MARGIN,
    COL_NORTH,
    COL_SOUTH,
    COL_WEST,
)
from globeview.lod.view_state import ViewState
from globeview.terrain.compose.metadata import N_STRIDES
from globeview.terrain.compose.stack import TerrainStack

__all__ = ["MAX_LEVEL", "Selection", "TileCandidates", "TileFacts", "TreeRows", "bend_fractions"]

#: Deepest level the walk goes to even where the data stops (curvature alone).
MAX_LEVEL = 22


def bend_fractions(size: int) -> np.ndarray:
    """(N_STRIDES,) the share of a displacement's bend over a tile (measured across LATTICE-1
    spans of its bounding lattice) that an edge of each stride 1, 2, 4.. spans (at most 1)."""
    return np.minimum(1.0, 2.0 ** np.arange(N_STRIDES) * (LATTICE - 1) / (size - 1))


class TileFacts(Protocol):
    """The per-tile facts a `TileCandidates` reads by slot: a level's table of the tile cache
    (`tile_cache.LevelTiles`) or the flat walk's candidate rows (`flat_walk`)."""

    xy: np.ndarray
    herr: np.ndarray
    finer: np.ndarray
    pts: np.ndarray
    past: np.ndarray
    pole: np.ndarray


@dataclass
class TileCandidates:
    """One level's tiles that passed the frustum and horizon tests, as a policy sees them.

    For a `LodPolicy.per_tile` policy on the flat walk (`globeview.lod.flat_walk`) the rows
    are tiles of several levels at once, some of them not visible (their answers are not
    used): ``level`` is then an (N,) int64 array and ``flat`` is True.

    Arrays are per tile (N,) unless noted; they are the traversal's own (do not write them).

    Attributes:
        view, terrain: the frame's view and terrain.
        level: the quadtree level; ``size`` the tiles' nodes per side.
        dist_m: a lower bound (m, >= 1) of the eye-tile distance (bounding sphere).
        px_per_m: pixels one metre of error covers at that distance (``view.sse_factor /
            dist_m``).
        err_m: (N, N_STRIDES) geometric error (m) of drawing each tile at strides 1, 2, 4..:
            height error x exaggeration + chord sag (+ ``bend_m_strides``); inf where a
            stride exceeds the grid.
        scratch: a dict the policy may use to hand values from `LodPolicy.cull` /
            `LodPolicy.refine` to `LodPolicy.stride` within the level. Arrays in it are per
            tile (first axis N): when `LodPolicy.cull` drops tiles, every array whose first
            axis has length N is cut to the kept rows (anything else is kept as it is).

    Computed on first access and then kept for the level (`functools.cached_property`):
    ``x``, ``y``, ``keys`` (N, 3), ``west``, ``south``, ``east``, ``north`` (degrees),
    ``height_err_m`` (N, N_STRIDES, the store's, not exaggerated), ``has_finer``, ``margin``
    (m), ``bend_m``, ``bend_m_strides``, ``points`` (N, K, 3) the bounding lattice as drawn
    (displaced when displaced), ``points_true`` (never displaced), ``levels_past_data`` (how
    many levels each tile lies below the finest data under it: 0 within the data),
    ``pole`` (`stitching.pole_codes`).
    """

    view: ViewState
    terrain: TerrainStack
    level: int | np.ndarray
    size: int
    _slots: np.ndarray = field(repr=False)
    _cols: np.ndarray = field(repr=False)
    dist_m: np.ndarray
    px_per_m: np.ndarray
    err_m: np.ndarray
    _bend: np.ndarray | None = field(repr=False)
    _bend_strides: np.ndarray | None = field(repr=False)
    _lv: TileFacts = field(repr=False)
    _dpts: np.ndarray | None = field(default=None, repr=False)
    scratch: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self._slots)

    @property
    def flat(self) -> bool:
        """Whether the rows span several levels (``level`` an array: the flat walk)."""
        return isinstance(self.level, np.ndarray)

    @cached_property
    def bend_m(self) -> np.ndarray:
        """(N,) the displacement's bend (m) over each tile's bounding lattice
        (`culling.displacement_bend_m`; zeros without a displacement)."""
        return np.zeros(len(self._slots)) if self._bend is None else self._bend

    @cached_property
    def bend_m_strides(self) -> np.ndarray:
        """(N, N_STRIDES) the bend (m) across an edge of each stride (`bend_fractions`), the
        part of ``err_m`` a displacement adds (zeros without one)."""
        if self._bend_strides is None:
            return np.zeros((len(self._slots), N_STRIDES))
        return self._bend_strides

    @cached_property
    def x(self) -> np.ndarray:
        return self._lv.xy[:, 0].take(self._slots)

    @cached_property
    def y(self) -> np.ndarray:
        return self._lv.xy[:, 1].take(self._slots)

    @cached_property
    def keys(self) -> np.ndarray:
        """(N, 3) int64 rows (level, x, y)."""
        out = np.empty((len(self._slots), 3), dtype=np.int64)
        out[:, 0] = self.level
        out[:, 1:] = self._lv.xy.take(self._slots, axis=0)
        return out

    @property
    def west(self) -> np.ndarray:
        return self._cols[COL_WEST]

    @property
    def east(self) -> np.ndarray:
        return self._cols[COL_EAST]

    @property
    def south(self) -> np.ndarray:
        return self._cols[COL_SOUTH]

    @property
    def north(self) -> np.ndarray:
        return self._cols[COL_NORTH]

    @property
    def margin(self) -> np.ndarray:
        return self._cols[COL_MARGIN]

    @cached_property
    def height_err_m(self) -> np.ndarray:
        return self._lv.herr.take(self._slots, axis=0)

    @cached_property
    def has_finer(self) -> np.ndarray:
        return self._lv.finer.take(self._slots)

    @cached_property
    def points_true(self) -> np.ndarray:
        return self._lv.pts.take(self._slots, axis=0)

    @cached_property
    def levels_past_data(self) -> np.ndarray:
        return self._lv.past.take(self._slots)

    @cached_property
    def pole(self) -> np.ndarray:
        return self._lv.pole.take(self._slots)

    @property
    def points(self) -> np.ndarray:
        return self._dpts if self._dpts is not None else self.points_true


def ancestor_jumps(parent: np.ndarray, level: np.ndarray) -> list[np.ndarray]:
    """Rows of each row's ancestor 1, 2, 4, .. levels up (``parent`` (N,): -1 for a root,
    which is then its own ancestor), as many tables as the levels the rows span need."""
    n = len(parent)
    out = [np.where(parent < 0, np.arange(n), parent)]
    depth = int(level.max() - level.min()) if n else 0
    while (1 << len(out)) < depth:
        out.append(out[-1].take(out[-1]))
    return out


def all_ancestors(flag: np.ndarray, parent: np.ndarray, jumps: list[np.ndarray]) -> np.ndarray:
    """(N,) bool: whether every ancestor of each row (parent, grandparent, .. a root) has
    ``flag`` (True for the roots), by pointer jumping over `ancestor_jumps`: two numpy calls
    a round, log2(depth) rounds, no loop over the levels."""
    acc = flag.take(jumps[0]) | (parent < 0)  # the parent (a root: nothing above)
    for up in jumps:
        # acc covers the d nearest ancestors (d = the jump's distance); so does the
        # ancestor's, d up: together the 2d nearest. A root's acc is True, and a root is
        # its own ancestor, so chains that end sooner stop there.
        acc = acc & acc.take(up)
    return acc


@dataclass
class TreeRows:
    """Rows of a quadtree a flat walk holds (`globeview.lod.flat_walk`), as a
    `LodPolicy.per_tile` policy sees them in `LodPolicy.stop_level` (every candidate row)
    and through `Selection.tree` (the rows visited, level by level in the walk's order).

    Arrays (N,): ``keys`` (N, 3) (level, x, y); ``level``; ``parent`` the row of each tile's
    parent (-1: a root); ``visited`` whether the walk reaches the tile and it is visible;
    ``refine`` whether it refines (`stop_level`: what the policy asked where the level
    allows; `Selection.tree`: what the walk refined); ``scratch`` what the policy left in
    `TileCandidates.scratch`, per row; ``memo`` a dict the policy may keep values in from
    one frame to the next (the selection state's: a provider's own). Through
    `Selection.tree` the rows are level-major, in the walk's order within a level, and
    include candidates not visited (``visited`` False: culled, or below a tile that was not
    refined).
    """

    keys: np.ndarray
    level: np.ndarray
    parent: np.ndarray
    visited: np.ndarray
    refine: np.ndarray
    scratch: dict[str, Any]
    memo: dict[str, Any] = field(default_factory=dict)
    _jumps: list[np.ndarray] | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.level)

    @property
    def jumps(self) -> list[np.ndarray]:
        """Ancestor rows 1, 2, 4, .. levels up (a root is its own ancestor), as many as the
        levels the rows span need (`ancestor_jumps`; the walk may hand its own)."""
        if self._jumps is None:
            self._jumps = ancestor_jumps(self.parent, self.level)
        return self._jumps

    def all_ancestors(self, flag: np.ndarray) -> np.ndarray:
        """(N,) bool: whether every ancestor of each row (parent, grandparent, ... a root)
        has ``flag`` (True for the roots), by pointer jumping: log2(depth) rounds of two
        numpy calls, no loop over the levels."""
        return all_ancestors(flag, self.parent, self.jumps)


@dataclass
class Selection:
    """What a traversal drew: ``keys`` (N, 3) (level, x, y), each tile's ``stride_idx``
    (stride = 2**stride_idx) and ``error_px`` (the policy's projected error at that stride),
    and the cull counts. From the flat walk also ``tree``: called, it returns the
    `TreeRows` visited (None from the level-by-level walk)."""

    keys: np.ndarray
    stride_idx: np.ndarray
    error_px: np.ndarray
    culled_frustum: int = 0
    culled_horizon: int = 0
    tree: Callable[[], TreeRows] | None = None
