"""Which layer type opens a file: dispatch over *all* enabled layer types, built-in or
installed, by declared extension and content sniffing.

Priority (documented in docs/plugins.md, "Drawing from a plugin"):

1. **An explicit choice**: ``render --layer TYPE:FILE`` (or ``layer_type=`` in
   `GlobeSession.add_overlay`) uses layer type TYPE and no other.
2. **Declared extensions**: the layer types whose suffixes (the manifest's
   ``extensions = [...]``; without one, the type's ``extensions`` attribute) end the file's
   name, case-insensitively, longest suffix first. Among those, installed plugins come before
   built-ins (a plugin may specialise a format the built-ins also read), then registry order.
   A candidate with a ``sniff(path) -> bool`` method takes the file when it returns True; one
   without ``sniff`` takes every file with its extension.
3. **Content sniffing**: when no candidate by extension took the file (an unknown or missing
   extension), every other enabled layer type with ``sniff`` is asked, in the same order.

No taker: a one-line `GlobeviewError` naming the installed layer types and their extensions,
and the types disabled on the way with why (a ``sniff`` that crashed, a type that did not
load). If a candidate's ``sniff`` raised a `GlobeviewError` (its format, but broken: invalid
GeoJSON, say) and nobody took the file, that more precise line is raised instead.

Sniffing runs plugin code under the registry's isolation: a ``sniff`` that crashes fails its
contribution (reported once) and counts as False.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from globeview.errors import GlobeviewError
from globeview.plugins.api import PluginKind

__all__ = [
    "LayerTypeInfo",
    "choose_layer_type",
    "layer_type_infos",
    "overlay_file_filter",
    "parse_layer_spec",
    "split_sublayer",
]

# One colon, not two: ``roads.gpkg::highways`` is a file's layer (split_sublayer), not a TYPE.
_SPEC_RE = re.compile(r"^([a-z0-9][a-z0-9._-]+):(?!:)(.+)$")


@dataclass(frozen=True)
class LayerTypeInfo:
    """An enabled layer type as dispatch sees it (from its manifest; ``extensions`` from the
    loaded object when the manifest declares none)."""

    name: str
    plugin: str
    label: str
    extensions: tuple[str, ...]
    builtin: bool


def parse_layer_spec(spec: str) -> tuple[str | None, str]:
    """``"TYPE:FILE"`` -> (TYPE, FILE); anything else -> (None, spec).

    TYPE is a contribution-like name of two or more characters (so ``C:\\x.tif`` stays a
    path), and a string naming an existing file is always a path (a file called
    ``vector:x.geojson`` opens as itself). ``FILE::LAYER`` is no TYPE (``wm.gpkg::trails``
    is the file wm.gpkg's layer trails)."""
    m = _SPEC_RE.match(spec)
    if m is None or Path(spec).exists():
        return None, spec
    return m.group(1), m.group(2)


def split_sublayer(text: str) -> tuple[str, str | None]:
    """``"FILE::LAYER"`` -> (FILE, LAYER), a layer inside a multi-layer file (a GeoPackage's
    table, a GPX file's tracks); anything else -> (text, None). A name that exists as it is
    stays whole (a file called ``a::b`` opens as itself)."""
    head, sep, layer = text.rpartition("::")
    if not sep or not head or not layer or Path(text).exists():
        return text, None
    return head, layer


def _object_extensions(registry: Any, name: str) -> tuple[str, ...]:
    obj = registry.find(PluginKind.LAYER, name)
    if obj is None:
        return ()
    raw = getattr(obj, "extensions", ())
    try:
        exts = tuple(str(e).lower() for e in raw)[:32]
    except Exception:  # noqa: BLE001  a plugin's hostile attribute: no extensions
        return ()
    return tuple(e for e in exts if e.startswith(".") and 1 < len(e) <= 50)


def layer_type_infos(registry: Any, load: bool = True) -> list[LayerTypeInfo]:
    """The enabled layer types in dispatch order: installed plugins first, then built-ins,
    each group in registry order; the first plugin declaring a name wins (as
    `PluginRegistry.find`). ``load``: import a type whose manifest declares no extensions to
    read its ``extensions`` attribute (False: such a type lists none)."""
    seen: set[str] = set()
    infos: list[LayerTypeInfo] = []
    for rec in list(registry):
        if rec.manifest is None or not rec.enabled or rec.status not in ("ok", "partial"):
            continue
        for c in rec.manifest.contributions:
            if c.kind != PluginKind.LAYER or c.name in seen:
                continue
            seen.add(c.name)
            exts = tuple(getattr(c, "extensions", ()) or ())
            if not exts and load:
                exts = _object_extensions(registry, c.name)
            infos.append(LayerTypeInfo(c.name, rec.name, c.label or c.name, exts, rec.builtin))
    return [i for i in infos if not i.builtin] + [i for i in infos if i.builtin]


def _suffix_match(path: Path, exts: tuple[str, ...]) -> int:
    """Length of the longest of ``exts`` the file name ends with (0: none)."""
    name = path.name.lower()
    return max((len(e) for e in exts if name.endswith(e) and len(name) > len(e)), default=0)


def _describe(infos: list[LayerTypeInfo]) -> str:
    if not infos:
        return "none"
    parts = []
    for i in infos:
        exts = " ".join(i.extensions[:6]) + (" ..." if len(i.extensions) > 6 else "")
        parts.append(f"{i.name} ({exts})" if exts else i.name)
    return ", ".join(parts)


#: Longest reason of a disabled type quoted in the no-taker line (the log has the rest).
_WHY_CHARS = 120


def _sniff(registry: Any, obj: Any, path: Path, errors: list[GlobeviewError]) -> bool | None:
    """True/False from the type's ``sniff``; None when it has none."""
    if not callable(getattr(obj, "sniff", None)):
        return None
    try:
        got = registry.invoke(obj, "sniff", str(path), default=False, user_errors=True)
    except GlobeviewError as exc:
        errors.append(exc)
        return False
    return got is True


def _no_taker(registry: Any, p: Path, infos: list[LayerTypeInfo], sniffed: set[str]) -> str:
    """The one line when no layer type opens ``p``: the types still enabled, then those
    disabled on the way (``sniffed``: the names whose ``sniff`` was called) and why. A type
    that failed must not be listed as installed: the user would think it had refused the
    file."""
    alive, dead = [], []
    for info in infos:
        why = registry.failure_of(info.name, PluginKind.LAYER)
        if why is None:
            alive.append(info)
            continue
        why = why if len(why) <= _WHY_CHARS else why[: _WHY_CHARS - 3] + "..."
        what = "its sniff failed" if info.name in sniffed else "failed"
        dead.append(f"{info.name} ({what}: {why})")
    disabled = f"; disabled: {', '.join(dead)}" if dead else ""
    return f"{p.name}: no layer type opens this file (installed: {_describe(alive)}{disabled})"


def choose_layer_type(registry: Any, path: str | Path, explicit: str | None = None) -> str:
    """The name of the layer type that opens ``path`` (see the module docstring for the
    priority). Raises `GlobeviewError` (one line) when none does."""
    p = Path(path)
    if not p.is_file():
        if p.is_dir():
            what = "is a directory, not a layer file"
        elif p.exists():  # a FIFO or a device would block or stream forever: never read
            what = "not a regular file"
        else:
            what = "no such file"
        raise GlobeviewError(f"{p.name or p}: {what}")
    # An explicit choice needs only the manifests' names: no plugin is imported for it.
    infos = layer_type_infos(registry, load=explicit is None)
    if explicit is not None:
        if not any(i.name == explicit for i in infos):
            raise GlobeviewError(
                f"no enabled layer type named {explicit!r:.60} (installed: {_describe(infos)})"
            )
        return explicit
    errors: list[GlobeviewError] = []
    by_ext = [(i, _suffix_match(p, i.extensions)) for i in infos]
    by_ext = sorted([t for t in by_ext if t[1]], key=lambda t: -t[1])  # stable: order kept
    tried: set[str] = set()
    sniffed: set[str] = set()
    for info, _ in by_ext:
        tried.add(info.name)
        obj = registry.find(PluginKind.LAYER, info.name)
        if obj is None:
            continue
        sniffed.add(info.name)
        verdict = _sniff(registry, obj, p, errors)
        if verdict is None or verdict:
            return info.name
    for info in infos:
        if info.name in tried:
            continue
        obj = registry.find(PluginKind.LAYER, info.name)
        if obj is None:
            continue
        sniffed.add(info.name)
        if _sniff(registry, obj, p, errors):
            return info.name
    if errors:
        raise errors[0]
    raise GlobeviewError(_no_taker(registry, p, infos, sniffed))


def overlay_file_filter(registry: Any) -> str:
    """The Open Overlay dialog's name filter (Qt syntax): every layer type's patterns, then
    one entry per layer type, then all files."""
    infos = layer_type_infos(registry)
    every: list[str] = []
    entries: list[str] = []
    for i in infos:
        pats = [f"*{e}" for e in i.extensions]
        every.extend(x for x in pats if x not in every)
        if pats:
            entries.append(f"{_filter_text(i.label)} ({' '.join(pats)})")
    head = [f"Overlays ({' '.join(every)})"] if every else []
    return ";;".join([*head, *entries, "All files (*)"])


def _filter_text(label: str) -> str:
    """A label safe inside a Qt filter entry (no parentheses or ';;')."""
    return re.sub(r"[();]", " ", label).strip() or "layer"
