"""Switching tools changes the model only; the displacement hook is compiled at the next
frame (issue #14). A hook that does not compile fails only that tool, in one line, and the
globe's tool becomes None (an event); the frame is drawn with the plain terrain shader."""

from __future__ import annotations

import pytest

from globeview.app.testing import PluginSite, plugin_manifest
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings
from globeview.render.gpu_objects import gpu_objects

pytestmark = pytest.mark.gl
SIZE = (96, 72)

TOOL_SRC = """
from globeview.plugins.api import Tool

class Warp(Tool):
    deactivated = 0

    def displacement_glsl(self):
        return {glsl!r}

    def deactivate(self):
        type(self).deactivated += 1
"""
GOOD_GLSL = "vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 c) { return rel + up * 10.0; }"
BAD_GLSL = "vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 c) { return nonsense_here; }"


def _registry(site: PluginSite, **tools: str) -> PluginRegistry:
    for name, glsl in tools.items():
        pkg = f"gvt_{name.replace('-', '_')}"
        site.add(
            pkg, plugin_manifest(name, pkg, "tool", "Warp"), {"impl": TOOL_SRC.format(glsl=glsl)}
        )
    return PluginRegistry(MemorySettings()).discover()


@pytest.fixture
def target(globeview_gl):
    from globeview.render.offscreen import OffscreenTarget

    t = OffscreenTarget(globeview_gl, SIZE)
    yield t
    t.release()


def _session(ctx, terrain, reg):
    from globeview.app.session import GlobeSession
    from globeview.model.camera import Camera

    return GlobeSession(ctx, terrain, Camera.from_lonlat(-71.3, 44.27, 4e4), reg)


@pytest.mark.slow
def test_activation_is_model_only_and_compiles_at_the_next_frame(
    plugin_site, globeview_gl, globeview_terrain, target
) -> None:
    reg = _registry(plugin_site, **{"warp-good": GOOD_GLSL})
    s = _session(globeview_gl, globeview_terrain, reg)
    try:
        events: list = []
        s.globe.events.tool.connect(events.append)
        s.activate_tool("warp-good")
        # The model changed and announced it; nothing was compiled yet.
        assert s.globe.tool == "warp-good" and events == ["warp-good"]
        assert s.renderer.displacement_hook is None and s.displacing
        s.render(target.fbo, SIZE)
        hook = s.renderer.displacement_hook
        assert hook is not None and "rel + up * 10.0" in hook.glsl
        s.render(target.fbo, SIZE)
        assert s.renderer.displacement_hook is hook  # compiled once, not per frame
        s.activate_tool(None)
        assert events == ["warp-good", None] and s.renderer.displacement_hook is hook
        assert type(s.find_tool("warp-good")).deactivated == 1
        s.render(target.fbo, SIZE)
        assert s.renderer.displacement_hook is None
    finally:
        s.release_gl()


@pytest.mark.slow
def test_a_hook_that_does_not_compile_fails_the_tool_at_the_frame(
    plugin_site, globeview_gl, globeview_terrain, target
) -> None:
    reg = _registry(plugin_site, **{"warp-bad": BAD_GLSL})
    s = _session(globeview_gl, globeview_terrain, reg)
    try:
        events: list = []
        s.globe.events.tool.connect(events.append)
        s.activate_tool("warp-bad")  # no GL yet: activation succeeds
        assert s.globe.tool == "warp-bad" and reg.failure_of("warp-bad") is None
        result = s.render(target.fbo, SIZE)
        why = reg.failure_of("warp-bad")
        assert why is not None and "\n" not in why
        assert events == ["warp-bad", None] and s.globe.tool is None and s.tool() is None
        assert s.renderer.displacement_hook is None and not s.displacing
        assert result.stats.tiles_drawn > 0  # the frame was drawn, plain shader
        assert s.render(target.fbo, SIZE).stats.tiles_drawn > 0
    finally:
        s.release_gl()


