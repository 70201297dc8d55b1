"""A valid view never overflows the GPU tile pool (issue #13, item 9): when the LOD selection
wants more tiles than the pool has slots, the renderer draws coarser tiles (siblings replaced
by their parent) and says so in the frame's stats, instead of failing the frame with
"tile pool too small"."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import zygote

from globeview.lod.render_set import RenderSet
from globeview.lod.tile_indices import IndexVariant
from globeview.render.renderer import coarsen_to_fit

GLOBEVIEW = Path(sys.executable).with_name("globeview")


def covered_cells(keys: np.ndarray, level: int) -> set[tuple[int, int]]:
    """The level-``level`` cells the tiles cover (each at most ``level`` deep)."""
    cells: set[tuple[int, int]] = set()
    for lv, x, y in keys:
        shift = level - int(lv)
        assert shift >= 0
        n = 1 << shift
        cells.update((int(x) * n + i, int(y) * n + j) for i in range(n) for j in range(n))
    return cells


def full_cover(level: int) -> np.ndarray:
    """Every tile of ``level`` (level 0 has 2 x 1 tiles)."""
    xs, ys = np.meshgrid(np.arange(2 << level), np.arange(1 << level), indexing="ij")
    return np.stack([np.full(xs.size, level), xs.ravel(), ys.ravel()], axis=1)


def mixed_set() -> RenderSet:
    """Level-5 tiles over one corner, level 3 elsewhere: a valid, non-overlapping cover."""
    keys = []
    for lv, x, y in full_cover(3):
        if x < 2 and y < 2:
            fine = full_cover(5)
            keep = (fine[:, 1] >> 2 == x) & (fine[:, 2] >> 2 == y)
            keys.extend(fine[keep].tolist())
        else:
            keys.append([lv, x, y])
    keys = np.array(keys, dtype=np.int64)
    err = np.linspace(0.1, 1.0, len(keys))
    variants = [IndexVariant(stride=2), IndexVariant(stride=1)]
    ids = (keys[:, 0] == 5).astype(np.int64)
    custom = {0: np.arange(6, dtype=np.uint32)}
    return RenderSet(keys, ids, variants, custom_indices=custom, error_px=err)


@pytest.mark.parametrize("capacity", [120, 100, 70, 40, 10, 2])
def test_coarsen_to_fit_covers_the_same_ground_without_overlap(capacity: int) -> None:
    rs = mixed_set()
    fitted, replaced = coarsen_to_fit(rs, capacity)
    assert len(fitted) <= capacity
    assert replaced > 0
    # Same ground, nothing drawn twice.
    before = covered_cells(rs.keys, 5)
    cells = [covered_cells(k[None, :], 5) for k in fitted.keys]
    assert set().union(*cells) == before
    assert sum(len(c) for c in cells) == len(before)
    # Consistent render set: one variant per tile, ids in range, custom rows in range.
    assert len(fitted.variant_ids) == len(fitted.keys)
    assert fitted.variant_ids.max() < len(fitted.variants)
    assert all(0 <= r < len(fitted) for r in fitted.custom_indices)
    # A kept tile keeps its own index list (it follows the tile to its new row).
    old_rows = {tuple(k): i for i, k in enumerate(rs.keys.tolist())}
    for r, idx in fitted.custom_indices.items():
        assert rs.custom_indices[old_rows[tuple(fitted.keys[r].tolist())]] is idx
    kept = {tuple(k) for k in fitted.keys.tolist()}
    for r in rs.custom_indices:
        if tuple(rs.keys[r].tolist()) in kept:
            assert any(idx is rs.custom_indices[r] for idx in fitted.custom_indices.values())
    assert fitted.error_px is not None and np.all(np.isfinite(fitted.error_px))


def test_coarsen_keeps_a_set_that_fits_and_the_finest_tiles_it_can() -> None:
    rs = mixed_set()  # 124 level-3 tiles and 64 level-5 ones
    fitted, replaced = coarsen_to_fit(rs, len(rs))
    assert replaced == 0 and np.array_equal(fitted.keys, rs.keys)
    # One slot short: only one sibling group (the one with the smallest error) goes.
    fitted, replaced = coarsen_to_fit(rs, len(rs) - 3)
    assert replaced == 4 and len(fitted) == len(rs) - 3
    assert int(fitted.keys[:, 0].max()) == 5


def test_parents_at_the_poles_get_pole_fans() -> None:
    keys = full_cover(2)  # rows 0 and 3 touch the poles
    rs = RenderSet(keys, np.zeros(len(keys), np.int64), [IndexVariant()])
    fitted, _ = coarsen_to_fit(rs, 2)
    assert len(fitted) == 2 and set(fitted.keys[:, 0]) == {0}
    assert {fitted.variants[i].pole for i in fitted.variant_ids} == {"both"}


@pytest.mark.slow
@pytest.mark.gl
def test_renderer_with_a_small_pool_draws_a_degraded_frame(gl_ctx, terrain, targets) -> None:
    from globeview.lod.sse_policy import ScreenSpaceErrorPolicy
    from globeview.lod.traversal import traverse
    from globeview.lod.view_state import ViewState
    from globeview.model.camera import Camera
    from globeview.render.renderer import GlobeRenderer
    from globeview.render.scene import GlobeScene

    cam = Camera.from_lonlat(-71.3, 44.2, 3000.0, 0.0, -10.0)
    view = ViewState.from_camera(cam, (160, 120), tau_px=1.0)
    rs = traverse(view, terrain, ScreenSpaceErrorPolicy())
    assert len(rs) > 16  # the view really wants more than the pool holds
    # The frame runs through the pipeline, drawing this render set with a 16-slot pool.
    scene = GlobeScene(gl_ctx, terrain, cam, lod=lambda v, t: rs)
    scene.renderer.release()
    scene.renderer = renderer = GlobeRenderer(gl_ctx, terrain, capacity=16)
    try:
        tgt = targets((160, 120))
        stats = scene.render(tgt.fbo, (160, 120)).stats
        assert 0 < stats.tiles_drawn <= 16
        assert stats.extra["tiles_coarsened"] > 0
        assert f"{len(rs)} tiles wanted, 16 slots" in stats.extra["degraded"]
        # The frame shows terrain below the horizon: no hole in the lower half of the image.
        rgb = tgt.read_rgb()[60:].reshape(-1, 3).astype(int)
        bg = np.round(np.array(renderer.settings.background) * 255)
        assert not np.any(np.all(np.abs(rgb - bg) <= 2, axis=1))
        # The async (window) path with the same overflowing set never fails either.
        renderer.async_loading = True
        for _ in range(30):
            stats = scene.render(tgt.fbo, (160, 120)).stats
            assert stats.tiles_drawn <= 16
    finally:
        scene.pipeline.release()
        renderer.release()


@pytest.mark.gl
@pytest.mark.slow
def test_cli_overflowing_view_renders_and_says_it_degraded(tmp_path: Path, seed_cache) -> None:
    """The view that failed with "tile pool too small: 1005 tiles to load": tiny tau, strong
    exaggeration, low oblique over the White Mountains, on the embedded terrain (its stores
    copied into the child's cache, not ingested again)."""
    out, stats = tmp_path / "x.png", tmp_path / "s.json"
    cache = seed_cache(tmp_path / "cache")
    res = zygote.run(  # a process of its own, forked from the pre-warmed server
        [
            str(GLOBEVIEW),
            "render",
            "--tau",
            "0.05",
            "--exaggeration",
            "50",
            "--camera=-71.3,44.2,3000,0,-10",
            "--size",
            "640x480",
            "--out",
            str(out),
            "--stats",
            str(stats),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "GLOBEVIEW_CACHE_DIR": str(cache)},
    )
    assert res.returncode == 0, res.stderr
    data = json.loads(stats.read_text())
    assert data["tiles_drawn"] <= 768 and data["tiles_coarsened"] > 0
    assert "drew coarser tiles" in data["degraded"]
    assert "degraded: tile pool" in res.stdout
    assert out.read_bytes()[:4] == b"\x89PNG"


def test_replaced_counts_input_tiles_once_over_several_levels() -> None:
    keys = full_cover(4)  # 512 tiles
    rs = RenderSet(keys, np.zeros(len(keys), np.int64), [IndexVariant()])
    fitted, replaced = coarsen_to_fit(rs, 10)  # down to level 1 (8 tiles)
    assert len(fitted) == 8 and replaced == 512
