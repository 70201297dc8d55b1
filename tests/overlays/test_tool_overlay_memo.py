"""Tool overlays keep their displaced positions between frames while the displacement stays
the same (a still collapse), and displace again as soon as it changes (an animating one)."""

from __future__ import annotations

import numpy as np

from globeview.geodesy import lonlat_to_ecef
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera
from globeview.render.overlay_tools import DisplacedMemo


class Shift:
    """A displacement moving every point by ``offset`` metres along x, counting its calls
    on more than the traversal's probe points."""

    def __init__(self, offset: float) -> None:
        self.offset = offset
        self.calls = 0

    def __call__(self, points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points, np.float64)
        if len(pts) != 64:  # the probes of lod.traversal.displacement_key
            self.calls += 1
        return pts + np.array([self.offset, 0.0, 0.0])


def test_displaced_positions_are_kept_while_the_displacement_is_the_same() -> None:
    view = ViewState.from_camera(Camera.from_lonlat(10.0, 46.0, 1.0e6), (320, 240))
    line = lonlat_to_ecef(np.linspace(8.0, 12.0, 50), np.full(50, 46.0), 0.0)
    memo = DisplacedMemo()
    shift = Shift(100.0)
    first = memo.wrap(view, shift)(line)
    again = memo.wrap(view, shift)(line.copy())  # the next frame: same points, same shift
    assert shift.calls == 1
    assert np.array_equal(first, again) and np.allclose(first - line, [100.0, 0.0, 0.0])
    shift.offset = 250.0  # the displacement changes (the probes move differently)
    moved = memo.wrap(view, shift)(line)
    assert shift.calls == 2 and np.allclose(moved - line, [250.0, 0.0, 0.0])
    other = memo.wrap(view, shift)(line[:10])  # other points: displaced, not looked up
    assert shift.calls == 3 and np.allclose(other - line[:10], [250.0, 0.0, 0.0])
