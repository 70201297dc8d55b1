"""A second headless context on the same thread never hijacks the first one's frames.

Creating an EGL context makes it current; before `make_current`, a scene drawn after another
headless context was opened (an in-process `globeview render`, a second session) drew into
that other context with its own object names: an order-dependent empty or wrong frame."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.model.camera import Camera
from globeview.render.offscreen import OffscreenTarget, create_headless_context

pytestmark = pytest.mark.gl
SIZE = (128, 96)


def _frame(scene, target) -> np.ndarray:
    scene.render(target.fbo, SIZE)
    return target.read_rgb()


def test_a_frame_after_another_context_was_opened_is_unchanged(scene, targets) -> None:
    scene.camera = Camera.from_lonlat(-71.3, 44.2, 60000.0, 0.0, -50.0)
    target = targets(SIZE)
    before = _frame(scene, target)
    assert len(np.unique(before.reshape(-1, 3), axis=0)) > 50  # terrain, not one colour

    other = create_headless_context(fresh=True)  # current on this thread now
    try:
        theirs = OffscreenTarget(other, SIZE)
        theirs.fbo.clear(1.0, 0.0, 1.0)
        assert np.array_equal(_frame(scene, target), before)
        assert (theirs.read_rgb() == [255, 0, 255]).all()  # and theirs was not drawn into
        theirs.release()
    finally:
        other.release()  # no context current on this thread any more
    assert np.array_equal(_frame(scene, target), before)
