"""Persistent application settings for plugins: a tiny backend protocol and a JSON file.

Keys are ``/``-separated strings (``plugins/enabled``, ``plugins/<name>/settings``), values
JSON-able (dicts, lists, str, numbers, bools, None). The Qt UI plugs a QSettings-backed object
into the same `SettingsBackend` protocol; headless code and tests use `JsonFileSettings` in
the user's config directory (see `config_dir`) or `MemorySettings`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import time
from collections.abc import Iterator, MutableMapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from globeview.errors import GlobeviewError
from globeview.fileio import OutputError, atomic_write_text, describe_os_error
from globeview.plugins.api import PluginKind, Setting

__all__ = [
    "ENABLED_KEY",
    "JsonFileSettings",
    "MemorySettings",
    "PluginSettings",
    "SettingTarget",
    "SettingsBackend",
    "TolerantSettings",
    "apply_overrides",
    "config_dir",
    "contribution_key",
    "default_settings",
    "describe_setting",
    "find_contribution",
    "find_setting",
    "parse_assignment",
    "parse_setting_value",
    "resolve_assignment",
    "resolve_plugin_args",
    "setting_problem",
    "settings_problems",
    "stored_values",
]

#: Key of the {plugin name: enabled} choices the user made.
ENABLED_KEY = "plugins/enabled"

log = logging.getLogger("globeview.plugins")


@runtime_checkable
class SettingsBackend(Protocol):
    """Get and set JSON-able values by key."""

    def get(self, key: str, default: Any = None) -> Any: ...

    def set(self, key: str, value: Any) -> None: ...


def config_dir() -> Path:
    """The user's globeview config directory.

    ``$GLOBEVIEW_CONFIG_DIR`` if set (tests point it at a tmp dir), else
    ``$XDG_CONFIG_HOME/globeview``, else ``~/.config/globeview``.
    """
    env = os.environ.get("GLOBEVIEW_CONFIG_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CONFIG_HOME")
    base = Path(xdg) if xdg else Path.home() / ".config"
    return base / "globeview"


class MemorySettings:
    """Settings held in a dict (nothing persists)."""

    def __init__(self, data: dict[str, Any] | None = None) -> None:
        self.data: dict[str, Any] = dict(data or {})

    def get(self, key: str, default: Any = None) -> Any:
        return json.loads(json.dumps(self.data[key])) if key in self.data else default

    def set(self, key: str, value: Any) -> None:
        self.data[key] = json.loads(json.dumps(value))  # JSON-able check and a private copy


class JsonFileSettings:
    """Settings in one JSON object file, re-read on every ``get`` and rewritten atomically on
    every ``set`` (`globeview.fileio.atomic_write_text`: a temporary beside it, fsynced, then
    renamed; so two registries on the same file see each other's changes and a full disk or
    Ctrl-C never leaves half a file).

    A missing file reads as empty; an unreadable or corrupt one too, so a damaged settings
    file never stops the application. The next write moves a corrupt file aside to
    ``settings.json.corrupt-<time>`` (never deleted: the user may want what was in it) and
    logs where. A write that fails (read-only config folder, full disk) raises a one-line
    `globeview.fileio.OutputError`.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def _read(self) -> tuple[dict[str, Any], bool]:
        """(the stored dict, whether an existing file could not be read as one)."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return {}, False
        except (OSError, ValueError):  # unreadable, not UTF-8
            return {}, self.path.is_file()
        try:
            data = json.loads(text)
        except ValueError:
            return {}, True
        return (data, False) if isinstance(data, dict) else ({}, True)

    def _load(self) -> dict[str, Any]:
        return self._read()[0]

    def get(self, key: str, default: Any = None) -> Any:
        return self._load().get(key, default)

    def set(self, key: str, value: Any) -> None:
        json.dumps(value)  # TypeError for a non-JSON value, before anything is touched
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # e.g. $GLOBEVIEW_CONFIG_DIR names a file
            folder = self.path.parent
            why = (
                f"{folder} is not a folder"
                if isinstance(exc, FileExistsError | NotADirectoryError)
                else describe_os_error(exc, folder)
            )
            raise OutputError(
                f"cannot write the settings file {self.path}: {why} (the config folder is "
                "$GLOBEVIEW_CONFIG_DIR, else $XDG_CONFIG_HOME/globeview, else ~/.config/globeview)"
            ) from None
        # Read-modify-write under an exclusive lock: two processes setting different keys at
        # once (`plugins set` beside a render, two windows) must not lose either update.
        with self._locked():
            data, corrupt = self._read()
            data[key] = value
            text = json.dumps(data, indent=2, sort_keys=True)
            if corrupt:
                stamp = time.strftime("%Y%m%d-%H%M%S")
                aside = self.path.with_name(f"{self.path.name}.corrupt-{stamp}")
                with contextlib.suppress(OSError):
                    os.replace(self.path, aside)
                    log.warning("settings file %s was unreadable; kept as %s", self.path, aside)
            atomic_write_text(self.path, text + "\n")

    @contextlib.contextmanager
    def _locked(self) -> Iterator[None]:
        """An exclusive advisory lock (``flock``) on ``settings.json.lock`` beside the file.
        Where there is no flock (Windows) or the lock file cannot be made (a read-only
        folder: the write itself then fails with its one-line reason), no lock."""
        try:
            import fcntl  # here: POSIX only, the ImportError is the Windows case
        except ImportError:
            yield
            return
        lock = self.path.with_name(self.path.name + ".lock")
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError:
            yield
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            yield
        finally:
            os.close(fd)  # releases the lock


class TolerantSettings:
    """A `SettingsBackend` for the window: writes go to ``backend``; one that fails (a
    read-only config folder, a full disk: a `GlobeviewError`) is logged once as a warning and
    the value kept in memory for the session, so a slider or a plugin switch never fails
    because the settings file cannot be written."""

    def __init__(self, backend: SettingsBackend) -> None:
        self.backend = backend
        self.unsaved: dict[str, Any] = {}
        self._warned = False

    @property
    def path(self) -> Path | None:
        return getattr(self.backend, "path", None)

    def get(self, key: str, default: Any = None) -> Any:
        if key in self.unsaved:
            return json.loads(json.dumps(self.unsaved[key]))
        return self.backend.get(key, default)

    def set(self, key: str, value: Any) -> None:
        try:
            self.backend.set(key, value)
        except GlobeviewError as exc:
            self.unsaved[key] = json.loads(json.dumps(value))
            if not self._warned:
                self._warned = True
                log.warning("plugin settings are not saved this session: %s", exc)
        else:
            self.unsaved.pop(key, None)


def default_settings() -> JsonFileSettings:
    """The JSON settings file in `config_dir` (``settings.json``)."""
    return JsonFileSettings(config_dir() / "settings.json")


class PluginSettings(MutableMapping[str, Any]):
    """One plugin's settings: a dict-like view of key ``plugins/<name>/settings`` in a backend.

    Every write stores the whole dict at once.
    """

    def __init__(self, backend: SettingsBackend, plugin_name: str) -> None:
        self._backend = backend
        self._key = f"plugins/{plugin_name}/settings"

    def _data(self) -> dict[str, Any]:
        data = self._backend.get(self._key, None)
        return dict(data) if isinstance(data, dict) else {}

    def __getitem__(self, key: str) -> Any:
        return self._data()[key]

    def __setitem__(self, key: str, value: Any) -> None:
        data = self._data()
        data[key] = value
        self._backend.set(self._key, data)

    def __delitem__(self, key: str) -> None:
        data = self._data()
        del data[key]
        self._backend.set(self._key, data)

    def __iter__(self) -> Iterator[str]:
        return iter(self._data())

    def __len__(self) -> int:
        return len(self._data())

    def __repr__(self) -> str:
        return f"PluginSettings({self._key!r}, {self._data()!r})"


# -- contribution settings from the command line ----------------------------------------------
def contribution_key(plugin: str, contribution: str) -> str:
    """The settings key holding one contribution's setting values (a dict), as the registry
    reads it when it creates the contribution and writes it on `PluginRegistry.configure`."""
    return f"plugins/{plugin}/contributions/{contribution}"


def parse_assignment(text: str, option: str = "--set") -> tuple[str, str, str]:
    """``"NAME.KEY=VALUE"`` -> (NAME, KEY, VALUE text). NAME is a contribution's name (it may
    hold dots and dashes: the key is after the last dot before '='). One-line
    `GlobeviewError` naming ``option`` for anything else."""
    left, eq, value = text.partition("=")
    name, dot, key = left.rpartition(".")
    if not eq or not dot or not name.strip() or not key.strip():
        raise GlobeviewError(
            f"{option} takes NAME.KEY=VALUE (e.g. collapse.ratio=0.3), not {text!r:.80}"
        )
    return name.strip(), key.strip(), value.strip()


def parse_setting_value(setting: Any, text: str) -> Any:
    """The value ``text`` (as typed on a command line) gives ``setting`` (an API `Setting`),
    checked strictly: unlike `Setting.coerce` (which clamps stored values so stale settings
    never break a plugin), a number outside min..max, a fraction for an integer, or a choice
    not offered is refused. Raises ValueError with a one-line reason."""
    kind = setting.type
    if kind == "choice":
        if text not in setting.choices:
            raise ValueError(f"{text!r:.40} is not offered")
        return text
    if kind == "bool":
        return setting.coerce(text)
    if kind not in ("int", "float"):
        raise ValueError(f"unknown setting type {kind!r}")
    try:
        num = float(text)
    except ValueError:
        raise ValueError(f"{text!r:.40} is not a number") from None
    if not math.isfinite(num):
        raise ValueError(f"{text!r:.40} is not a finite number")
    if kind == "int":
        if num != int(num):
            raise ValueError(f"{text!r:.40} is not a whole number")
        num = int(num)
    lo, hi = setting.min, setting.max
    if (lo is not None and num < lo) or (hi is not None and num > hi):
        lo_s = "-inf" if lo is None else _num(lo)
        hi_s = "inf" if hi is None else _num(hi)
        raise ValueError(f"{text} is outside {lo_s}..{hi_s}")
    return num


@dataclass
class SettingTarget:
    """A contribution's setting found by name (`find_setting`)."""

    plugin: str
    contribution: str
    instance: Any
    setting: Any  # the API `Setting`

    @property
    def label(self) -> str:
        return f"{self.contribution}.{self.setting.name}"

    def kind(self, registry: Any) -> str:
        """The contribution's kind ('lod', 'tool', 'layer') from its plugin's manifest."""
        manifest = registry.get(self.plugin).manifest
        return manifest.contribution(self.contribution).kind.value


