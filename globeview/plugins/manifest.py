"""Plugin manifests: the static TOML file that describes a plugin without running its code.

Format (all keys at the top level, plus one ``[[contributions]]`` table per contribution)::

    name = "fixed-level"                 # lower-case letters, digits, '-', '_', '.'
    version = "0.1.0"
    description = "Draws every visible tile at one fixed quadtree level."
    kinds = ["lod", "tool"]              # among 'lod', 'tool', 'layer'
    api_version = "1.0"                  # the globeview plugin API it targets

    [[contributions]]
    name = "fixed-level"                 # unique within the plugin
    kind = "lod"                         # one of the plugin's kinds
    target = "globeview_fixedlevel.provider:FixedLevelProvider"
    label = "Fixed level"                # optional, for menus
    # extensions = [".gpx"]              # layer contributions: file suffixes it opens

A tool contribution may declare commands: buttons and menu entries (optionally with a
keyboard shortcut) that call a method of the tool object, read here without importing it::

    [[contributions.commands]]
    name = "clear"                       # unique within the contribution
    label = "Clear points"               # optional (default: the name)
    shortcut = "Shift+X"                 # optional: modifiers Ctrl/Shift/Alt/Meta + one key
    method = "clear"                     # a public method of the tool, called with no argument

An entry point in group ``globeview.plugins`` points at the manifest as
``"package.path:file.toml"``: the manifest is the file ``file.toml`` inside the package's
directory. It is located with `importlib.util.find_spec` on the top-level package (which finds
a module without executing it) and the remaining path segments as directories, so reading
manifests never imports a plugin.
"""

from __future__ import annotations

import importlib.util
import re
import stat
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from globeview.errors import GlobeviewError
from globeview.plugins.api import API_VERSION, PluginKind

__all__ = [
    "Command",
    "Contribution",
    "Manifest",
    "ManifestError",
    "check_api_version",
    "locate_manifest",
    "parse_manifest",
    "read_manifest",
]

_NAME_RE = re.compile(r"^[a-z0-9][a-z0-9._-]*$")
_DOTTED = r"[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*"
_TARGET_RE = re.compile(rf"^{_DOTTED}:{_DOTTED}$")
_RESOURCE_RE = re.compile(rf"^({_DOTTED}):([\w.-]+\.toml)$")
_VERSION_RE = re.compile(r"^(\d+)\.(\d+)$")
_KINDS = tuple(k.value for k in PluginKind)
#: Largest manifest file read (a real one is well under 4 KiB).
MAX_MANIFEST_BYTES = 64 * 1024
#: Longest value of each string field (hostile manifests carry megabyte strings).
_MAX_FIELD_CHARS = {"description": 2000, "label": 200}
_DEFAULT_MAX_FIELD_CHARS = 200
#: Most commands one contribution may declare (a toolbar has room for a handful).
MAX_COMMANDS = 32
_METHOD_RE = re.compile(r"^[A-Za-z]\w{0,63}$")
_MODIFIERS = ("Ctrl", "Shift", "Alt", "Meta")
#: Named keys a shortcut may use besides one printable character (Qt's spelling).
_NAMED_KEYS = frozenset(
    [f"F{i}" for i in range(1, 25)]
    + ["Space", "Tab", "Backspace", "Return", "Enter", "Ins", "Del", "Home", "End"]
    + ["PgUp", "PgDown", "Left", "Right", "Up", "Down"]
)


