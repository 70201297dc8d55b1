"""The measure tool headless through the session and the registry (EGL), as `globeview render
--tool measure --points A;B` drives it: the points go in through the tool's `place_points`,
the geodesic is drawn over the White Mountains where it projects, and refused points are a
one-line user error."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.errors import GlobeviewError
from globeview.geodesy import lonlat_to_ecef
from globeview.model.camera import Camera

pytestmark = pytest.mark.gl

SIZE = (240, 180)
A = (-71.45, 44.23)
B = (-71.22, 44.31)
CAMERA = (-71.335, 44.27, 4.0e4)
LINE_RGB = np.array([26, 204, 255])  # measure.LINE_RGBA (0.1, 0.8, 1.0)


# The fixtures a plugin author gets (globeview.app.testing): the session's GL context and
# the embedded terrain, not a context and stack of this module's own.
@pytest.fixture(scope="module")
def gl(globeview_gl):
    from globeview.render.offscreen import OffscreenTarget

    target = OffscreenTarget(globeview_gl, SIZE)
    yield globeview_gl, target
    target.release()


@pytest.fixture(scope="module")
def session(gl, globeview_terrain):
    from globeview.app.session import GlobeSession
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    reg = PluginRegistry(MemorySettings()).discover()
    scene = GlobeSession(gl[0], globeview_terrain, Camera.from_lonlat(*CAMERA), registry=reg)
    yield scene
    scene.release_gl()


def draw(session, gl):
    session.camera = Camera.from_lonlat(*CAMERA)
    result = session.render(gl[1].fbo, SIZE)
    return gl[1].read_rgb(), result, result.overlay_drawn


def line_mask(rgb: np.ndarray) -> np.ndarray:
    return np.abs(rgb.astype(int) - LINE_RGB).max(axis=2) < 30


@pytest.mark.slow
def test_place_points_draws_the_geodesic_where_it_projects(session, gl) -> None:
    session.activate_tool(None)
    plain, _, _ = draw(session, gl)
    assert not line_mask(plain).any()  # no such colour without the tool
    session.activate_tool("measure")
    tool = session.tools()["measure"]
    assert session.registry.invoke(tool, "place_points", [A, B], user_errors=True) is True
    m = tool.measurement
    assert 18e3 < m.distance_m < 22e3 and m.profile_h_m.max() > 1000.0
    assert session.hooks.status.startswith("measure: ")
    rgb, result, drawn = draw(session, gl)
    assert drawn >= 3  # two markers and the geodesic
    mask = line_mask(rgb)
    # The middle of the geodesic, on the terrain, projects onto line-coloured pixels.
    i = m.profile_lon.size // 2
    mid = np.asarray(
        lonlat_to_ecef(m.profile_lon[i], m.profile_lat[i], m.profile_ellipsoidal_m[i]), np.float64
    ).reshape(1, 3)
    x, y, _ = result.view.project(mid)[0]
    x, y = round(float(x)), round(float(y))
    assert mask[y - 3 : y + 4, x - 3 : x + 4].any()
    assert mask.sum() > 60  # a line across the view, not a dot
    assert session.registry.get("measure").status == "ok"


@pytest.mark.slow
@pytest.mark.parametrize("points", [[A, B, A], [(0.0, 95.0), B], [(float("nan"), 0.0), B]])
def test_refused_points_are_a_user_error(session, points) -> None:
    session.activate_tool("measure")
    tool = session.tools()["measure"]
    with pytest.raises(GlobeviewError) as info:
        session.registry.invoke(tool, "place_points", points, user_errors=True)
    assert "\n" not in str(info.value)
    assert session.registry.get("measure").status == "ok"  # the user's error, not a bug