def contribution_settings(registry: Any, instance: Any) -> tuple:
    """The `Setting`s a loaded contribution declares (reading them is plugin code: isolated;
    anything that is not a Setting is ignored)."""
    owner = registry.owner_of(instance)
    declared = registry.call(
        owner, lambda: tuple(getattr(instance, "settings", ()) or ()), default=()
    )
    return tuple(s for s in declared if isinstance(s, Setting))


def settings_problems(declared: Any) -> list[str]:
    """What is wrong with a contribution's ``settings`` declaration (for `plugins validate
    --import`): entries that are not `Setting`s, duplicate or non-identifier names, unknown
    types, min > max, a choice setting without choices, a default its own setting refuses.
    One short phrase per problem; [] when all is well."""
    problems: list[str] = []
    seen: set[str] = set()
    for s in tuple(declared or ()):
        if not isinstance(s, Setting):
            problems.append(f"settings holds a {type(s).__name__}, not a Setting")
            continue
        name = s.name if isinstance(s.name, str) else repr(s.name)
        if not isinstance(s.name, str) or not s.name.isidentifier():
            problems.append(f"setting name {name!r:.40} is not an identifier")
        if name in seen:
            problems.append(f"setting {name!r} declared twice")
        seen.add(name)
        if s.type not in ("float", "int", "bool", "choice"):
            problems.append(f"setting {name!r}: unknown type {s.type!r:.20}")
            continue
        if s.type == "choice" and not s.choices:
            problems.append(f"setting {name!r}: a choice with no choices")
        if s.min is not None and s.max is not None and s.min > s.max:
            problems.append(f"setting {name!r}: min {s.min} > max {s.max}")
        try:
            if s.type == "bool" and not isinstance(s.default, bool):
                raise ValueError(f"{s.default!r:.40} is not a boolean")
            if s.type in ("int", "float", "choice"):
                parse_setting_value(s, str(s.default))
        except ValueError as exc:
            problems.append(f"setting {name!r}: default {exc}")
    return problems


