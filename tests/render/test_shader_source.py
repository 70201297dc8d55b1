"""The shader loader (render/shader_source.py) without GL: #include resolution, include-once,
cycle and missing-file errors naming the chain, #define injection after #version, verbatim
chunk replacement, and the app's shaders written once (one loader, one log-depth formula)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from globeview.errors import GlobeviewError
from globeview.render.shader_source import (
    SHADERS,
    ShaderLibrary,
    ShaderSourceError,
    build_shader,
    explain_sources,
    load_shader,
)

ROOT = Path(__file__).resolve().parents[2]
SHADER_DIR = ROOT / "globeview" / "render" / "shaders"


def library(tmp_path: Path, files: dict[str, str]) -> ShaderLibrary:
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    return ShaderLibrary(tmp_path)


def code_lines(text: str) -> list[str]:
    """The lines GLSL compiles, without the loader's #line directives and blank lines."""
    return [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#line")]


def one_line_error(excinfo: pytest.ExceptionInfo) -> str:
    msg = str(excinfo.value)
    assert isinstance(excinfo.value, GlobeviewError)
    assert "\n" not in msg and msg
    return msg


# -- includes ---------------------------------------------------------------------------------
def test_includes_resolve_depth_first_in_place(tmp_path: Path) -> None:
    lib = library(
        tmp_path,
        {
            "r.vert": '#version 330\n#include "a.glsl"\nvoid main() {}\n',
            "a.glsl": 'float a;\n  #include "b.glsl"   // comment allowed\nfloat a2;\n',
            "b.glsl": "float b;\n",
        },
    )
    src = lib.build("r.vert")
    assert code_lines(src.text) == [
        "#version 330",
        "float a;",
        "float b;",
        "float a2;",
        "void main() {}",
    ]
    assert src.pieces == ("r.vert", "a.glsl", "b.glsl")
    # Piece K counts from K * 10000 + 1 (source number K); the includer's count resumes.
    lines = src.text.splitlines()
    assert lines[:3] == ["#version 330", "#line 2 0", "#line 10001 1"]
    assert lines[lines.index("float a2;") - 1] == "#line 10003 1"
    assert lines[lines.index("void main() {}") - 1] == "#line 3 0"


def test_a_chunk_is_included_once_per_program(tmp_path: Path) -> None:
    lib = library(
        tmp_path,
        {
            "r.vert": '#version 330\n#include "a.glsl"\n#include "b.glsl"\n#include "c.glsl"\n',
            "a.glsl": '#include "c.glsl"\nfloat a;\n',
            "b.glsl": '#include "c.glsl"\nfloat b;\n',
            "c.glsl": "const float C = 1.0;\n",
        },
    )
    text = lib.load("r.vert")
    assert code_lines(text) == ["#version 330", "const float C = 1.0;", "float a;", "float b;"]


@pytest.mark.parametrize(
    ("files", "chain"),
    [
        ({"r.vert": '#include "r.vert"\n'}, "r.vert -> r.vert"),
        (
            {
                "r.vert": '#version 330\n#include "a.glsl"\n',
                "a.glsl": '#include "b.glsl"\n',
                "b.glsl": 'float b;\n#include "a.glsl"\n',
            },
            "r.vert -> a.glsl -> b.glsl -> a.glsl",
        ),
    ],
)
def test_an_include_cycle_is_a_one_line_error_naming_the_chain(
    tmp_path: Path, files: dict[str, str], chain: str
) -> None:
    lib = library(tmp_path, files)
    with pytest.raises(ShaderSourceError) as excinfo:
        lib.load("r.vert")
    assert one_line_error(excinfo) == f"shader include cycle: {chain}"


def test_a_missing_chunk_is_a_one_line_error_naming_who_included_it(tmp_path: Path) -> None:
    lib = library(
        tmp_path,
        {"r.vert": '#version 330\n#include "a.glsl"\n', "a.glsl": '\n\n#include "nope.glsl"\n'},
    )
    with pytest.raises(ShaderSourceError) as excinfo:
        lib.load("r.vert")
    msg = one_line_error(excinfo)
    assert "'nope.glsl' not found" in msg and "included by r.vert -> a.glsl" in msg
    with pytest.raises(ShaderSourceError, match=r"'absent\.vert' not found"):
        lib.load("absent.vert")


@pytest.mark.parametrize(
    "line",
    [
        "#include nope.glsl",
        "#include <nope.glsl>",
        '#include "a.glsl" trailing',
        '#include "a.glsl',
        "#include",
    ],
)
def test_a_malformed_include_names_file_and_line(tmp_path: Path, line: str) -> None:
    lib = library(tmp_path, {"r.vert": f"#version 330\nfloat x;\n{line}\n", "a.glsl": ""})
    with pytest.raises(ShaderSourceError) as excinfo:
        lib.load("r.vert")
    assert "malformed #include in r.vert line 3" in one_line_error(excinfo)


@pytest.mark.parametrize(
    "name", ["../secret.glsl", "/etc/passwd", "sub/x.glsl", "x\\y.glsl", "", ".hidden", "a..b"]
)
def test_chunk_names_cannot_leave_the_shader_folder(tmp_path: Path, name: str) -> None:
    (tmp_path.parent / "secret.glsl").write_text("float secret;\n")
    lib = library(tmp_path, {"r.vert": f'#version 330\n#include "{name}"\n'})
    with pytest.raises(ShaderSourceError) as excinfo:
        lib.load("r.vert")
    msg = one_line_error(excinfo)
    assert "bad shader file name" in msg and "included by r.vert" in msg
    with pytest.raises(ShaderSourceError, match="bad shader file name"):
        lib.load(name)


def test_an_include_is_resolved_inside_an_inactive_ifdef(tmp_path: Path) -> None:
    """Textual resolution: the chunk is spliced in, GLSL's own preprocessor drops it."""
    lib = library(
        tmp_path,
        {"r.vert": '#version 330\n#ifdef OFF\n#include "a.glsl"\n#endif\n', "a.glsl": "x;\n"},
    )
    assert code_lines(lib.load("r.vert")) == ["#version 330", "#ifdef OFF", "x;", "#endif"]


def test_a_stray_include_outside_an_include_line_is_refused(tmp_path: Path) -> None:
    """moderngl resolves '#include "x"' anywhere (comments too) and raises KeyError: the
    loader lets none through."""
    lib = library(tmp_path, {"r.vert": '#version 330\nfloat x;  // like #include "a.glsl"\n'})
    with pytest.raises(ShaderSourceError) as excinfo:
        lib.load("r.vert")
    assert "stray" in one_line_error(excinfo)


# -- defines ----------------------------------------------------------------------------------
def test_defines_follow_the_version_line(tmp_path: Path) -> None:
    lib = library(tmp_path, {"r.vert": '#version 330\n#include "a.glsl"\n', "a.glsl": "a;\n"})
    text = lib.load(
        "r.vert", defines={"GV_ON": True, "GV_OFF": False, "GV_N": 3, "GV_X": 0.25, "GV_T": "vec3"}
    )
    assert code_lines(text) == [
        "#version 330",
        "#define GV_ON 1",
        "#define GV_N 3",
        "#define GV_X 0.25",
        "#define GV_T vec3",
        "a;",
    ]
    # Without a #version line the defines open the text.
    lib2 = library(tmp_path, {"plain.glsl": "b;\n"})
    assert code_lines(lib2.load("plain.glsl", defines={"GV_ON": True})) == ["#define GV_ON 1", "b;"]


@pytest.mark.parametrize(
    ("defines", "needle"),
    [
        ({"1X": True}, "bad #define name"),
        ({"X Y": True}, "bad #define name"),
        ({"X\n#define Y": True}, "bad #define name"),
        ({"": True}, "bad #define name"),
        ({"GL_FOO": True}, "reserved"),
        ({"GV__X": True}, "reserved"),
        ({"X": "1\n#error injected"}, "not a bool, number"),
        ({"X": ""}, "not a bool, number"),
        ({"X": "a;b"}, "not a bool, number"),
        ({"X": float("nan")}, "not finite"),
        ({"X": float("inf")}, "not finite"),
        ({"X": object()}, "not a bool, number"),
        ({"X": None}, "not a bool, number"),
    ],
)
def test_bad_defines_are_one_line_errors(tmp_path: Path, defines: dict, needle: str) -> None:
    lib = library(tmp_path, {"r.vert": "#version 330\n"})
    with pytest.raises(ShaderSourceError) as excinfo:
        lib.load("r.vert", defines=defines)
    assert needle in one_line_error(excinfo)


# -- verbatim replacement (the displacement hook) ---------------------------------------------
def test_replace_inserts_text_verbatim_in_place_of_a_chunk(tmp_path: Path) -> None:
    lib = library(
        tmp_path,
        {"r.vert": '#version 330\n#include "hook.glsl"\nmain;\n', "hook.glsl": "identity;\n"},
    )
    hook = "// hook\n#define GV_HOOK 1\nfloat plugin;"
    src = lib.build("r.vert", replace={"hook.glsl": hook})
    assert code_lines(src.text) == [
        "#version 330",
        "// hook",
        "#define GV_HOOK 1",
        "float plugin;",
        "main;",
    ]
    assert src.pieces == ("r.vert", "<replace hook.glsl>")
    assert "#line 10001 1\n// hook" in src.text  # the hook's lines count from 1
    # Verbatim text may not include anything (moderngl would try to resolve it on its own),
    # not even inside a comment.
    for text in ('#include "r.vert"', 'x; // see #include "a.glsl"'):
        with pytest.raises(ShaderSourceError) as excinfo:
            lib.load("r.vert", replace={"hook.glsl": text})
        assert "hook text is inserted verbatim" in one_line_error(excinfo)
    with pytest.raises(ShaderSourceError, match=r"includes no shader chunk 'other\.glsl'"):
        lib.load("r.vert", replace={"other.glsl": "x;"})
    # GL would cut the text at a NUL (and report a missing main); lone surrogates garble the
    # driver's message: both are refused up front.
    for text in ("float a;\x00garbage", "// \udcff\n"):
        with pytest.raises(ShaderSourceError) as excinfo:
            lib.load("r.vert", replace={"hook.glsl": text})
        assert "NUL or an unencodable character" in one_line_error(excinfo)
    # Line numbers give each piece 10000 (see explain_sources): a longer one is refused.
    with pytest.raises(ShaderSourceError) as excinfo:
        lib.load("r.vert", replace={"hook.glsl": "x;\n" * 10_000})
    assert "has 10001 lines" in one_line_error(excinfo)
    with pytest.raises(ShaderSourceError, match="is bytes, not GLSL text"):
        lib.load("r.vert", replace={"hook.glsl": b"x;"})  # type: ignore[dict-item]
    with pytest.raises(ShaderSourceError, match="bad shader file name"):
        lib.load("r.vert", replace={"../hook.glsl": "x;"})


# -- the app's shaders ------------------------------------------------------------------------
def app_programs() -> list[str]:
    return sorted(p.name for p in SHADER_DIR.iterdir() if p.suffix in (".vert", ".frag"))


def test_every_app_shader_loads_with_version_first() -> None:
    names = app_programs()
    assert "terrain.vert" in names and len(names) >= 14
    for name in names:
        text = load_shader(name)
        assert text.startswith("#version 330\n"), name
        assert not re.search(r"^\s*#\s*include", text, re.M), name
    assert build_shader("terrain.vert").pieces[0] == "terrain.vert"
    assert "displace.glsl" in build_shader("terrain.vert").pieces


def test_shared_chunks_are_written_once() -> None:
    """The log-depth formula, the hi/lo eye subtraction and the identity hook each live in
    one file, and every vertex shader that depth-tests uses the log-depth chunk."""
    files = {p.name: p.read_text() for p in SHADER_DIR.iterdir()}
    assert [n for n, t in files.items() if "log2(1.0 + w)" in t] == ["log_depth.glsl"]
    assert [n for n, t in files.items() if "- u_eye_hi" in t] == ["relative_position.glsl"]
    assert [n for n, t in files.items() if "vec3 gv_displace(" in t] == ["displace.glsl"]
    for name in ("terrain", "overlay_line", "overlay_billboard", "overlay_label", "overlay_object"):
        assert "gv_log_depth(" in files[f"{name}.vert"], name
        assert '#include "log_depth.glsl"' in files[f"{name}.vert"], name
    assert "gv_log_depth(" in files["overlay_tool.vert"]


def test_one_loader_and_no_string_splicing_of_shaders() -> None:
    """`load_shader` is defined once; no other module reads shader files or splices GLSL."""
    src = {p: p.read_text() for p in (ROOT / "globeview").rglob("*.py")}
    defs = [p.name for p, t in src.items() if re.search(r"^def (load_shader|_?shader)\(", t, re.M)]
    assert defs == ["shader_source.py"]
    readers = [p.name for p, t in src.items() if '"shaders"' in t or "'shaders'" in t]
    assert readers == ["shader_source.py"]
    assert not any("GV_DISPLACE" in t for t in src.values())
    assert SHADERS.read("terrain.vert") == (SHADER_DIR / "terrain.vert").read_text()


def test_every_shader_file_is_package_data() -> None:
    """The wheel carries the chunks and the collapse GLSL (pyproject's package-data globs)."""
    import tomllib
    from pathlib import PurePosixPath

    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"
    ]["globeview"]
    pkg = ROOT / "globeview"
    files = [p for p in SHADER_DIR.iterdir() if p.is_file()]
    files.append(pkg / "plugins" / "builtin" / "collapse" / "collapse.glsl")
    for path in files:
        rel = PurePosixPath(path.relative_to(pkg).as_posix())
        assert any(rel.match(g) for g in globs), rel


