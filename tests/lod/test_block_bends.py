"""Per-block bends (`lod.block_bends`, issue #27 item 4): under the collapse each block's
bend at strides 2, 4, 8 covers, by brute force, how far the straight edges of that stride
inside the block stray from the collapsed surface, and its distance bound stays below the
eye's distance to every collapsed node of the block; blocks away from the fold get far
smaller bends than those it crosses."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from globeview.geodesy import ecef_to_lonlat, lonlat_to_ecef
from globeview.lod.block_bends import block_bounds, displaced_block_terms
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera
from globeview.plugins.builtin.collapse.geometry import CollapseFrame
from globeview.terrain.quadtree import tile_bounds_arrays

LEVEL = 8
SAMPLES = 33


def _tile_on_fold(frame: CollapseFrame) -> np.ndarray:
    """(1, 3) key of the level-LEVEL tile holding a point of the fold line psi = psi0."""
    lon, lat, _ = ecef_to_lonlat(frame.edge_line(frame.psi0, 0.0, 1))
    size = 180.0 / 2**LEVEL
    return np.array([[LEVEL, int((lon[0] + 180.0) // size), int((90.0 - lat[0]) // size)]])


def _stray(frame: CollapseFrame, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...,) farthest distance (m) of the collapsed straight edges a-b (..., 3) from the
    straight edges between their collapsed ends."""
    t = np.linspace(0.0, 1.0, SAMPLES)[:, None]
    seg = a[..., None, :] + t * (b - a)[..., None, :]
    moved = frame.forward(seg.reshape(-1, 3)).reshape(seg.shape)
    da, db = moved[..., :1, :], moved[..., -1:, :]
    chord = da + t * (db - da)
    return np.max(np.linalg.norm(moved - chord, axis=-1), axis=-1)


@pytest.fixture(scope="module")
def case() -> tuple[CollapseFrame, ViewState, np.ndarray]:
    frame = CollapseFrame.from_lonlat(-123.0, 48.5, -118.0, 44.0, 0.1)
    cam = Camera.from_lonlat(-120.0, 44.0, 5.0e5)
    view = ViewState.from_camera(cam, (1280, 720))
    view = replace(view, displace=frame.forward, displacement_bend=frame.bend_bound_m)
    return frame, view, _tile_on_fold(frame)


def test_block_bends_cover_the_edges_of_each_stride(case) -> None:
    frame, view, key = case
    zeros = np.zeros((1, 64))
    px_per_m, bend_s = displaced_block_terms(key, zeros, zeros, view)
    w, s, e, n = tile_bounds_arrays(LEVEL, key[:, 1], key[:, 2])
    t = np.arange(65) / 64
    lon = np.broadcast_to(w[0] + (e[0] - w[0]) * t, (65, 65))
    lat = np.broadcast_to((n[0] + (s[0] - n[0]) * t)[:, None], (65, 65))
    nodes = lonlat_to_ecef(lon, lat, np.zeros((65, 65)))  # (65, 65, 3) row 0 north
    moved = frame.forward(nodes.reshape(-1, 3)).reshape(nodes.shape)
    dist = np.linalg.norm(moved - view.eye, axis=-1)
    crossed = 0
    for bi in range(8):
        for bj in range(8):
            blk = nodes[8 * bi : 8 * bi + 9, 8 * bj : 8 * bj + 9]
            b = 8 * bi + bj
            near = dist[8 * bi : 8 * bi + 9, 8 * bj : 8 * bj + 9].min()
            assert view.sse_factor / px_per_m[0, b] <= near
            for k, st in enumerate((2, 4, 8)):
                a = blk[:-st:st, :-st:st]
                worst = max(
                    _stray(frame, a, blk[st::st, :-st:st]).max(),
                    _stray(frame, a, blk[:-st:st, st::st]).max(),
                    _stray(frame, a, blk[st::st, st::st]).max(),
                    _stray(frame, blk[st::st, :-st:st], blk[:-st:st, st::st]).max(),
                )
                assert bend_s[0, b, k] >= worst, (bi, bj, st, worst, bend_s[0, b, k])
            crossed += bool(_stray(frame, blk[0, 0], blk[-1, -1]) > 1.0)
    # The fold crosses some blocks, not all; the others' bends are far smaller.
    assert 0 < crossed < 64
    order = np.sort(bend_s[0, :, 2])
    assert order[-1] > 100.0 * order[0]


def test_block_bounds_tile_the_tile() -> None:
    key = np.array([[5, 3, 7]])
    w, s, e, n = block_bounds(key)
    tw, ts, te, tn = tile_bounds_arrays(5, key[:, 1], key[:, 2])
    assert w[0, 0] == tw[0] and n[0, 0] == tn[0] and e[0, 63] == te[0] and s[0, 63] == ts[0]
    np.testing.assert_allclose(e[0, :7], w[0, 1:8])  # row-major from the north-west block
    np.testing.assert_allclose(s[0, :8], n[0, 8:16])


def test_blocks_away_from_the_fold_coarsen_within_tau(case) -> None:
    """`choose_block_strides` under the collapse (flat land, a level-LEVEL tile the fold
    crosses, drawn at stride 1): the blocks away from the fold go coarser than those it
    crosses, and every block's chosen stride keeps its brute-force bend, projected from the
    eye's true distance to its collapsed nodes, within tau. Without the tiles' keys nothing
    goes coarser (the old behaviour)."""
    from globeview.lod.block_strides import block_facts, block_height_stats, choose_block_strides

    frame, view, key = case
    tau = 2.0
    facts = block_facts(key, block_height_stats(np.zeros((1, 65, 65)), np.zeros(1)))
    args = (facts, np.array([0]), key[:, 0], np.array([0]), view, tau, 65)
    assert np.all(choose_block_strides(*args) == -1)
    chosen = choose_block_strides(*args, keys=key)[0]
    assert chosen.min() < chosen.max()  # the blocks the fold crosses stay finer
    w, s, e, n = tile_bounds_arrays(LEVEL, key[:, 1], key[:, 2])
    t = np.arange(65) / 64
    lon = np.broadcast_to(w[0] + (e[0] - w[0]) * t, (65, 65))
    lat = np.broadcast_to((n[0] + (s[0] - n[0]) * t)[:, None], (65, 65))
    nodes = lonlat_to_ecef(lon, lat, np.zeros((65, 65)))
    moved = frame.forward(nodes.reshape(-1, 3)).reshape(nodes.shape)
    dist = np.linalg.norm(moved - view.eye, axis=-1)
    for bi in range(8):
        for bj in range(8):
            k = int(chosen[bi, bj])
            if k == 0:
                continue
            st = 2**k
            blk = nodes[8 * bi : 8 * bi + 9, 8 * bj : 8 * bj + 9]
            a = blk[:-st:st, :-st:st]
            worst = max(
                _stray(frame, a, blk[st::st, :-st:st]).max(),
                _stray(frame, a, blk[:-st:st, st::st]).max(),
                _stray(frame, a, blk[st::st, st::st]).max(),
            )
            near = dist[8 * bi : 8 * bi + 9, 8 * bj : 8 * bj + 9].min()
            assert worst * view.sse_factor / near <= tau, (bi, bj, st)