def find_contribution(registry: Any, name: str) -> list[tuple[str, Any]]:
    """(plugin, loaded contribution) of every enabled contribution called ``name`` (any
    kind), importing only the plugins that declare it. One-line `GlobeviewError` when none
    is usable, naming the known contributions or the failure."""
    declaring = [
        rec
        for rec in registry
        if rec.manifest is not None and any(c.name == name for c in rec.manifest.contributions)
    ]
    if not declaring:
        known = sorted(
            {c.name for rec in registry if rec.manifest for c in rec.manifest.contributions}
        )
        raise GlobeviewError(
            f"no plugin contribution named {name!r:.80} (known: {', '.join(known) or 'none'})"
        )
    found = []
    problems = []
    for rec in declaring:
        if not rec.enabled and rec.status != "failed":
            problems.append(
                f"plugin {rec.name} is disabled (`globeview plugins enable {rec.name}`)"
            )
            continue
        instance = registry.load_contribution(rec.name, name)
        if instance is None:
            why = registry.failure_of(name) or rec.error or "it did not load"
            problems.append(f"plugin {rec.name} failed: {why}")
            continue
        found.append((rec.name, instance))
    if not found:
        raise GlobeviewError(f"{name}: {'; '.join(problems)}")
    return found


def find_setting(registry: Any, name: str, key: str) -> SettingTarget:
    """Setting ``key`` of contribution ``name`` (see `find_contribution`); a one-line
    `GlobeviewError` naming the contribution's settings when it has no such key."""
    offered: list[str] = []
    for plugin, instance in find_contribution(registry, name):
        settings = contribution_settings(registry, instance)
        for s in settings:
            if s.name == key:
                return SettingTarget(plugin, name, instance, s)
        offered.extend(s.name for s in settings)
    if not offered:
        raise GlobeviewError(f"{name} has no settings")
    raise GlobeviewError(f"{name} has no setting {key!r:.60} (settings: {', '.join(offered)})")


