"""A tool plugin's displacement GLSL goes through the shader loader end to end: a real plugin
(installed as a distribution, found through its entry point) whose hook is the identity draws
the same pixels as no tool; hostile hook text fails only that plugin, with a one-line report
that names the problem (an #include, a NUL, a compile error at the hook's own line), and the
frame is still drawn, undisplaced."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.app.testing import PluginSite, plugin_manifest

IDENTITY = "vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 c) {\n    return rel;\n}\n"

TOOL_SRC = """
from globeview.plugins.api import Tool

class HookTool(Tool):
    def displacement_glsl(self):
        return {glsl!r}
"""


@pytest.fixture
def hook_tool(request: pytest.FixtureRequest, plugin_site: PluginSite) -> str:
    """Installs the plugin 'hook-tool' whose hook text is the test's parameter (before the
    `rendered` fixture's registry discovers plugins: list this fixture first)."""
    plugin_site.add(
        "gvt_hook",
        plugin_manifest("hook-tool", "gvt_hook", "tool", "HookTool"),
        {"impl": TOOL_SRC.format(glsl=request.param)},
    )
    return "hook-tool"


@pytest.mark.slow
@pytest.mark.parametrize("hook_tool", [IDENTITY], indirect=True)
def test_an_identity_hook_changes_no_pixel(hook_tool: str, rendered) -> None:
    plain = rendered("chunked-sse").image
    hooked = rendered("chunked-sse", tool=hook_tool)
    assert hooked.failures == {}
    assert hooked.session.tool() is not None  # active, its hook compiled in
    assert hooked.image.std() > 10  # a globe was drawn
    assert np.array_equal(hooked.image, plain)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("hook_tool", "reason"),
    [
        ('#include "view.glsl"\n' + IDENTITY, "ShaderSourceError: replacement for shader chunk"),
        (IDENTITY + "\x00", "NUL or an unencodable character"),
        (IDENTITY + "float x = oops;\n", "= line 4 of <replace displace.glsl>]"),
        ("float x;\n", "of terrain.vert] GLSL"),  # no gv_displace: the host's call fails
    ],
    ids=["include", "nul", "compile-error", "no-function"],
    indirect=["hook_tool"],
)
def test_hostile_hook_text_fails_only_the_tool(hook_tool: str, rendered, reason: str) -> None:
    plain = rendered("chunked-sse").image
    frame = rendered("chunked-sse", tool=hook_tool)
    why = frame.failures.get(hook_tool, "")
    assert reason in why and "\n" not in why, why
    assert frame.provider == "chunked-sse"
    assert np.array_equal(frame.image, plain)  # drawn, undisplaced