@pytest.mark.parametrize(
    "located",
    [
        "0:10003(15): error: x",
        "1:10003(2): error: x",
        "0(10003) : error C1008: x",
        "ERROR: 1:10003: x",
    ],
    ids=["mesa-source-0", "mesa", "nvidia", "amd"],
)
def test_compile_messages_are_mapped_to_pieces(tmp_path: Path, located: str) -> None:
    """Line K * 10000 + n is line n of piece K, in each driver's message format; a message
    that cites no known line gets the whole legend."""
    lib = library(
        tmp_path, {"r.vert": '#version 330\n#include "a.glsl"\n', "f.frag": "#version 330\n"}
    )
    vert = lib.build("r.vert", replace={"a.glsl": "x;\ny;\nz;"})
    frag = lib.build("f.frag")
    message = f"GLSL Compiler failed\n\nvertex_shader\n=============\n{located}\n"
    assert explain_sources(message, vertex=vert, fragment=frag) == (
        "vertex shader: 10003 = line 3 of <replace a.glsl>"
    )
    linker = "GLSL Linker failed\n\nProgram\n=======\nerror: vertex shader lacks `main'\n"
    assert explain_sources(linker, vertex=vert, fragment=frag) == (
        "GLSL pieces (line K*10000+n is line n of piece K): "
        "vertex 0 = r.vert, 1 = <replace a.glsl>; fragment 0 = f.frag"
    )