def resolve_assignment(
    registry: Any, text: str, option: str = "--set"
) -> tuple[SettingTarget, Any]:
    """``"NAME.KEY=VALUE"`` -> (the setting, its checked value); one-line `GlobeviewError`
    naming ``option`` for a bad name, key or value."""
    name, key, value = parse_assignment(text, option)
    target = find_setting(registry, name, key)
    try:
        return target, parse_setting_value(target.setting, value)
    except ValueError as exc:
        raise GlobeviewError(
            f"{option} {target.label}: {setting_problem(target.setting, exc)}"
        ) from None


def setting_problem(setting: Any, exc: ValueError) -> str:
    """The reason without `Setting.coerce`'s own "setting 'x': " prefix, plus what is valid."""
    msg = str(exc)
    prefix = f"setting {setting.name!r}: "
    msg = msg[len(prefix) :] if msg.startswith(prefix) else msg
    return f"{msg} ({describe_setting(setting)})"


def describe_setting(setting: Any) -> str:
    """What values a setting takes, for messages and `plugins get`: ``float in 0.01..1``,
    ``one of fast, exact``, ``true or false``."""
    if setting.type == "bool":
        return "true or false"
    if setting.type == "choice":
        return "one of " + ", ".join(setting.choices)
    if setting.min is None and setting.max is None:
        return f"any {setting.type}"
    lo = "-inf" if setting.min is None else _num(setting.min)
    hi = "inf" if setting.max is None else _num(setting.max)
    return f"{setting.type} in {lo}..{hi}"


def _num(x: float) -> str:
    """A bound as a person writes it: 1000000, not 1e+06; 0.01."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def stored_values(backend: SettingsBackend, plugin: str, contribution: str) -> dict[str, Any]:
    """The setting values stored for a contribution ({} when none or not a dict)."""
    data = backend.get(contribution_key(plugin, contribution), {})
    return dict(data) if isinstance(data, dict) else {}


def apply_overrides(registry: Any, assignments: list[tuple[SettingTarget, Any]]) -> None:
    """Apply ``--set`` values for this run only: each contribution is configured with its
    stored values overlaid with the new ones (nothing is written to the settings file)."""
    merged: dict[int, tuple[SettingTarget, dict[str, Any]]] = {}
    for target, value in assignments:
        entry = merged.setdefault(
            id(target.instance),
            (target, stored_values(registry.settings, target.plugin, target.contribution)),
        )
        entry[1][target.setting.name] = value
    for target, values in merged.values():
        registry.invoke(target.instance, "configure", values)


def resolve_plugin_args(registry: Any, tool: str | None, sets: list[tuple[str, str]]) -> list:
    """Check a command line's ``--tool`` and ``--set`` (texts with the option each came from)
    against the plugins, importing only the plugins that declare the names: one-line
    `GlobeviewError` for an unknown or failed contribution, an unknown setting or a bad
    value. Returns the checked (`SettingTarget`, value) pairs for `apply_overrides`. `render`
    and `gui` check theirs with it before any work; the window applies them with it."""
    if tool is not None and not registry.offers(PluginKind.TOOL, tool):
        if any(  # declared, but by a disabled or failed plugin: say which and why
            rec.manifest is not None
            and any(
                c.kind == PluginKind.TOOL and c.name == tool for c in rec.manifest.contributions
            )
            for rec in registry
        ):
            find_contribution(registry, tool)  # raises, naming the plugin's state
        known = ", ".join(sorted(registry.declared(PluginKind.TOOL))) or "none"
        raise GlobeviewError(f"--tool: no enabled tool named {tool!r:.80} (tools: {known})")
    return [resolve_assignment(registry, text, option) for text, option in sets]
