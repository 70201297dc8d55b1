"""`FramePipeline` (issue #14): one frame runs prepare -> view -> LOD -> load -> draw ->
overlays -> tool overlay -> stats in that order and builds ONE ViewState that the tool, the
LOD selection, the draw and the result all see; the camera speed comes from the camera's
history and the frames' time stamps, so headless frames exercise it too.

Real GL (EGL), the embedded terrain and the built-in chunked selection; the tool here is a
small recording `FrameTool` (the protocol the plugin host implements), and the session test
runs the real collapse plugin through the registry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from globeview.model.camera import Camera
from globeview.plugins.api import Marker
from globeview.render.frame_pipeline import PAUSE_S, CameraMotion, check_time

pytestmark = pytest.mark.gl

SIZE = (160, 120)


class RecordingTool:
    """A `FrameTool` that records each call and the view it was handed."""

    def __init__(self, log: list) -> None:
        self.log = log

    def animate(self, now_s: float) -> bool:
        self.log.append(("animate", now_s))
        return True

    def shape_view(self, view):
        self.log.append(("shape_view", view))
        return view

    def uniforms(self, view):
        self.log.append(("uniforms", view))
        return {}

    def overlay(self, view):
        self.log.append(("overlay", view))
        return [Marker(position=tuple(float(v) for v in view.eye * 0.5), label="")], None


@pytest.fixture
def recording_scene(gl_ctx, terrain):
    """A bare scene (chunked selection) whose host calls are logged in ``scene.log``."""
    from globeview.lod.sse_policy import ScreenSpaceErrorPolicy
    from globeview.lod.traversal import traverse
    from globeview.render.offscreen import OffscreenTarget
    from globeview.render.scene import GlobeScene

    class Recording(GlobeScene):
        def prepare_gpu(self) -> None:
            self.log.append(("prepare_gpu", None))

        def select(self, view):
            self.log.append(("select", view))
            return super().select(view)

        def frame_tool(self):
            return self.tool

    scene = Recording(
        gl_ctx,
        terrain,
        Camera.from_lonlat(-71.3, 44.2, 4.0e5),
        lod=lambda v, t: traverse(v, t, ScreenSpaceErrorPolicy()),
    )
    scene.log = []
    scene.tool = RecordingTool(scene.log)
    target = OffscreenTarget(gl_ctx, SIZE)
    yield scene, target
    scene.pipeline.release()
    scene.renderer.release()
    target.release()


@pytest.mark.slow
def test_one_frame_runs_its_steps_in_order_on_one_view(recording_scene) -> None:
    scene, target = recording_scene
    result = scene.render(target.fbo, SIZE, now_s=5.0)
    steps = [name for name, _ in scene.log]
    assert steps == ["prepare_gpu", "animate", "shape_view", "uniforms", "select", "overlay"]
    assert scene.log[1][1] == 5.0  # the tool animates to the frame's time stamp
    views = [v for name, v in scene.log if name not in ("prepare_gpu", "animate")]
    # ONE ViewState: the tool's, the LOD selection's, the draw's and the result's.
    assert all(v is result.view for v in views)
    assert scene.renderer.last_view is result.view
    assert result.animating is True
    assert result.overlay_drawn > 0  # the tool overlay is part of the frame
    assert result.target is target.fbo
    assert result.stats.triangles > 0 and result.stats.tiles_drawn == len(result.render_set)


@pytest.mark.slow
def test_a_failed_tool_frame_draws_without_its_displacement(recording_scene) -> None:
    scene, target = recording_scene
    scene.tool.uniforms = lambda view: None  # the host says: the tool failed this frame
    scene.tool.shape_view = lambda view: __import__("dataclasses").replace(
        view, displace=lambda p: p, displacement_key=("k",)
    )
    result = scene.render(target.fbo, SIZE, now_s=1.0)
    assert result.view.displace is None and result.view.displacement_key is None
    assert result.overlay_drawn == 0  # nor its overlay
    assert scene.renderer.last_view is result.view


@pytest.mark.slow
def test_speed_comes_from_camera_history_and_time_stamps(recording_scene) -> None:
    scene, target = recording_scene
    first = scene.render(target.fbo, SIZE, now_s=100.0)
    scene.camera.fly_forward(500.0)
    moved = scene.render(target.fbo, SIZE, now_s=100.25)
    seen = [v.speed_mps for name, v in scene.log if name == "select"]
    assert first.view.speed_mps == 0.0  # the first frame has no history
    assert moved.view.speed_mps == pytest.approx(2000.0, rel=1e-6)  # 500 m in 0.25 s
    assert seen[-1] == moved.view.speed_mps  # the LOD provider sees it
    scene.camera.fly_forward(500.0)
    paused = scene.render(target.fbo, SIZE, now_s=100.25 + PAUSE_S + 0.1)
    assert paused.view.speed_mps == 0.0  # after a pause: at rest
    # Frames without a stamp use the pipeline's clock.
    ticks = iter([7.0, 7.5])
    scene.pipeline.clock = lambda: next(ticks)
    scene.pipeline.motion.reset()
    scene.render(target.fbo, SIZE)
    scene.camera.fly_forward(100.0)
    assert scene.render(target.fbo, SIZE).view.speed_mps == pytest.approx(200.0, rel=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, "1.0", True, None, [1.0]])
def test_a_bad_time_stamp_is_refused_in_one_line(recording_scene, bad) -> None:
    scene, target = recording_scene
    if bad is None:  # None means "use the clock": not an error
        assert scene.render(target.fbo, SIZE, now_s=bad).view.speed_mps == 0.0
        return
    with pytest.raises(ValueError, match="now_s must be a") as err:
        scene.render(target.fbo, SIZE, now_s=bad)
    assert "\n" not in str(err.value)
    assert scene.log == []  # refused before anything ran


def test_camera_motion_rules() -> None:
    cam = Camera.from_lonlat(10.0, 45.0, 1.0e4)
    m = CameraMotion()
    assert m.speed(cam, 0.0) == 0.0  # first frame
    cam.fly_forward(30.0)
    assert m.speed(cam, 0.1) == pytest.approx(300.0)
    cam.fly_forward(30.0)
    assert m.speed(cam, 0.1) == 0.0  # the stamp did not advance
    cam.fly_forward(30.0)
    assert m.speed(cam, 0.05) == 0.0  # the stamp went back
    assert m.speed(cam, 0.05 + PAUSE_S) == 0.0  # not moved: 0 m/s, still measured
    other = Camera.from_lonlat(-120.0, 40.0, 1.0e4)
    assert m.speed(other, 0.06 + PAUSE_S) == 0.0  # a replaced camera is a cut
    other.fly_forward(10.0)
    assert m.speed(other, 0.16 + PAUSE_S) == pytest.approx(100.0)
    m.reset()
    other.fly_forward(10.0)
    assert m.speed(other, 0.2 + PAUSE_S) == 0.0
    assert check_time(np.float32(2.5)) == 2.5 and check_time(3) == 3.0


@pytest.mark.slow
def test_session_frame_with_a_tool_builds_one_view(globeview_gl, terrain) -> None:
    """The real collapse plugin through the registry: the provider's view is the frame's,
    it carries the collapse's displacement, and the frame drew the fold lines itself."""
    from globeview.app.session import GlobeSession
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.render.offscreen import OffscreenTarget

    reg = PluginRegistry(MemorySettings()).discover()
    cam = Camera.from_lonlat(-120.0, 44.0, 5.0e5, 300.0, -55.0)
    session = GlobeSession(globeview_gl, terrain, cam, registry=reg)
    target = OffscreenTarget(globeview_gl, SIZE)
    try:
        tool = session.tools()["collapse"]
        reg.invoke(tool, "set_points", -123.0, 48.5, -118.0, 44.0, 0.1)
        session.activate_tool("collapse")
        selected = []
        select = session.select  # a spy around the real selection, not a replacement

        def spy(view):
            selected.append(view)
            return select(view)

        session.select = spy
        result = session.render(target.fbo, SIZE, now_s=0.0)
        assert len(selected) == 1 and selected[0] is result.view
        assert session.renderer.last_view is result.view
        assert result.view.displace is not None and result.view.displacement_key is not None
        assert result.overlay_drawn > 0  # markers and fold lines, drawn by the frame
        assert reg.failure_of("collapse") is None
    finally:
        session.activate_tool(None)
        session.release_gl()
        target.release()


