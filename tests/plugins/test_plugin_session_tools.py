"""Switching tools changes the model only; the displacement hook is compiled at the next
frame (issue #14). A hook that does not compile fails only that tool, in one line, and the
globe's tool becomes None (an event); the frame is drawn with the plain terrain shader."""

from __future__ import annotations

import pytest

from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings
from globeview.plugins.testing import PluginSite, plugin_manifest

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
    from globeview.model.camera import Camera
    from globeview.plugins.session import GlobeSession

    return GlobeSession(ctx, terrain, Camera.from_lonlat(-71.3, 44.27, 4e4), reg)


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