def _short(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters, for error messages."""
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001  a plugin value whose __repr__ raises
        text = f"<{type(value).__name__}>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


class ManifestError(GlobeviewError):
    """A plugin manifest is missing, unreadable or invalid (one-line message)."""


@dataclass(frozen=True)
class Command:
    """A tool's manifest-declared command: the window shows a button and a Tools menu entry
    labelled ``label`` that call ``method`` (no arguments) on the tool object, activating the
    tool first; ``shortcut`` (Qt's spelling, e.g. ``"C"``, ``"Ctrl+Shift+M"``; "" for none)
    triggers it from the keyboard."""

    name: str
    label: str
    method: str
    shortcut: str = ""


@dataclass(frozen=True)
class Contribution:
    """One thing a plugin adds: ``target`` is ``"module:attribute"`` of its factory;
    ``commands`` are a tool's declared commands (empty for other kinds)."""

    name: str
    kind: PluginKind
    target: str
    label: str = ""
    commands: tuple[Command, ...] = ()
    #: Layer contributions: lower-case file suffixes it opens, with the dot (``(".gpx",)``),
    #: read without importing the plugin (file dispatch, the Open Overlay filter).
    extensions: tuple[str, ...] = ()

    @property
    def module(self) -> str:
        return self.target.partition(":")[0]

    @property
    def attribute(self) -> str:
        return self.target.partition(":")[2]


@dataclass(frozen=True)
class Manifest:
    """A validated plugin manifest. ``path`` is the file it was read from (None if parsed
    from text)."""

    name: str
    version: str
    description: str
    kinds: tuple[PluginKind, ...]
    api_version: str
    contributions: tuple[Contribution, ...]
    path: Path | None = None

    def contribution(self, name: str) -> Contribution:
        for c in self.contributions:
            if c.name == name:
                return c
        raise KeyError(f"plugin {self.name!r} has no contribution {name!r}")


def check_api_version(wanted: str, host: str = API_VERSION) -> None:
    """Raise ManifestError unless a plugin targeting API ``wanted`` runs on API ``host``:
    same major, and the plugin's minor not newer than the host's."""
    m = _VERSION_RE.match(wanted)
    if m is None:
        raise ManifestError(f"api_version {wanted!r} is not MAJOR.MINOR (e.g. {host!r})")
    h = _VERSION_RE.match(host)
    assert h is not None
    if m.group(1) != h.group(1):
        raise ManifestError(
            f"targets plugin API {wanted}, this globeview provides {host} (major versions differ)"
        )
    if int(m.group(2)) > int(h.group(2)):
        raise ManifestError(f"targets plugin API {wanted}, newer than this globeview's {host}")


def _str_field(data: dict[str, Any], key: str, where: str, required: bool = True) -> str:
    if key not in data:
        if required:
            raise ManifestError(f"{where}missing required field {key!r}")
        return ""
    value = data[key]
    if not isinstance(value, str):
        raise ManifestError(f"{where}field {key!r} must be a string, got {type(value).__name__}")
    if required and not value.strip():
        raise ManifestError(f"{where}field {key!r} is empty")
    limit = _MAX_FIELD_CHARS.get(key, _DEFAULT_MAX_FIELD_CHARS)
    if len(value) > limit:
        raise ManifestError(f"{where}field {key!r} is {len(value)} characters (at most {limit})")
    if any(ch in value for ch in "\n\r\x00") and key != "description":
        raise ManifestError(f"{where}field {key!r} must be one line")
    return value


def _kind(value: Any, where: str) -> PluginKind:
    if not isinstance(value, str) or value not in _KINDS:
        raise ManifestError(
            f"{where}unknown kind {_short(value)} (expected one of {', '.join(_KINDS)})"
        )
    return PluginKind(value)


_EXTENSION_RE = re.compile(r"^(\.[a-z0-9_+-]{1,16}){1,3}$")


def _extensions(c: dict[str, Any], kind: PluginKind, where: str) -> tuple[str, ...]:
    """A layer contribution's optional ``extensions = [".gpx", ...]`` (lower-cased)."""
    if "extensions" not in c:
        return ()
    raw = c["extensions"]
    if kind != PluginKind.LAYER:
        raise ManifestError(f"{where}'extensions' is for layer contributions only")
    if not isinstance(raw, list) or len(raw) > 32:
        raise ManifestError(f"{where}'extensions' must be a list of at most 32 suffixes")
    out: list[str] = []
    for e in raw:
        if not isinstance(e, str) or not _EXTENSION_RE.match(e.lower()):
            raise ManifestError(
                f"{where}extension {_short(e)} is not a file suffix with its dot (e.g. '.gpx')"
            )
        out.append(e.lower())
    return tuple(dict.fromkeys(out))


def normalize_shortcut(text: str) -> str:
    """A shortcut in canonical form (``"ctrl+shift+m"`` -> ``"Ctrl+Shift+M"``: modifiers in
    Ctrl, Shift, Alt, Meta order, then one key). Raises ValueError (one line) for anything
    else: several keys, an unknown key name, a repeated modifier, or Escape (reserved: it
    leaves the active tool)."""
    if text == "+":
        parts = ["+"]
    elif text.endswith("++"):  # "Ctrl++": the plus key
        parts = [*text[:-2].split("+"), "+"]
    else:
        parts = text.split("+")
    *mods, key = parts
    canon_mods: list[str] = []
    for m in mods:
        found = next((c for c in _MODIFIERS if c.lower() == m.strip().lower()), None)
        if found is None:
            raise ValueError(
                f"shortcut {_short(text)}: {_short(m)} is not one of Ctrl, Shift, Alt, Meta"
            )
        if found in canon_mods:
            raise ValueError(f"shortcut {_short(text)}: {found} given twice")
        canon_mods.append(found)
    key = key if key == " " else key.strip()
    if key.lower() in ("esc", "escape"):
        raise ValueError(f"shortcut {_short(text)}: Escape is reserved (it leaves the tool)")
    if len(key) == 1 and key.isprintable() and key != " " and key.isascii():
        key = key.upper()
    else:
        named = next((k for k in _NAMED_KEYS if k.lower() == key.lower()), None)
        if named is None:
            raise ValueError(
                f"shortcut {_short(text)}: {_short(key)} is not one key "
                "(a letter, digit or sign, F1..F24, Space, Tab, Return, Del, Home, Left, ...)"
            )
        key = named
    order = sorted(canon_mods, key=_MODIFIERS.index)
    return "+".join([*order, key])


def _commands(raw: Any, kind: PluginKind, where: str) -> tuple[Command, ...]:
    """The validated ``[[contributions.commands]]`` of one contribution."""
    if raw is None:
        return ()
    if kind != PluginKind.TOOL:
        raise ManifestError(f"{where}only tool contributions declare commands, not {kind.value}")
    if not isinstance(raw, list):
        raise ManifestError(
            f"{where}'commands' must be an array of tables ([[contributions.commands]])"
        )
    if len(raw) > MAX_COMMANDS:
        raise ManifestError(f"{where}{len(raw)} commands (at most {MAX_COMMANDS})")
    out: list[Command] = []
    for i, c in enumerate(raw):
        at = f"{where}command {i + 1}: "
        if not isinstance(c, dict):
            raise ManifestError(
                f"{at}must be a table with name, method and optional label, shortcut"
            )
        name = _str_field(c, "name", at)
        if not _NAME_RE.match(name):
            raise ManifestError(
                f"{at}name {_short(name)} must be lower-case letters, digits, '-', '_' or '.'"
            )
        if any(o.name == name for o in out):
            raise ManifestError(f"{at}duplicate command name {name!r}")
        method = _str_field(c, "method", at)
        if not _METHOD_RE.match(method):
            raise ManifestError(
                f"{at}method {_short(method)} must be the name of a public method of the tool"
            )
        label = _str_field(c, "label", at, required=False) or name
        shortcut = _str_field(c, "shortcut", at, required=False)
        if shortcut:
            try:
                shortcut = normalize_shortcut(shortcut)
            except ValueError as exc:
                raise ManifestError(f"{at}{exc}") from None
        unknown = sorted(set(c) - {"name", "label", "method", "shortcut"})
        if unknown:
            raise ManifestError(f"{at}unknown field {_short(unknown[0])}")
        out.append(Command(name, label, method, shortcut))
    return tuple(out)


def parse_manifest(data: dict[str, Any], path: Path | None = None) -> Manifest:
    """Validate a manifest's decoded TOML and return it; ManifestError names the first fault."""
    if not isinstance(data, dict):
        raise ManifestError("a manifest must be a TOML table")
    name = _str_field(data, "name", "")
    if not _NAME_RE.match(name):
        raise ManifestError(
            f"plugin name {_short(name)} must be lower-case letters, digits, '-', '_' or '.'"
        )
    version = _str_field(data, "version", "")
    description = _str_field(data, "description", "")
    api_version = _str_field(data, "api_version", "")
    check_api_version(api_version)

    if "kinds" not in data:
        raise ManifestError("missing required field 'kinds'")
    raw_kinds = data["kinds"]
    if isinstance(raw_kinds, str):
        raw_kinds = [raw_kinds]
    if not isinstance(raw_kinds, list) or not raw_kinds:
        raise ManifestError("field 'kinds' must be a non-empty list of 'lod', 'tool', 'layer'")
    kinds = tuple(dict.fromkeys(_kind(k, "") for k in raw_kinds))

    raw_contribs = data.get("contributions")
    if raw_contribs is None:
        raise ManifestError("missing required field 'contributions' (one [[contributions]] table)")
    if not isinstance(raw_contribs, list) or not raw_contribs:
        raise ManifestError("'contributions' must be a non-empty array of tables")
    if len(raw_contribs) > 256:
        raise ManifestError(f"{len(raw_contribs)} contributions (at most 256)")
    contribs: list[Contribution] = []
    seen: set[str] = set()
    for i, c in enumerate(raw_contribs):
        where = f"contribution {i + 1}: "
        if not isinstance(c, dict):
            raise ManifestError(f"{where}must be a table with name, kind and target")
        cname = _str_field(c, "name", where)
        if not _NAME_RE.match(cname):
            raise ManifestError(
                f"{where}name {_short(cname)} must be lower-case letters, digits, '-', '_' or '.'"
            )
        if cname in seen:
            raise ManifestError(f"{where}duplicate contribution name {cname!r}")
        seen.add(cname)
        ckind = _kind(_str_field(c, "kind", where), where)
        if ckind not in kinds:
            raise ManifestError(f"{where}kind {ckind.value!r} is not among the plugin's kinds")
        target = _str_field(c, "target", where)
        if not _TARGET_RE.match(target):
            raise ManifestError(
                f"{where}target {_short(target)} is not 'module:attribute' "
                "(e.g. 'pkg.mod:Provider')"
            )
        label = _str_field(c, "label", where, required=False) or cname
        extensions = _extensions(c, ckind, where)
        commands = _commands(c.get("commands"), ckind, where)
        contribs.append(
            Contribution(cname, ckind, target, label, commands=commands, extensions=extensions)
        )
    return Manifest(name, version, description, kinds, api_version, tuple(contribs), path)


def read_manifest(path: str | Path) -> Manifest:
    """Read and validate a manifest file. Errors are ManifestError naming the file."""
    p = Path(path)
    try:
        # A FIFO or device would block or stream forever: only regular files are read.
        if not stat.S_ISREG(p.stat().st_mode):
            kind = "a directory" if p.is_dir() else "not a regular file"
            raise ManifestError(f"{p}: cannot read manifest ({kind})")
        with p.open("rb") as f:
            raw = f.read(MAX_MANIFEST_BYTES + 1)
    except OSError as exc:
        raise ManifestError(f"{p}: cannot read manifest ({exc.strerror or exc})") from None
    if len(raw) > MAX_MANIFEST_BYTES:
        raise ManifestError(f"{p}: manifest larger than {MAX_MANIFEST_BYTES // 1024} KiB")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ManifestError(f"{p}: not UTF-8 text (byte {exc.start})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ManifestError(f"{p}: not valid TOML ({_short(str(exc), 120)})") from None
    except RecursionError:  # arrays nested thousands deep
        raise ManifestError(f"{p}: not valid TOML (nested too deeply)") from None
    try:
        return parse_manifest(data, p)
    except ManifestError as exc:
        raise ManifestError(f"{p}: {exc}") from None


def locate_manifest(reference: str) -> Path:
    """The manifest file an entry point value ``"package.path:file.toml"`` names.

    Finds the top-level package with `importlib.util.find_spec` (which locates it without
    executing it) and follows the remaining package names as directories, so no plugin code
    runs. Raises ManifestError when the reference is malformed or the file is absent.
    """
    m = _RESOURCE_RE.match(reference.strip()) if len(reference) < 500 else None
    if m is None:
        raise ManifestError(
            f"entry point value {_short(reference)} must be 'package:manifest.toml' "
            "(a TOML file inside the package)"
        )
    package, resource = m.group(1), m.group(2)
    top, *rest = package.split(".")
    try:
        spec = importlib.util.find_spec(top)
    except Exception as exc:  # noqa: BLE001  a broken finder or package metadata: this plugin's problem
        raise ManifestError(f"cannot locate package {top!r}: {_short(str(exc), 120)}") from None
    if spec is None:
        raise ManifestError(f"package {top!r} of manifest {reference!r} is not installed")
    locations = list(spec.submodule_search_locations or [])
    if not locations:
        raise ManifestError(f"{top!r} is a module, not a package holding {resource!r}")
    for loc in locations:
        candidate = Path(loc).joinpath(*rest, resource)
        if candidate.is_file():
            return candidate
    raise ManifestError(f"manifest {resource!r} not found in package {package!r}")
