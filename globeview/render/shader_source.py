"""The one loader of GLSL source: ``#include`` chunks, ``#define`` feature flags, hook text.

Every program in globeview is built from files in ``globeview/render/shaders``:

- ``#include "name.glsl"`` (alone on its line) is replaced by that file's text, itself
  resolved the same way. A chunk is included at most once per program (a second include of it
  is dropped, so two chunks may both include a third); a chunk that includes itself, directly
  or through others, is an error. Includes are resolved textually, before GLSL sees the code,
  so an ``#include`` inside ``#ifdef`` is resolved whether or not the branch is compiled.
- ``defines`` become ``#define NAME VALUE`` lines right after ``#version`` (which GLSL needs
  first): the terrain shader's optional parts are compiled in or out this way.
- ``replace`` swaps a chunk for text given by the caller, inserted verbatim (not searched for
  includes): the host puts a tool plugin's displacement GLSL in place of the identity
  ``displace.glsl`` this way. Such text may not contain ``#include "..."`` (moderngl would
  try to resolve it itself), a NUL (GL would cut the program there) or 10000 lines.

Each piece K of `ShaderSource.pieces` is numbered from line K * 10000 + 1 by a ``#line``
directive (the text after an include by one that restores the includer's numbering), so a
GLSL compiler message ``K:LLLLL(COL)`` points at line LLLLL % 10000 of piece LLLLL // 10000
(K, the source-string number, says the same, but Mesa reports some errors under 0);
`explain_sources` turns such a message into piece names and lines.

Errors (a missing chunk, an include cycle, a malformed include, a bad define or refused
replacement text) are one-line `ShaderSourceError`s naming the include chain.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

from globeview.errors import GlobeviewError

__all__ = [
    "SHADERS",
    "ShaderLibrary",
    "ShaderSource",
    "ShaderSourceError",
    "build_shader",
    "describe_pieces",
    "explain_sources",
    "load_shader",
    "source_legend",
]

#: Package and folder the shader files live in.
SHADER_PACKAGE = "globeview.render"
SHADER_DIR = "shaders"

# `#include "name"` alone on its line (leading/trailing blanks and a trailing // comment allowed).
_INCLUDE = re.compile(r"^[ \t]*#[ \t]*include\b(?P<rest>.*)$")
_INCLUDE_ARG = re.compile(r'^[ \t]*"(?P<name>[^"]*)"[ \t]*(//.*)?$')
# Chunk names are flat file names: no folders, no "..", nothing a path could escape with.
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,99}$")
# moderngl's Context.program resolves this pattern anywhere in the text (even in comments)
# from ctx.includes and raises KeyError when it is not there: none may reach it.
_MODERNGL_INCLUDE = re.compile(r'#include\s+"([^"]+)"')
# Line numbers are K * LINES_PER_PIECE + line in piece K, and K is also the source-string
# number: Mesa reports some errors under source 0 whatever #line said, but keeps the line.
LINES_PER_PIECE = 10_000
# Message locations: Mesa "K:LINE(COL): error", NVIDIA "K(LINE) : error", AMD and others
# "ERROR: K:LINE: ...".
_CITED = re.compile(r"(?<![\w.:(])(\d+)(?::(\d+)\(\d+\)|\((\d+)\)\s*:|:(\d+):)")
_VERSION = re.compile(r"^[ \t]*#[ \t]*version\b")
_DEFINE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")
_DEFINE_VALUE = re.compile(r"^[A-Za-z0-9_.+\-() ]{1,64}$")

DefineValue = bool | int | float | str


class ShaderSourceError(GlobeviewError):
    """Shader source cannot be assembled: a missing chunk, an include cycle, a bad define."""


@dataclass(frozen=True)
class ShaderSource:
    """Assembled GLSL text and the pieces its ``#line`` source numbers refer to.

    ``pieces[k]`` names the text of GLSL source-string number k: a chunk file name, or
    ``"<replace name>"`` for caller-given text that replaced chunk ``name``.
    """

    text: str
    pieces: tuple[str, ...]


class ShaderLibrary:
    """Shader files under one folder (the app's: globeview/render/shaders), read once each.

    Args:
        root: the folder (a path or an importlib.resources Traversable).
        label: how error messages name the folder.
    """

    def __init__(self, root: Traversable | Path, label: str | None = None) -> None:
        self.root = root
        self.label = label or str(root)
        self._texts: dict[str, str] = {}

    def read(self, name: str) -> str:
        """The text of file ``name`` (cached: the files ship with the package and do not
        change while the app runs). Raises ShaderSourceError if ``name`` is not a plain file
        name or there is no such file."""
        _check_name(name, (name,))
        text = self._texts.get(name)
        if text is None:
            try:
                text = self.root.joinpath(name).read_text(encoding="utf-8")
            except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
                raise ShaderSourceError(f"shader file {name!r} not found in {self.label}") from None
            except (OSError, UnicodeDecodeError) as exc:
                raise ShaderSourceError(f"shader file {name!r} cannot be read: {exc}") from None
            self._texts[name] = text
        return text

    def load(
        self,
        name: str,
        defines: Mapping[str, DefineValue] | None = None,
        replace: Mapping[str, str] | None = None,
    ) -> str:
        """GLSL text of shader ``name`` with its includes resolved and ``defines`` injected.

        Args:
            name: a file in the library's folder, e.g. ``"terrain.vert"``.
            defines: NAME -> value; ``True`` defines NAME as 1, ``False`` leaves it undefined
                (feature flags tested with ``#ifdef``), numbers and short tokens are written
                as they are.
            replace: chunk name -> GLSL text inserted verbatim wherever that chunk is
                included (each key must be a chunk the program really includes).
        """
        return self.build(name, defines, replace).text

    def build(
        self,
        name: str,
        defines: Mapping[str, DefineValue] | None = None,
        replace: Mapping[str, str] | None = None,
    ) -> ShaderSource:
        """`load` with the names of the pieces that ``#line`` source numbers refer to."""
        replace = dict(replace or {})
        for key, text in replace.items():
            _check_name(key, (name, key))
            if not isinstance(text, str):
                raise ShaderSourceError(
                    f"replacement for shader chunk {key!r} is {type(text).__name__}, not GLSL text"
                )
            if "\x00" in text or not _encodable(text):  # GL would cut the text at a NUL
                raise ShaderSourceError(
                    f"replacement for shader chunk {key!r} has a NUL or an unencodable character"
                )
            if _MODERNGL_INCLUDE.search(text):
                raise ShaderSourceError(
                    f"replacement for shader chunk {key!r} has an #include: hook text is "
                    "inserted verbatim (define what it needs itself)"
                )
        pieces: list[str] = []
        done: set[str] = set()
        body = self._expand(name, (name,), replace, pieces, done)
        unused = sorted(set(replace) - done)
        if unused:
            raise ShaderSourceError(
                f"{name} includes no shader chunk {unused[0]!r} to replace (its chunks: "
                f"{', '.join(sorted(done - {name})) or 'none'})"
            )
        stray = _MODERNGL_INCLUDE.search(body)
        if stray:  # e.g. in a comment: moderngl would fail on it with a KeyError
            raise ShaderSourceError(f"{name}: stray {stray.group(0)!r:.80} outside an include line")
        return ShaderSource(_inject_defines(body, defines or {}, name), tuple(pieces))

    def _expand(
        self,
        name: str,
        chain: tuple[str, ...],
        replace: Mapping[str, str],
        pieces: list[str],
        done: set[str],
    ) -> str:
        """``name``'s text with its includes expanded depth first (``chain``: who includes
        it, ending with ``name``)."""
        done.add(name)
        index = len(pieces)
        if name in replace:
            pieces.append(f"<replace {name}>")
            _check_length(replace[name], f"replacement for {name}")
            return f"{_line(index, 1)}{replace[name]}\n"
        text = self._read_in_chain(name, chain)
        _check_length(text, " -> ".join(chain))
        pieces.append(name)
        out: list[str] = []
        header_done = len(chain) > 1  # the root's first #line goes after its #version line
        if header_done:
            out.append(_line(index, 1))
        for lineno, line in enumerate(text.splitlines(), start=1):
            if not header_done and _VERSION.match(line):
                out.append(f"{line}\n{_line(index, lineno + 1)}")
                header_done = True
                continue
            m = _INCLUDE.match(line)
            if m is None:
                out.append(line + "\n")
                continue
            arg = _INCLUDE_ARG.match(m.group("rest"))
            if arg is None:
                raise ShaderSourceError(
                    f"malformed #include in {' -> '.join(chain)} line {lineno} "
                    '(expected #include "name.glsl")'
                )
            child = arg.group("name")
            _check_name(child, (*chain, child))
            if child in chain:
                raise ShaderSourceError(f"shader include cycle: {' -> '.join((*chain, child))}")
            if child in done:
                out.append("\n")  # already in this program (include once): keep the count
                continue
            out.append(self._expand(child, (*chain, child), replace, pieces, done))
            out.append(_line(index, lineno + 1))
        if not header_done:  # no #version line: number from the top
            out.insert(0, _line(index, 1))
        return "".join(out)

    def _read_in_chain(self, name: str, chain: tuple[str, ...]) -> str:
        try:
            return self.read(name)
        except ShaderSourceError as exc:
            if len(chain) == 1:
                raise
            raise ShaderSourceError(f"{exc} (included by {' -> '.join(chain[:-1])})") from None


#: The app's shaders: globeview/render/shaders (package data).
SHADERS = ShaderLibrary(
    resources.files(SHADER_PACKAGE).joinpath(SHADER_DIR), "globeview/render/shaders"
)


def load_shader(
    name: str,
    defines: Mapping[str, DefineValue] | None = None,
    replace: Mapping[str, str] | None = None,
) -> str:
    """GLSL text of the app's shader ``name`` (see `ShaderLibrary.load`)."""
    return SHADERS.load(name, defines, replace)


def build_shader(
    name: str,
    defines: Mapping[str, DefineValue] | None = None,
    replace: Mapping[str, str] | None = None,
) -> ShaderSource:
    """`load_shader` with piece names (see `ShaderLibrary.build`)."""
    return SHADERS.build(name, defines, replace)


def describe_pieces(source: ShaderSource) -> str:
    """'0 = terrain.vert, 1 = log_depth.glsl, ...': the legend of GLSL messages' K:LINE."""
    return ", ".join(f"{k} = {p}" for k, p in enumerate(source.pieces))


def explain_sources(message: str, **stages: ShaderSource) -> str:
    """Name the pieces a GLSL compiler ``message`` cites as ``K:LINE(COL)``, per stage.

    ``stages``: ``vertex=``, ``fragment=`` sources (moderngl heads each stage's messages with
    ``vertex_shader`` / ``fragment_shader``). Returns e.g. ``'vertex shader: 50003 = line 3
    of <replace displace.glsl>'``, or the whole `source_legend` when the message cites no
    line (a link error)."""
    stage: str | None = None
    notes: list[str] = []
    for line in message.splitlines():
        head = line.strip().removesuffix("_shader")
        if head in stages:
            stage = head
            continue
        if stage is None:
            continue
        pieces = stages[stage].pieces
        for m in _CITED.finditer(line):
            cited = next(g for g in m.groups()[1:] if g is not None)
            k, lineno = divmod(int(cited), LINES_PER_PIECE)
            if k < len(pieces):
                note = f"{stage} shader: {cited} = line {lineno} of {pieces[k]}"
                if note not in notes:
                    notes.append(note)
    return "; ".join(notes[:4]) if notes else source_legend(**stages)


def source_legend(**stages: ShaderSource) -> str:
    """One line naming each stage's pieces, e.g. ``source_legend(vertex=v, fragment=f)`` ->
    'GLSL pieces (line K*10000+n is line n of piece K): vertex 0 = terrain.vert, ...;
    fragment 0 = terrain.frag, ...'."""
    parts = "; ".join(f"{stage} {describe_pieces(src)}" for stage, src in stages.items())
    return f"GLSL pieces (line K*10000+n is line n of piece K): {parts}"


def _line(index: int, lineno: int) -> str:
    """The #line directive that numbers the next line as line ``lineno`` of piece ``index``."""
    return f"#line {index * LINES_PER_PIECE + lineno} {index}\n"


def _check_length(text: str, what: str) -> None:
    n = text.count("\n") + 1
    if n >= LINES_PER_PIECE:
        raise ShaderSourceError(f"{what} has {n} lines; a shader piece has at most 9999")


def _encodable(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:  # lone surrogates
        return False
    return True


def _check_name(name: object, chain: tuple[object, ...]) -> None:
    """Refuse anything but a plain file name (no folders, no "..")."""
    if not isinstance(name, str) or not _NAME.match(name) or ".." in name:
        where = f" (included by {' -> '.join(map(str, chain[:-1]))})" if len(chain) > 1 else ""
        raise ShaderSourceError(
            f"bad shader file name {name!r:.60}{where}: use a plain file name, no folders"
        )


def _inject_defines(text: str, defines: Mapping[str, DefineValue], name: str) -> str:
    lines = []
    for key, value in defines.items():
        if not isinstance(key, str) or not _DEFINE_NAME.match(key):
            raise ShaderSourceError(f"bad #define name {key!r:.60} for {name}")
        if key.startswith("GL_") or "__" in key:
            raise ShaderSourceError(f"#define name {key!r} for {name} is reserved by GLSL")
        if value is False:
            continue
        if value is True:
            shown = "1"
        elif isinstance(value, int | float) and not isinstance(value, bool):
            shown = repr(value)
            if not _DEFINE_VALUE.match(shown) or shown in ("nan", "inf", "-inf"):
                raise ShaderSourceError(f"#define {key} for {name}: {value!r} is not finite")
        elif isinstance(value, str) and _DEFINE_VALUE.match(value):
            shown = value
        else:
            raise ShaderSourceError(
                f"#define {key} for {name}: value {value!r:.60} is not a bool, number or "
                "short one-line token"
            )
        lines.append(f"#define {key} {shown}\n")
    if not lines:
        return text
    head, _, rest = text.partition("\n")
    if _VERSION.match(head):  # #version must stay the first line
        return f"{head}\n{''.join(lines)}{rest}"
    return "".join(lines) + text