@pytest.mark.slow
def test_setting_the_globe_tool_directly_is_followed(
    plugin_site, globeview_gl, globeview_terrain, target
) -> None:
    reg = _registry(plugin_site, **{"warp-good": GOOD_GLSL})
    s = _session(globeview_gl, globeview_terrain, reg)
    try:
        s.globe.tool = "warp-good"  # e.g. the window's tool bar, on the model
        s.render(target.fbo, SIZE)
        assert s.renderer.displacement_hook is not None
        s.globe.tool = "no-such-tool"  # the model holds names; the host refuses it
        assert s.tool() is None and s.globe.tool is None
        s.render(target.fbo, SIZE)
        assert s.renderer.displacement_hook is None
    finally:
        s.release_gl()


@pytest.mark.slow
def test_an_unavailable_tool_name_ends_as_none_for_every_listener(
    globeview_gl, globeview_terrain, globeview_registry
) -> None:
    s = _session(globeview_gl, globeview_terrain, globeview_registry)
    try:
        seen: list = []
        s.globe.events.tool.connect(seen.append)  # after the tool host's own listener
        s.globe.tool = "no-such-tool"
        assert seen == ["no-such-tool", None] and s.globe.tool is None
    finally:
        s.release_gl()


UNIFORMS_SRC = """
from globeview.plugins.api import Tool

class Warp(Tool):
    def displacement_glsl(self):
        return {glsl!r}

    def displacement_uniforms(self, view):
        {body}
"""


@pytest.mark.slow
@pytest.mark.parametrize(
    ("body", "fails"),
    [
        ("return None", False),  # no uniforms this frame: {} (the hook stays compiled)
        ("return {}", False),
        ("return {'gv_u_k': float('nan')}", True),
        ("raise RuntimeError('boom')", True),
    ],
)
def test_uniforms_never_recompile_the_terrain_shader_per_frame(
    plugin_site, globeview_gl, globeview_terrain, target, body, fails
) -> None:
    pkg = "gvt_uniwarp"
    plugin_site.add(
        pkg,
        plugin_manifest("uni-warp", pkg, "tool", "Warp"),
        {"impl": UNIFORMS_SRC.format(glsl=GOOD_GLSL, body=body)},
    )
    reg = PluginRegistry(MemorySettings()).discover()
    s = _session(globeview_gl, globeview_terrain, reg)
    try:
        s.activate_tool("uni-warp")
        s.render(target.fbo, SIZE)  # compiles the hook (and fails a bad tool once)
        tracker = gpu_objects(globeview_gl)
        mark = tracker.mark
        for _ in range(5):
            assert s.render(target.fbo, SIZE).stats.tiles_drawn > 0
        # Every program a recompile makes goes through the tracker: none in 5 frames.
        assert tracker.mark == mark
        assert (reg.failure_of("uni-warp") is not None) == fails
        assert (s.renderer.displacement_hook is None) == fails
        assert (s.globe.tool is None) == fails
    finally:
        s.release_gl()


@pytest.mark.slow
def test_a_tool_without_uniforms_keeps_its_hook(
    plugin_site, globeview_gl, globeview_terrain, target
) -> None:
    src = f"""
class Warp:  # duck-typed: not a Tool subclass, no displacement_uniforms
    def __init__(self, ctx=None):
        self.ctx = ctx

    def displacement_glsl(self):
        return {GOOD_GLSL!r}

    def displacement_numpy(self, points):
        return points

    def on_mouse(self, event):
        return False

    def on_key(self, event):
        return False

    def overlay(self, view):
        return []
"""
    plugin_site.add(
        "gvt_bare", plugin_manifest("bare-warp", "gvt_bare", "tool", "Warp"), {"impl": src}
    )
    reg = PluginRegistry(MemorySettings()).discover()
    s = _session(globeview_gl, globeview_terrain, reg)
    try:
        s.activate_tool("bare-warp")
        s.render(target.fbo, SIZE)
        hook = s.renderer.displacement_hook
        s.render(target.fbo, SIZE)
        assert hook is not None and s.renderer.displacement_hook is hook
        assert reg.failure_of("bare-warp") is None
    finally:
        s.release_gl()
