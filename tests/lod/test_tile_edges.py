"""Tile edges of the default provider's sets stitched to same-level neighbours instead of
skirted (`globeview.lod.stitching.stitch_tile_edges`, issue #27 item 3): both tiles draw
the same nodes along a shared edge (no crack without a skirt), the edge has no skirt on
either side, and every edge that cannot be stitched (another level, a pole, a pattern
beside a variant coarser than a block) keeps its skirts. Index lists only, no GL."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.lod.block_indices import BLOCKS, SKIRTED, pattern_counts, pattern_indices
from globeview.lod.render_set import InvalidRenderSet, RenderSet
from globeview.lod.stitching import TileEdges, stitch_tile_edges
from globeview.lod.tile_indices import IndexVariant, grid_indices

SIZE = 65
N = SIZE - 1
BASE = SIZE * SIZE  # first skirt vertex
NORTH, SOUTH, WEST, EAST = range(4)


def _set(keys: list[tuple[int, int, int]], strides: list[int]) -> RenderSet:
    """A default-provider set: plain variants with skirts, blocks chosen by the renderer."""
    uniq = sorted(set(strides))
    variants = [IndexVariant(stride=s) for s in uniq]
    ids = np.array([uniq.index(s) for s in strides], dtype=np.int64)
    return RenderSet(np.array(keys, dtype=np.int64), ids, variants, block_tau_px=2.0)


def _blocks(n: int, rows: dict[int, np.ndarray]) -> np.ndarray:
    out = np.full((n, BLOCKS, BLOCKS), -1, dtype=np.int8)
    for i, b in rows.items():
        out[i] = b
    return out


def _lists(rs: RenderSet, te: TileEdges) -> list[np.ndarray]:
    """Each tile's index list as the renderer draws it."""
    out = []
    for i in range(len(rs)):
        if te.blocks[i, 0, 0] >= 0:
            idx, _ = pattern_indices(SIZE, te.blocks[i : i + 1], te.edges[i : i + 1])
        else:
            idx = grid_indices(SIZE, te.variants[int(te.variant_ids[i])])
        out.append(idx.reshape(-1, 3).astype(np.int64))
    return out


def _edge_nodes(tris: np.ndarray, edge: int) -> list[int]:
    """Positions (column for north/south, row for west/east) of the nodes the grid
    triangles use on one edge of the tile."""
    grid = tris[(tris < BASE).all(axis=1)].reshape(-1)
    r, c = grid // SIZE, grid % SIZE
    on = (r == 0, r == N, c == 0, c == N)[edge]
    along = c if edge in (NORTH, SOUTH) else r
    return sorted(set(along[on].tolist()))


