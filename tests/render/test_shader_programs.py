"""Every GL program the app builds from the shader loader compiles and links on EGL: each
vertex/fragment pair in render/shaders, the terrain's feature variants with and without the
collapse plugin's displacement hook (found through its entry point), and GLSL compiler
messages point into the right piece (a hook's own line numbers)."""

from __future__ import annotations

import itertools
from pathlib import Path

import moderngl
import pytest

from globeview.render.renderer import TERRAIN_FEATURES, terrain_defines
from globeview.render.shader_source import (
    ShaderSourceError,
    build_shader,
    explain_sources,
    load_shader,
    source_legend,
)

SHADER_DIR = Path(__file__).resolve().parents[2] / "globeview" / "render" / "shaders"


@pytest.fixture
def egl_ctx(gl_ctx):
    """The session's EGL context (conftest: moderngl.create_standalone_context, EGL)."""
    return gl_ctx


def compile_pair(ctx: moderngl.Context, vert: str, frag: str) -> None:
    program = ctx.program(vertex_shader=vert, fragment_shader=frag)
    try:
        assert len(list(program)) > 0  # linked, with active inputs/uniforms
    finally:
        program.release()


def collapse_glsl() -> str:
    """The collapse tool's GLSL as the host gets it: through the plugin's entry point."""
    from globeview.plugins.api import PluginKind
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    reg = PluginRegistry(MemorySettings()).discover()
    tool = reg.find(PluginKind.TOOL, "collapse")
    assert tool is not None
    glsl = reg.invoke(tool, "displacement_glsl")
    assert isinstance(glsl, str) and "vec3 gv_displace(" in glsl
    return glsl


@pytest.mark.slow
def test_every_vertex_fragment_pair_compiles(egl_ctx) -> None:
    stems = sorted(p.stem for p in SHADER_DIR.glob("*.vert"))
    assert stems == sorted(p.stem for p in SHADER_DIR.glob("*.frag"))
    # Named, so a shader pair that goes missing (or a new one nobody compiles) fails here.
    assert set(stems) == {
        "overlay_billboard",
        "overlay_box_sprite",
        "overlay_label",
        "overlay_line",
        "overlay_object",
        "overlay_placemark_sprite",
        "overlay_tool",
        "overlay_tool_label",
        "terrain",
    }
    for stem in stems:
        compile_pair(egl_ctx, load_shader(f"{stem}.vert"), load_shader(f"{stem}.frag"))


@pytest.mark.slow
@pytest.mark.parametrize("hook", [False, True], ids=["plain", "collapse-hook"])
def test_every_terrain_variant_compiles(egl_ctx, hook: bool) -> None:
    """Each shaded variant (imagery, hillshade, fog, tilt on or off) and the wireframe pass's
    variant, with both stages given the same defines, as the renderer builds them."""
    assert TERRAIN_FEATURES[-1] == "GV_WIREFRAME"
    replace = {"displace.glsl": collapse_glsl()} if hook else None
    shaded = [(*f, False) for f in itertools.product((False, True), repeat=4)]
    for flags in [*shaded, (False, False, False, False, True)]:
        defines = terrain_defines(flags, hook)
        vert = load_shader("terrain.vert", replace=replace, defines=defines)
        frag = load_shader("terrain.frag", defines=defines)
        program = egl_ctx.program(vertex_shader=vert, fragment_shader=frag)
        try:
            wire = flags[4]
            # The flags really switch code: the drape's sampler exists only with GV_IMAGERY,
            # the fog range only with GV_FOG (the vertex shader computes fog per vertex).
            assert ("u_imagery" in program) == (flags[0] and not wire)
            assert ("u_fog_start" in program) == (flags[2] and not wire)
            # The wireframe variant draws one colour and fetches nothing.
            assert ("u_wire_color" in program) == wire
            assert ("u_albedo" in program) == (not wire)
            assert ("u_coast_jump" in program) == (not wire)
            assert ("gv_u_map" in program) == hook
        finally:
            program.release()


@pytest.mark.slow
def test_compile_messages_point_into_the_hook_text(egl_ctx) -> None:
    """A hook with an error on its 3rd line: the message cites line K * 10000 + 3, where K
    is the piece the legend names as the replaced displace.glsl."""
    bad = (
        "vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 c) {\n"
        "    float ok = 1.0;\n"
        "    return rel + undeclared_name;\n"
        "}\n"
    )
    vert = build_shader("terrain.vert", replace={"displace.glsl": bad})
    frag = build_shader("terrain.frag")
    k = vert.pieces.index("<replace displace.glsl>")
    with pytest.raises(moderngl.Error) as excinfo:
        egl_ctx.program(vertex_shader=vert.text, fragment_shader=frag.text)
    # Mesa cites some of these errors under source 0, but always at line k * 10000 + 3.
    assert f":{k * 10000 + 3}(" in str(excinfo.value)
    assert explain_sources(str(excinfo.value), vertex=vert, fragment=frag) == (
        f"vertex shader: {k * 10000 + 3} = line 3 of <replace displace.glsl>"
    )
    legend = source_legend(vertex=vert, fragment=frag)
    assert f"{k} = <replace displace.glsl>" in legend and "fragment 0 = terrain.frag" in legend


@pytest.mark.slow
def test_renderer_hook_errors_name_the_pieces(gl_ctx, terrain) -> None:
    """GlobeRenderer.set_displacement_hook: a hook that does not compile raises
    moderngl.Error naming the pieces, and the renderer keeps drawing with its old program."""
    from globeview.render.renderer import DisplacementHook, GlobeRenderer

    renderer = GlobeRenderer(gl_ctx, terrain, capacity=8)
    try:
        before = renderer.program
        bad = "vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 c) { return rel + oops; }"
        with pytest.raises(
            moderngl.Error,
            match=r"^\[vertex shader: \d+ = line 1 of <replace displace\.glsl>\] GLSL",
        ):
            renderer.set_displacement_hook(DisplacementHook("bad", bad))
        assert renderer.program is before
        # A fragment-shader error in the same message format names the fragment piece.
        frag_msg = "GLSL Compiler failed\n\nfragment_shader\n=====\n0:7(2): error: x\n"
        assert (
            explain_sources(
                frag_msg, vertex=build_shader("terrain.vert"), fragment=build_shader("terrain.frag")
            )
            == "fragment shader: 7 = line 7 of terrain.frag"
        )
        # An #include in hook text (moderngl would resolve it itself, with a KeyError) is a
        # one-line loader error: hooks are inserted verbatim, the host's chunks are not API.
        with pytest.raises(ShaderSourceError, match="hook text is inserted verbatim"):
            renderer.set_displacement_hook(DisplacementHook("bad", '#include "view.glsl"\n'))
        assert renderer.program is before
        renderer.set_displacement_hook(DisplacementHook("collapse", collapse_glsl()))
        assert "gv_u_map" in renderer.program
    finally:
        renderer.release()