# An installed tool whose frame methods return garbage: a truth value that raises, then an
# overlay that is not a list. The frame goes on; the tool fails (one line), nothing else.
HOSTILE_TOOL = """
from globeview.plugins.api import Tool

class Liar:
    def __bool__(self):
        raise RuntimeError("no truth here")

class Hostile(Tool):
    def animate(self, now):
        return Liar()

    def overlay(self, view):
        return "not a list"
"""


@pytest.mark.slow
@pytest.mark.parametrize("broken", ["animate", "overlay"])
def test_a_hostile_tool_fails_alone_and_the_frame_is_drawn(
    plugin_site, globeview_gl, terrain, broken
) -> None:
    from globeview.app.session import GlobeSession
    from globeview.app.testing import plugin_manifest
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.render.offscreen import OffscreenTarget

    src = HOSTILE_TOOL
    if broken == "overlay":  # only the overlay is garbage
        src = src.replace("return Liar()", "return False")
    plugin_site.add("gvt_hostile", plugin_manifest("gvt-hostile", "gvt_hostile", "tool", "Hostile"),
                    {"impl": src})  # fmt: skip
    reg = PluginRegistry(MemorySettings()).discover()
    session = GlobeSession(globeview_gl, terrain, registry=reg)
    target = OffscreenTarget(globeview_gl, SIZE)
    try:
        session.activate_tool("gvt-hostile")
        result = session.render(target.fbo, SIZE, now_s=1.0)
        assert result.stats.triangles > 0  # the terrain was drawn
        assert result.animating is False and result.overlay_drawn == 0
        why = reg.failure_of("gvt-hostile")
        assert why is not None and "\n" not in why
        assert ("animate()" if broken == "animate" else "overlay() returned str") in why
        assert session.tool() is None
        assert reg.failure_of("chunked-sse") is None  # the provider is untouched
        again = session.render(target.fbo, SIZE, now_s=1.1)  # and frames go on
        assert again.stats.triangles > 0
    finally:
        session.release_gl()
        target.release()