def _skirted(tris: np.ndarray, edge: int) -> bool:
    """Whether the tile's list has skirt triangles on ``edge`` (skirt vertices of edge k are
    BASE + k * SIZE ..)."""
    sk = tris[tris >= BASE]
    return bool(((sk - BASE) // SIZE == edge).any())


def _ramp() -> np.ndarray:
    return (np.add.outer(np.arange(BLOCKS), np.arange(BLOCKS)) // 4).clip(0, 3).astype(np.int8)


def test_patterns_side_by_side_share_their_edge_nodes_and_drop_its_skirts() -> None:
    """A west of B, both patterned, with different edge blocks: each edge block is drawn at
    the larger stride by both, without skirts; the other edges keep theirs."""
    a = _ramp()
    b = np.full((BLOCKS, BLOCKS), 1, dtype=np.int8)
    b[:, 0] = [0, 3, 1, 2, 0, 0, 3, 1]
    rs = _set([(6, 10, 20), (6, 11, 20)], [1, 1])
    te = stitch_tile_edges(rs, _blocks(2, {0: a, 1: b}))
    la, lb = _lists(rs, te)
    assert _edge_nodes(la, EAST) == _edge_nodes(lb, WEST)
    want = np.maximum(a[:, -1], b[:, 0])
    assert te.edges[0, EAST].tolist() == te.edges[1, WEST].tolist() == want.tolist()
    assert not _skirted(la, EAST) and not _skirted(lb, WEST)
    for edge in (NORTH, SOUTH, WEST):
        assert _skirted(la, edge)
        assert te.edges[0, edge].tolist() == [SKIRTED] * BLOCKS
    assert te.index_counts(rs, SIZE).tolist() == [len(la) * 3, len(lb) * 3]


def test_variants_share_the_coarser_stride_and_drop_the_skirt() -> None:
    """Whole tiles at strides 16 and 32 one above the other (and across the antimeridian):
    the shared edge at 32 by both, no skirt there."""
    last = (2 << 6) - 1
    rs = _set([(6, 3, 20), (6, 3, 21), (6, last, 21), (6, 0, 21)], [16, 32, 16, 64])
    te = stitch_tile_edges(rs, None)
    lists = _lists(rs, te)
    assert (te.blocks[:, 0, 0] < 0).all()
    assert _edge_nodes(lists[0], SOUTH) == _edge_nodes(lists[1], NORTH) == [0, 32, 64]
    assert not _skirted(lists[0], SOUTH) and not _skirted(lists[1], NORTH)
    assert _skirted(lists[0], NORTH) and _skirted(lists[1], SOUTH)
    # Across the antimeridian: x = last is the west neighbour of x = 0.
    assert _edge_nodes(lists[2], EAST) == _edge_nodes(lists[3], WEST) == [0, 64]
    assert not _skirted(lists[2], EAST) and not _skirted(lists[3], WEST)


def test_a_variant_beside_a_pattern_becomes_a_uniform_pattern() -> None:
    """A whole tile at stride 4 beside a patterned one is drawn as a pattern of stride 4
    (the same triangles) so that its edge follows the neighbour's blocks."""
    rs = _set([(6, 10, 20), (6, 10, 21)], [2, 4])
    te = stitch_tile_edges(rs, _blocks(2, {0: _ramp()}))
    assert (te.blocks[1] == 2).all()
    la, lb = _lists(rs, te)
    assert _edge_nodes(la, SOUTH) == _edge_nodes(lb, NORTH)
    assert not _skirted(la, SOUTH) and not _skirted(lb, NORTH)
    # Unstitched, the uniform pattern is the variant.
    alone = pattern_counts(SIZE, te.blocks[1:2])
    assert alone.tolist() == [len(grid_indices(SIZE, IndexVariant(stride=4)))]


@pytest.mark.parametrize(
    ("keys", "strides"),
    [
        ([(6, 10, 20), (6, 11, 20)], [1, 16]),  # a pattern beside a variant past a block
        ([(6, 10, 20), (7, 22, 40)], [1, 1]),  # another level
        ([(6, 10, 0), (6, 11, 0)], [1, 1]),  # pole tiles (their own variants)
    ],
)
def test_edges_that_cannot_be_stitched_keep_their_skirts(keys, strides) -> None:
    rs = _set(keys, strides)
    if keys[0][2] == 0:  # pole tiles are drawn with pole fans
        rs = RenderSet(
            rs.keys, np.zeros(2, np.int64), [IndexVariant(pole="north")], block_tau_px=2.0
        )
        blocks = None
    else:
        blocks = _blocks(2, {0: _ramp()})
    te = stitch_tile_edges(rs, blocks)
    for tris in _lists(rs, te):
        for edge in (SOUTH, WEST, EAST):
            assert _skirted(tris, edge)


def test_stitched_patterns_are_watertight_inside() -> None:
    """A pattern with stitched tile edges covers its square once with no T-junction (the
    stitched edge blocks' fans), and has skirts exactly on the edges left skirted."""
    pattern = _ramp()[None]
    edges = np.full((1, 4, BLOCKS), SKIRTED, dtype=np.int8)
    edges[0, NORTH] = np.maximum(pattern[0, 0], [3, 3, 0, 1, 2, 3, 3, 3])
    edges[0, EAST] = 3
    idx, _ = pattern_indices(SIZE, pattern, edges)
    tris = idx.reshape(-1, 3).astype(np.int64)
    grid = tris[(tris < BASE).all(axis=1)]
    r, c = grid // SIZE, grid % SIZE
    area = 0.5 * np.abs(
        (r[:, 1] - r[:, 0]) * (c[:, 2] - c[:, 0]) - (r[:, 2] - r[:, 0]) * (c[:, 1] - c[:, 0])
    )
    assert (area > 0).all() and area.sum() == N * N
    north = _edge_nodes(tris, NORTH)
    want = sorted({8 * j + k for j in range(BLOCKS) for k in range(0, 9, 1 << edges[0, 0, j])})
    assert north == want
    assert _edge_nodes(tris, EAST) == list(range(0, SIZE, 8))
    assert not _skirted(tris, NORTH) and not _skirted(tris, EAST)
    assert _skirted(tris, SOUTH) and _skirted(tris, WEST)


def test_a_stitched_edge_finer_than_its_block_is_refused() -> None:
    edges = np.full((1, 4, BLOCKS), SKIRTED, dtype=np.int8)
    edges[0, NORTH, 0] = 0
    with pytest.raises(ValueError, match="no finer"):
        pattern_counts(SIZE, np.full((1, BLOCKS, BLOCKS), 2, dtype=np.int8), edges)


def test_stitched_edges_are_flagged_and_skirt_flags_are_checked() -> None:
    """`TileEdges.stitched` says which edges lost their skirts (the renderer pushes those to
    overlap, `EDGE_PUSH_PX`); a variant's ``skirt_edges`` must be four bools."""
    rs = _set([(6, 3, 20), (6, 3, 21)], [16, 32])
    te = stitch_tile_edges(rs, None)
    assert te.stitched.tolist() == [[False, True, False, False], [True, False, False, False]]
    ok = RenderSet(rs.keys, np.zeros(2, np.int64), [IndexVariant(skirt_edges=(True,) * 4)])
    ok.validate(SIZE)
    bad = RenderSet(rs.keys, np.zeros(2, np.int64), [IndexVariant(skirt_edges=(1, 1, 1, 1))])  # type: ignore[arg-type]
    with pytest.raises(InvalidRenderSet, match="4 bools"):
        bad.validate(SIZE)


def test_a_variants_index_list_is_built_once_read_only_and_counted_from_it() -> None:
    # A frame counts a new variant's indices and uploads them: one build, shared (#27).
    from globeview.lod.tile_indices import _build_grid_indices, index_count

    variant = IndexVariant(4, True, None, (8, 4, 16, 4), (False, True, True, False))
    first = grid_indices(SIZE, variant)
    assert grid_indices(SIZE, variant) is first
    assert not first.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        first[0] = 0
    np.testing.assert_array_equal(first, _build_grid_indices(SIZE, variant))
    assert first.dtype == np.uint32 and index_count(SIZE, variant) == len(first)
