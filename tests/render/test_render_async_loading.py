"""Interactive (asynchronous) tile loading: frames never show holes or overlaps while tiles
load, and once everything has loaded the image equals the synchronous render."""

from __future__ import annotations

import time

import numpy as np
import pytest

from globeview.lod.render_set import RenderSet
from globeview.lod.tile_indices import IndexVariant
from globeview.model.camera import Camera
from globeview.render.tile_loader import substitute_missing

pytestmark = pytest.mark.gl


def test_substitution_replaces_missing_tiles_by_their_resident_ancestor() -> None:
    keys = np.array([[3, 4, 2], [3, 5, 2], [3, 4, 3], [3, 5, 3], [2, 0, 0]])
    rs = RenderSet(keys, np.zeros(5, np.int64), [IndexVariant()], error_px=np.ones(5))
    resident = {(2, 2, 1), (2, 0, 0), (3, 4, 2)}  # (3, 5, 2) and the others are missing

    out, missing = substitute_missing(
        rs, lambda k: np.array([tuple(map(int, r)) in resident for r in k], dtype=bool)
    )
    got = {tuple(map(int, r)) for r in out.keys}
    # The parent (2, 2, 1) stands in for its four children, even the resident one (no overlap);
    # the unrelated tile stays.
    assert got == {(2, 2, 1), (2, 0, 0)}
    assert {tuple(map(int, r)) for r in missing} == {(3, 5, 2), (3, 4, 3), (3, 5, 3)}
    assert len(out.variant_ids) == len(out.keys) == len(out.error_px)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["thread", "process"])
def test_async_frames_converge_to_the_synchronous_image(scene, targets, kind) -> None:
    """Render a view synchronously, then with background loading from an empty pool: frames
    come back at once while tiles load, and once loading is done the image is exactly the
    synchronous one, with tiles built on a loader thread or in worker processes (issue #27:
    texels baked there, uploaded as they come)."""
    size = (256, 192)
    target = targets(size)
    scene.camera = Camera.from_lonlat(-71.3, 44.2, 60000.0, 0.0, -50.0)
    scene.renderer.settings.background = (1.0, 0.0, 1.0)
    renderer = scene.renderer
    saved = renderer.load_kind, renderer.load_workers, renderer.load_batch
    if renderer.loader is not None:
        renderer.loader.shutdown()
        renderer.loader = None
    renderer.load_kind, renderer.load_workers, renderer.load_batch = kind, 2, 8
    try:
        scene.render(target.fbo, size)
        reference = target.read_rgb()

        scene.renderer.pool.invalidate()
        scene.renderer.async_loading = True
        loading_seen = False
        deadline = time.monotonic() + 60.0
        while True:
            result = scene.render(target.fbo, size)
            img = target.read_rgb()
            loading_seen |= result.stats.tiles_loading > 0
            if result.stats.tiles_drawn and result.stats.tiles_loading == 0:
                break
            assert time.monotonic() < deadline, "tiles never finished loading"
            time.sleep(0.02)
        assert loading_seen
        assert np.array_equal(img, reference)
        assert renderer.loader is not None and renderer.loader.describe() == f"{kind} x2"
    finally:
        if renderer.loader is not None:
            renderer.loader.shutdown()
            renderer.loader = None
        renderer.load_kind, renderer.load_workers, renderer.load_batch = saved
        scene.renderer.async_loading = False
        scene.renderer.settings.background = (0.0, 0.0, 0.0)


