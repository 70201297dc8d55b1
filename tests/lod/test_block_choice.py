"""Block errors and the per-frame block choice (`globeview.lod.block_strides`, issue #27
item 3), without GL: the block stats against a per-block np.interp computation, and what
the choice leaves to the variants, never draws finer than the tile, and how it follows tau
and distance."""

from __future__ import annotations

import dataclasses

import numpy as np

from globeview.lod.block_strides import (
    N_FACTS,
    block_facts,
    block_height_stats,
    choose_block_strides,
)
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera

KEY = (12, 2473, 1043)  # under the camera of `_view` (White Mountains)


def _reference_delta(h: np.ndarray, s: int) -> float:
    x = np.arange(9)
    rows = np.array([np.interp(x, x[::s], row[::s]) for row in h[::s]])
    bil = np.array([np.interp(x, x[::s], col) for col in rows.T]).T
    return float(np.abs(bil - h).max())


def test_block_stats_match_a_per_block_computation() -> None:
    rng = np.random.default_rng(3)
    heights = rng.normal(0.0, 30.0, size=(2, 65, 65)).cumsum(axis=1).astype(np.float32)
    stats = block_height_stats(heights, np.array([1.5, 0.0]))
    assert stats.shape == (2, 64, 5)
    for t, bi, bj in ((0, 0, 0), (0, 3, 7), (1, 7, 7), (1, 5, 2)):
        block = heights[t, 8 * bi : 8 * bi + 9, 8 * bj : 8 * bj + 9].astype(np.float64)
        deltas = np.maximum.accumulate([_reference_delta(block, s) for s in (2, 4, 8)])
        level = (1.5, 0.0)[t]
        got = stats[t, 8 * bi + bj]
        np.testing.assert_allclose(got[:3], level + deltas, rtol=1e-12, atol=1e-9)
        assert got[3] == block.min() and got[4] == block.max()


def _view(height_m: float) -> ViewState:
    cam = Camera.from_lonlat(-71.3, 44.15, height_m, 0.0, -30.0)
    return ViewState.from_camera(cam, (1280, 720))


def _facts(err_m: float) -> np.ndarray:
    stats = np.zeros((3, 64, 5))
    stats[:, :, 0:3] = err_m * np.array([1.0, 2.0, 4.0])
    stats[:, :, 3:5] = (200.0, 900.0)
    return block_facts(np.array([KEY] * 3), stats)


def test_choice_leaves_whole_tiles_and_unknown_facts_to_the_variants() -> None:
    facts = _facts(1.0)
    facts[2] = np.nan
    out = choose_block_strides(
        facts, np.arange(3), np.full(3, 12), np.array([0, 3, 0]), _view(1e6), 2.0, 65
    )
    assert out.dtype == np.int8 and out.shape == (3, 8, 8)
    assert (out[0] == 3).all()  # far away: every block at stride 8
    assert (out[1:] == -1).all()  # a tile at stride 8; a tile without facts
    no_slot = choose_block_strides(
        facts, np.array([-1, -1, -1]), np.full(3, 12), np.zeros(3), _view(1e6), 2.0, 65
    )
    assert (no_slot == -1).all()
    bent = dataclasses.replace(_view(1e6), displace=lambda p: p)
    shaped = choose_block_strides(facts, np.arange(3), np.full(3, 12), np.zeros(3), bent, 2.0, 65)
    assert (shaped == -1).all()


def test_choice_follows_tau_and_never_goes_finer_than_the_tile() -> None:
    facts = _facts(5.0)
    slots, level = np.arange(3), np.full(3, 12)
    view = _view(9.0e3)
    last = None
    totals = set()
    for tau in (0.5, 1.0, 2.0, 4.0, 8.0, 64.0):
        out = choose_block_strides(facts, slots, level, np.array([1, 1, 2]), view, tau, 65)
        got = np.where(out < 0, np.array([1, 1, 2])[:, None, None], out)
        assert (got[:2] >= 1).all() and (got[2] >= 2).all()
        if last is not None:
            assert (got >= last).all(), tau  # a larger tau never draws a block finer
        last = got
        totals.add(int(got.sum()))
    assert len(totals) >= 3  # the choice changes over the ladder
    assert (last == 3).all()
    assert facts.shape == (3, N_FACTS, 64) and facts.dtype == np.float32
