"""Block patterns' index lists (`globeview.lod.block_indices`, issue #27 item 3): a pattern
checked by hand, watertightness over random patterns (every interior edge shared by exactly
two triangles, no vertex on another triangle's edge, the tile covered once, every border
segment with its skirt), counts, and `RenderSet.validate` of block strides. No GL."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.lod.block_indices import BLOCKS, pattern_counts, pattern_indices
from globeview.lod.render_set import InvalidRenderSet, RenderSet
from globeview.lod.tile_indices import IndexVariant, grid_indices

SIZE = 65
N = SIZE - 1
BASE = SIZE * SIZE  # first skirt vertex


def _node(r: int, c: int) -> int:
    return r * SIZE + c


def _split(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(grid triangles (T, 3), skirt triangles (S, 3)) of one tile's list."""
    tris = idx.reshape(-1, 3).astype(np.int64)
    skirt = (tris >= BASE).any(axis=1)
    return tris[~skirt], tris[skirt]


def test_two_block_pattern_by_hand() -> None:
    """Block (0, 0) at stride 4, all others at 8: its east and south edges are drawn at 8
    (the middle nodes (4, 8) and (8, 4) are left out), so it is six triangles; the 63 others
    two each; skirts: one segment per block edge at 8, two for block (0, 0)'s at 4."""
    pattern = np.full((1, BLOCKS, BLOCKS), 3, dtype=np.int8)
    pattern[0, 0, 0] = 2
    idx, bounds = pattern_indices(SIZE, pattern)
    assert bounds.tolist() == [0, len(idx)]
    grid, skirt = _split(idx)
    in_block = (grid // SIZE <= 8).all(axis=1) & (grid % SIZE <= 8).all(axis=1)
    got = {tuple(sorted(t)) for t in grid[in_block].tolist()}
    want = {
        tuple(sorted(_node(r, c) for r, c in tri))
        for tri in (
            ((0, 0), (4, 0), (0, 4)),
            ((0, 4), (4, 0), (4, 4)),
            ((0, 4), (4, 4), (0, 8)),
            ((4, 0), (8, 0), (4, 4)),
            ((4, 4), (8, 0), (8, 8)),
            ((4, 4), (0, 8), (8, 8)),
        )
    }
    assert got == want
    assert len(grid) == 6 + 63 * 2
    # North and west: 2 segments for block (0, 0) and 7 others; south and east: 8.
    assert len(skirt) == 2 * (9 + 9 + 8 + 8)
    assert pattern_counts(SIZE, pattern).tolist() == [len(idx)] == [3 * 200]


def test_uniform_patterns_are_the_variants() -> None:
    """A pattern of one stride draws exactly the tile's variant at that stride."""
    for k in range(4):
        idx, _ = pattern_indices(SIZE, np.full((1, BLOCKS, BLOCKS), k, dtype=np.int8))
        ref = grid_indices(SIZE, IndexVariant(stride=1 << k))
        assert _tri_set(idx) == _tri_set(ref), k
        assert len(idx) == len(ref)


def _tri_set(idx: np.ndarray) -> set[tuple[int, ...]]:
    return {tuple(sorted(t)) for t in idx.reshape(-1, 3).tolist()}


def _check_watertight(idx: np.ndarray) -> None:
    grid, skirt = _split(idx)
    r, c = grid // SIZE, grid % SIZE
    # No degenerate triangle, and the tile's square covered exactly once (areas add up to it
    # and no edge is shared by more than two triangles: no overlap, no hole).
    area = 0.5 * np.abs(
        (r[:, 1] - r[:, 0]) * (c[:, 2] - c[:, 0]) - (r[:, 2] - r[:, 0]) * (c[:, 1] - c[:, 0])
    )
    assert (area > 0).all()
    assert area.sum() == N * N
    edges = np.sort(np.concatenate([grid[:, [0, 1]], grid[:, [1, 2]], grid[:, [0, 2]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    er, ec = uniq // SIZE, uniq % SIZE
    on_border = (er == 0).all(1) | (er == N).all(1) | (ec == 0).all(1) | (ec == N).all(1)
    assert (count[~on_border] == 2).all(), "an interior edge not shared by exactly two"
    assert (count[on_border] == 1).all()
    # No T-junction: no vertex of the triangulation strictly inside any edge.
    verts = np.unique(grid)
    vr, vc = verts // SIZE, verts % SIZE
    r0, c0, r1, c1 = er[:, 0], ec[:, 0], er[:, 1], ec[:, 1]
    cross = (r1 - r0)[:, None] * (vc - c0[:, None]) - (c1 - c0)[:, None] * (vr - r0[:, None])
    dot = (vr - r0[:, None]) * (r1 - r0)[:, None] + (vc - c0[:, None]) * (c1 - c0)[:, None]
    length2 = ((r1 - r0) ** 2 + (c1 - c0) ** 2)[:, None]
    inside = (cross == 0) & (dot > 0) & (dot < length2)
    assert not inside.any(), "a vertex lies on another triangle's edge (T-junction)"
    # Every border segment of the grid has its skirt quad (two triangles on its two nodes).
    border = {tuple(e) for e in uniq[on_border].tolist()}
    tops = np.where(skirt < BASE, skirt, -1)
    skirt_edges = {tuple(sorted(t[t >= 0].tolist())) for t in tops if (t >= 0).sum() == 2}
    assert skirt_edges == border
    assert len(skirt) == 2 * len(border)


def test_random_patterns_are_watertight() -> None:
    rng = np.random.default_rng(27)
    patterns = rng.integers(0, 4, size=(6, BLOCKS, BLOCKS)).astype(np.int8)
    # Also smooth ones (neighbours differ by one level), as views choose them.
    ramp = (np.add.outer(np.arange(BLOCKS), np.arange(BLOCKS)) // 4).clip(0, 3)
    patterns = np.concatenate([patterns, ramp[None].astype(np.int8)])
    idx, bounds = pattern_indices(SIZE, patterns)
    counts = pattern_counts(SIZE, patterns)
    assert np.array_equal(np.diff(bounds), counts)
    for i in range(len(patterns)):
        _check_watertight(idx[bounds[i] : bounds[i + 1]])


def test_bad_stride_index_is_refused() -> None:
    with pytest.raises(ValueError, match=r"0\.\.3"):
        pattern_counts(SIZE, np.full((1, BLOCKS, BLOCKS), 4, dtype=np.int8))


def _set(keys: list[list[int]], blocks: np.ndarray | None) -> RenderSet:
    return RenderSet(
        np.array(keys), np.zeros(len(keys), np.int64), [IndexVariant()], block_strides=blocks
    )


def test_render_set_counts_and_validates_block_strides() -> None:
    keys = [[5, 3, 7], [5, 4, 7]]
    blocks = np.full((2, BLOCKS, BLOCKS), -1, dtype=np.int8)
    blocks[1] = 3
    rs = _set(keys, blocks)
    rs.validate(SIZE)
    full = len(grid_indices(SIZE, IndexVariant()))
    assert rs.index_counts(SIZE).tolist() == [full, len(grid_indices(SIZE, IndexVariant(8)))]
    bad = blocks.copy()
    bad[1, 0, 0] = -1  # part of a tile
    with pytest.raises(InvalidRenderSet, match=r"all -1 or all 0\.\.3"):
        _set(keys, bad).validate(SIZE)
    with pytest.raises(InvalidRenderSet, match="int8"):
        _set(keys, blocks.astype(np.int64)).validate(SIZE)
    with pytest.raises(InvalidRenderSet, match="pole tile"):
        _set([[5, 3, 0], [5, 4, 0]], blocks).validate(SIZE)
    with pytest.raises(InvalidRenderSet, match="block_tau_px"):
        RenderSet(
            np.array(keys), np.zeros(2, np.int64), [IndexVariant()], block_tau_px=-1.0
        ).validate(SIZE)
