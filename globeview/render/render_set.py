"""What an LOD provider hands the renderer each frame, and what the renderer reports back."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from globeview.render.tile_indices import IndexVariant


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
    """

    keys: np.ndarray
    variant_ids: np.ndarray
    variants: list[IndexVariant]
    custom_indices: dict[int, np.ndarray] = field(default_factory=dict)
    error_px: np.ndarray | None = None
    stats: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.keys = np.asarray(self.keys, dtype=np.int64).reshape(-1, 3)
        self.variant_ids = np.asarray(self.variant_ids, dtype=np.int64).reshape(-1)
        if len(self.variant_ids) != len(self.keys):
            raise ValueError("one variant id per tile")

    def __len__(self) -> int:
        return len(self.keys)

    @classmethod
    def empty(cls) -> RenderSet:
        return cls(np.empty((0, 3), np.int64), np.empty(0, np.int64), [])


@dataclass
class FrameStats:
    """Figures of one rendered frame (what `globeview render --stats` writes)."""

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

    def as_dict(self) -> dict[str, float | int | str]:
        d = {k: v for k, v in self.__dict__.items() if k != "extra"}
        d.update(self.extra)
        return d