@pytest.mark.slow
def test_async_frames_count_missing_stand_in_and_failed_tiles(scene, targets) -> None:
    """A tile that cannot be built (here: its heights raise, as an unreadable store window
    would) is counted in the frame's ``tiles_failed``, stays stood in by an ancestor, and
    does not keep the view "loading"; the others load."""
    size = (256, 192)
    target = targets(size)
    renderer = scene.renderer
    scene.camera = Camera.from_lonlat(-71.3, 44.2, 60000.0, 0.0, -50.0)
    terrain = renderer.terrain
    real_heights = terrain.heights
    deepest: set[tuple[int, int, int]] = set()

    def heights(key, *args, **kwargs):
        if tuple(int(v) for v in key) in deepest:
            raise OSError(f"unreadable window for {key}")
        return real_heights(key, *args, **kwargs)

    if renderer.loader is not None:
        renderer.loader.shutdown()
        renderer.loader = None
    renderer.pool.invalidate()
    terrain.heights = heights  # every build (batched or not) reads through it
    renderer.async_loading = True
    try:
        first = scene.render(target.fbo, size)
        keys = first.render_set.keys
        level = int(keys[:, 0].max())
        deepest.update(tuple(map(int, k)) for k in keys[keys[:, 0] == level][:2])
        assert first.stats.extra["tiles_missing"] == len(keys)  # an empty pool
        deadline = time.monotonic() + 60.0
        while True:
            result = scene.render(target.fbo, size)
            if result.stats.tiles_loading == 0:
                break
            assert time.monotonic() < deadline, "tiles never finished loading"
            time.sleep(0.02)
        extra = result.stats.extra
        assert extra["tiles_failed"] == 2 == extra["tiles_missing"]
        assert extra["tiles_standin"] >= 1  # an ancestor covers the two failed tiles
        assert result.stats.tiles_drawn >= 1
    finally:
        del terrain.heights
        if renderer.loader is not None:
            renderer.loader.shutdown()
            renderer.loader = None
        renderer.pool.invalidate()
        renderer.async_loading = False


@pytest.mark.slow
def test_a_layer_shown_again_keeps_the_view_drawn_and_converges(scene, targets, gv) -> None:
    """A regional layer shown again while the window draws (the layers changed: every tile
    is built again): the frame after the change draws the retired tiles of the view before
    it, so no pixel shows the background where the view had ground; a few coarse ancestors
    are asked for ahead of the view's own tiles; once everything has loaded the image is
    exactly the synchronous render of the new layers."""
    size = (192, 128)
    target = targets(size)
    renderer, terrain = scene.renderer, scene.renderer.terrain
    name = next(ly.name for ly in terrain.layers if "N44W072" in ly.name)
    scene.camera = Camera.from_lonlat(-71.3, 44.2, 60000.0, 0.0, -50.0)
    scene.renderer.settings.background = (1.0, 0.0, 1.0)
    if renderer.loader is not None:
        renderer.loader.shutdown()
        renderer.loader = None
    try:
        scene.render(target.fbo, size)
        shown = target.read_rgb()
        terrain.set_visible(name, False)
        hidden_result = scene.render(target.fbo, size)
        hidden = target.read_rgb()
        ground = ~gv.is_colour(hidden, (1.0, 0.0, 1.0))
        assert ground.mean() > 0.5 and hidden_result.stats.tiles_drawn > 0

        renderer.async_loading = True
        terrain.set_visible(name, True)
        first = scene.render(target.fbo, size)
        img = target.read_rgb()
        extra = first.stats.extra
        assert extra["tiles_stale"] > 0 and extra["tiles_ahead"] > 0
        assert not gv.is_colour(img, (1.0, 0.0, 1.0))[ground].any()  # not blanked
        deadline = time.monotonic() + 60.0
        while True:
            result = scene.render(target.fbo, size)
            if result.stats.tiles_drawn and result.stats.tiles_loading == 0:
                break
            assert time.monotonic() < deadline, "tiles never finished loading"
            time.sleep(0.02)
        assert result.stats.extra["tiles_stale"] == 0
        assert np.array_equal(target.read_rgb(), shown)
    finally:
        terrain.set_visible(name, True)
        if renderer.loader is not None:
            renderer.loader.shutdown()
            renderer.loader = None
        renderer.async_loading = False
        renderer.settings.background = (0.0, 0.0, 0.0)
