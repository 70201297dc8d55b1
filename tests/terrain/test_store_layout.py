"""Store format 7's global chunk grid, shard tree and file names (terrain/store/layout.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from globeview.terrain.store import layout as L

SHA = "0123456789abcdef" * 4


@pytest.mark.parametrize("tile_n", range(1, 11))
@pytest.mark.parametrize("level", [0, 1, 3, 5, 8])
def test_every_node_in_exactly_one_chunk(tile_n: int, level: int) -> None:
    if level + tile_n > 15:
        pytest.skip("too many nodes for a brute-force count")
    rows, cols = L.chunk_grid_shape(level, tile_n)
    r_total, w_total = 1 << (level + tile_n), 1 << (level + 1 + tile_n)
    row_cover = np.zeros(r_total + 1, int)
    col_cover = np.zeros(w_total, int)
    for cy in range(rows):
        gr0, _, h, _ = L.chunk_window(level, tile_n, cy, 0)
        row_cover[gr0 : gr0 + h] += 1
    for cx in range(cols):
        _, gc0, _, w = L.chunk_window(level, tile_n, 0, cx)
        col_cover[gc0 : gc0 + w] += 1
    assert (row_cover == 1).all() and (col_cover == 1).all()


def test_planet_numbers() -> None:
    assert L.chunk_tiles(6) == 16 and L.chunk_nodes(6) == 1024 and L.chunk_levels_c0(6) == 4
    assert [L.chunk_grid_shape(lv, 6) for lv in (0, 3, 4, 5, 13)] == [
        (1, 1),
        (1, 1),
        (1, 2),
        (2, 4),
        (512, 1024),
    ]
    assert L.shard_roots(13, 6) == (6, 10)  # planet
    assert L.shard_roots(9, 6) == (6,)  # GEBCO
    assert L.shard_roots(18, 6) == (6, 7, 11, 15)  # 1 m DTM
    assert L.shard_roots(5, 6) == ()  # the top shard holds everything
    assert L.shard_of(13, 300, 700, 6, 13) == L.ShardRef(10, 37, 87, 4)
    assert L.shard_of(9, 300, 700, 6, 13) == L.ShardRef(6, 37, 87, 4)
    assert L.shard_of(5, 1, 3, 6, 13) == L.ShardRef(0, 0, 0, 6)
    assert len(L.shard_chunks(L.ShardRef(0, 0, 0, 6), 6)) == 4 + 2 + 8
    assert len(L.shard_chunks(L.ShardRef(10, 3, 5, 4), 6)) == 85


@given(
    tile_n=st.integers(1, 10),
    max_level=st.integers(0, 22),
    data=st.data(),
)
@settings(max_examples=200, deadline=None)
def test_tile_chunk_shard_parent_round_trip(tile_n: int, max_level: int, data) -> None:
    level = data.draw(st.integers(0, max_level))
    x = data.draw(st.integers(0, (1 << (level + 1)) - 1))
    y = data.draw(st.integers(0, (1 << level) - 1))
    cy, cx = (int(v) for v in L.tile_chunk(x, y, tile_n))
    x0, y0, nx, ny = L.chunk_tile_range(level, tile_n, cy, cx)
    assert x0 <= x < x0 + nx and y0 <= y < y0 + ny
    ref = L.shard_of(level, cy, cx, tile_n, max_level)
    assert ref.level <= level < ref.level + ref.depth
    assert ref.depth <= max(L.shard_depth(tile_n), L.top_levels(tile_n))
    assert (level, cy, cx) in L.shard_chunks(ref, tile_n)
    if level:
        p = L.chunk_parent(level, cy, cx, tile_n)
        assert (level, cy, cx) in L.chunk_children(*p, tile_n)
    roots = L.shard_roots(max_level, tile_n)
    assert list(roots) == sorted(set(roots))
    gaps = np.diff([*roots, max_level + 1])
    assert (gaps <= L.shard_depth(tile_n)).all()


def test_names_hold_level_22() -> None:
    rows, cols = L.chunk_grid_shape(22, 10)
    assert cols == 1 << 23
    name = L.chunk_file_name(22, rows - 1, cols - 1, SHA)
    assert name == f"chunks/22/{rows - 1}/{cols - 1}-0123456789abcdef.tif"
    assert L.is_store_path(name)
    ref = L.shard_of(22, rows - 1, cols - 1, 10, 22)
    assert L.is_store_path(L.shard_file_name(ref, SHA))
    assert L.is_store_path(L.shard_file_name(L.ShardRef(0, 0, 0, 2), SHA))
    assert L.is_store_path(L.sources_file_name(SHA))
    assert L.is_store_path("level_07.vrt") and L.is_store_path("manifest.json")
    for bad in ("../x.tif", "chunks/05/01/2-0123456789abcdef.tif", "chunks/5/1/2-01.tif", "x"):
        assert not L.is_store_path(bad)
    with pytest.raises(ValueError, match="sha256"):
        L.chunk_file_name(3, 0, 0, "nothex")


def test_antimeridian_column_folds_to_zero() -> None:
    tile_n, level = 6, 5
    w_total = 1 << (level + 1 + tile_n)
    spans = L.chunk_spans(level, tile_n, w_total - 2, 4, axis=1)
    assert spans[0] == L.ChunkSpan(3, 1022, 0, 2)
    assert spans[1] == L.ChunkSpan(0, 0, 2, 2)
    # The pole row belongs to the last chunk row; rows past it are left out.
    r_total = 1 << (level + tile_n)
    rows = L.chunk_spans(level, tile_n, r_total - 1, 4, axis=0)
    assert rows == [L.ChunkSpan(1, 1023, 0, 2)]
    assert L.chunk_spans(level, tile_n, -3, 4, axis=0) == [L.ChunkSpan(0, 0, 3, 1)]


def test_chunk_codes_round_trip() -> None:
    cy = np.array([0, 5, (1 << 31) - 1])
    cx = np.array([7, 0, (1 << 31) - 1])
    back = L.decode_chunk_code(L.chunk_code(cy, cx))
    assert (back[0] == cy).all() and (back[1] == cx).all()
