"""The plugin registry: discovery, enable/disable, lazy loading and failure isolation.

Discovery reads the manifests named by the entry points of group ``globeview.plugins``
(`importlib.metadata`) — the built-ins ship through the same group from globeview's own
pyproject — and never imports plugin code. A contribution's module is imported the first time
the host asks for it (`load_contribution`, `lod_providers`, `tools`, `layer_types`), and only
if its plugin is enabled.

Isolation: every call into plugin code goes through `PluginRegistry.call` (or `invoke`). An
exception there fails the **contribution** it came from for this session (that contribution is
dropped, so the host stops calling it; the plugin's other contributions keep working and the
plugin's status reads 'partial'), is logged with its traceback to the ``globeview.plugins``
logger, and the call returns a default. Once every contribution of a plugin has failed, or
when the failure cannot be pinned on one contribution (an invalid manifest), the plugin as a
whole is 'failed'. A failure found by the host itself (e.g. a displacement shader that does
not compile) is reported with `fail` (the contribution) or `report_failure`. A failure is not
persisted: the next start tries the plugin again. The user's enable/disable choices are
persisted in the settings backend (``plugins/enabled``); plugins the user never touched are
enabled (built-in or installed with pip alike).

Isolation covers every `BaseException` raised by plugin code — ``SystemExit``,
``GeneratorExit``, a ``KeyboardInterrupt`` the plugin raises itself — except a real Ctrl-C: the
host installs a SIGINT handler (`install_sigint_marker`) that counts the signals it delivers,
and a KeyboardInterrupt escaping plugin code is re-raised only when a SIGINT arrived during
that call. Frame-path calls (``budgeted=True``) are timed; see `Budget`. The failure is logged
as one line at WARNING on ``globeview.plugins`` and its traceback at DEBUG (and kept on the
record, `PluginRecord.traceback`), so a terminal sees one line, never a traceback.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.metadata as md
import logging
import math
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

from globeview.errors import GlobeviewError
from globeview.paths import log_path
from globeview.plugins.api import LodProvider, PluginContext, PluginKind, RendererHooks, Tool
from globeview.plugins.manifest import Manifest, ManifestError, locate_manifest, read_manifest
from globeview.plugins.settings import (
    ENABLED_KEY,
    PluginSettings,
    SettingsBackend,
    default_settings,
)

__all__ = [
    "BUDGET_MS_KEY",
    "BUDGET_OVERRUNS_KEY",
    "BUDGET_POLICY_KEY",
    "ENTRY_POINT_GROUP",
    "Budget",
    "ContributionFailure",
    "LoadedContribution",
    "PluginRecord",
    "PluginRegistry",
    "PluginTimeout",
    "install_sigint_marker",
]

#: Entry point group plugins register under.
ENTRY_POINT_GROUP = "globeview.plugins"
#: Distribution whose entry points are the built-in plugins.
BUILTIN_DISTRIBUTION = "globeview"

log = logging.getLogger("globeview.plugins")

#: 'partial': enabled, and some (not all) of its contributions failed this session.
Status = Literal["ok", "partial", "disabled", "failed"]
T = TypeVar("T")

# Methods a contribution of each kind must have.
_REQUIRED_METHODS: dict[PluginKind, tuple[str, ...]] = {
    PluginKind.LOD: ("select",),
    PluginKind.TOOL: ("on_mouse", "on_key", "overlay"),
    PluginKind.LAYER: ("open",),
}


#: Settings keys of the frame-path time budget (see `Budget`).
BUDGET_MS_KEY = "plugins/budget_ms"
BUDGET_OVERRUNS_KEY = "plugins/budget_overruns"
BUDGET_POLICY_KEY = "plugins/budget_policy"
#: Methods called on the UI thread every frame or input event: timed against the budget
#: (`invoke`). Not ``displacement_numpy``: providers call it inside their own ``select``.
FRAME_PATH_METHODS = frozenset({"select", "overlay", "displacement_uniforms", "on_mouse", "on_key"})
#: Longest error text kept on a record or logged (hostile plugins raise huge messages).
MAX_MESSAGE_CHARS = 300


class PluginTimeout(Exception):
    """A plugin's frame-path calls overran the time budget too many times in a row."""


def describe_exception(exc: BaseException) -> str:
    """``"ExcType: message"`` on one line, at most `MAX_MESSAGE_CHARS` characters."""
    try:
        msg = " ".join(str(exc).split())
    except Exception:  # noqa: BLE001  a plugin's exception whose __str__ itself raises
        msg = "<unprintable message>"
    text = f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__
    if len(text) > MAX_MESSAGE_CHARS:
        text = text[: MAX_MESSAGE_CHARS - 3] + "..."
    return text


# -- telling a real Ctrl-C from a KeyboardInterrupt raised by plugin code ----------------------
_sigint_count = 0
_sigint_lock = threading.Lock()
_marker_installed = False


def _counting_sigint_handler(signum: int, frame: Any) -> None:
    """SIGINT handler: count the signal, then raise KeyboardInterrupt as Python's default
    handler does."""
    global _sigint_count
    _sigint_count += 1
    raise KeyboardInterrupt


def install_sigint_marker() -> bool:
    """Make Ctrl-C countable, so `PluginRegistry.call` can tell the user's interrupt (re-raised)
    from a KeyboardInterrupt that plugin code raised itself (a plugin failure).

    Replaces Python's default SIGINT handler (`signal.default_int_handler`) by one that counts
    the signal and then raises KeyboardInterrupt exactly as the default does. Leaves any other
    handler (SIG_DFL, SIG_IGN, an application's own) alone: with those a Ctrl-C raises no
    KeyboardInterrupt into plugin code. Only possible from the main thread; idempotent.
    Returns True when the counting handler is in place.
    """
    global _marker_installed
    with _sigint_lock:
        if _marker_installed:
            return signal.getsignal(signal.SIGINT) is _counting_sigint_handler
        if threading.current_thread() is not threading.main_thread():
            return False
        try:
            if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
                return False
            signal.signal(signal.SIGINT, _counting_sigint_handler)
        except (ValueError, OSError):  # not the main interpreter / no signals here
            return False
        _marker_installed = True
        return True


def _not_ready(exc: BaseException) -> bool:
    """Whether ``exc`` is a remote tile not fetched yet (`TileNotReady`), imported only then
    (the registry serves `globeview plugins` too, which reads no terrain)."""
    from globeview.terrain.store.backend import TileNotReady

    return isinstance(exc, TileNotReady)


def sigint_count() -> int:
    """How many SIGINTs the counting handler has delivered in this process."""
    return _sigint_count


@dataclass
class Budget:
    """The time budget of frame-path plugin calls (``select``, a tool's per-frame hooks).

    Attributes:
        ms: milliseconds one call may take (<= 0: no budget).
        overruns: consecutive overruns after which the ``disable`` policy disables the plugin.
        policy: what ``overruns`` consecutive overruns do: 'disable' the plugin (the window:
            a slow provider would freeze it) or 'warn' (headless renders and benchmarks: one
            warning line per plugin, the plugin keeps running).
    """

    # 1 s, not a frame's 33 ms: a built-in provider rebuilding its meshes on llvmpipe under
    # load takes a few hundred ms a call (quadtree-clod ~200 ms at 1280x720), and a slow
    # machine must not cost the user a built-in. Five calls in a row over 1 s still catch a
    # provider that freezes the window.
    ms: float = 1000.0
    overruns: int = 5
    policy: Literal["warn", "disable"] = "warn"


@dataclass
class LoadedContribution:
    """A created contribution and where it came from."""

    plugin: str
    name: str
    kind: PluginKind
    label: str
    instance: Any


@dataclass
class ContributionFailure:
    """Why one contribution failed this session.

    Attributes:
        kind: the contribution's kind.
        error: ``"ExcType: message"``, one line.
        traceback: the full traceback text (also in the log file).
    """

    kind: PluginKind
    error: str
    traceback: str = field(default="", repr=False)


@dataclass
class PluginRecord:
    """What the registry knows about one plugin.

    Attributes:
        name: the plugin's name (the entry point's name; the manifest must agree).
        manifest: the validated manifest, or None when it could not be read.
        source: where it comes from: ``"<distribution> <version>"`` or a manifest path.
        builtin: shipped with globeview.
        enabled: the user's choice (False also after the whole plugin failed this session).
        status: 'ok' (enabled, no failure), 'partial' (enabled; some contributions failed,
            the others work), 'disabled' (by the user) or 'failed' (nothing of it works).
        error: when 'failed' or 'partial': ``"ExcType: message"`` (or the manifest problem);
            for a plugin of several contributions, ``"NAME: ExcType: message"`` for each
            failed contribution, joined by ``"; "``.
        failures: contribution name -> `ContributionFailure`, for this session.
    """

    name: str
    manifest: Manifest | None
    source: str
    builtin: bool = False
    enabled: bool = True
    status: Status = "ok"
    error: str | None = None
    traceback: str | None = field(default=None, repr=False)
    context: PluginContext | None = field(default=None, repr=False)
    loaded: dict[str, LoadedContribution] = field(default_factory=dict, repr=False)
    failures: dict[str, ContributionFailure] = field(default_factory=dict)
    # Consecutive frame-budget overruns, per contribution ("" for calls not tied to one).
    overruns: dict[str, int] = field(default_factory=dict, repr=False)
    budget_warned: bool = field(default=False, repr=False)

    @property
    def version(self) -> str:
        return self.manifest.version if self.manifest else ""

    @property
    def kinds(self) -> tuple[str, ...]:
        return tuple(k.value for k in self.manifest.kinds) if self.manifest else ()

    def contribution_status(self, name: str) -> Status:
        """The state of contribution ``name``: 'failed' when it (or the whole plugin) failed,
        'disabled' when the plugin is disabled, else 'ok'."""
        if name in self.failures or self.status == "failed":
            return "failed"
        return "disabled" if not self.enabled else "ok"

    def contribution_active(self, name: str) -> bool:
        """True when the plugin is enabled, and neither it nor contribution ``name`` failed."""
        return self.enabled and self.status in ("ok", "partial") and name not in self.failures

    def as_dict(self) -> dict[str, Any]:
        """JSON-able summary (what ``globeview plugins list --json`` prints); each
        contribution carries its own ``status`` and ``error``."""
        return {
            "name": self.name,
            "version": self.version,
            "kinds": list(self.kinds),
            "description": self.manifest.description if self.manifest else "",
            "api_version": self.manifest.api_version if self.manifest else "",
            "enabled": self.enabled,
            "status": self.status,
            "error": self.error,
            "traceback": self.traceback,
            "builtin": self.builtin,
            "source": self.source,
            "contributions": [
                {
                    "name": c.name,
                    "kind": c.kind.value,
                    "target": c.target,
                    "label": c.label,
                    "status": self.contribution_status(c.name),
                    "error": self.failures[c.name].error if c.name in self.failures else None,
                }
                for c in (self.manifest.contributions if self.manifest else ())
            ],
        }


class PluginRegistry:
    """All known plugins, their state, and the contributions of the enabled ones.

    Args:
        settings: where enable/disable choices and per-plugin settings persist
            (default: the JSON file in the user's config directory).
        scene, terrain, camera, renderer: what `PluginContext` hands plugins; `attach`
            changes them later.
        budget_policy: what a frame-path overrun does unless the settings say otherwise
            (``plugins/budget_policy``): 'warn' (default; headless) or 'disable' (the window).
    """

    def __init__(
        self,
        settings: SettingsBackend | None = None,
        *,
        scene: Any = None,
        terrain: Any = None,
        camera: Any = None,
        renderer: RendererHooks | None = None,
        budget_policy: Literal["warn", "disable"] = "warn",
    ) -> None:
        self.settings: SettingsBackend = settings if settings is not None else default_settings()
        install_sigint_marker()
        self.budget = self._read_budget(budget_policy)
        self._host: dict[str, Any] = {
            "scene": scene,
            "terrain": terrain,
            "camera": camera,
            "renderer": renderer,
        }
        self.records: dict[str, PluginRecord] = {}
        # id(instance) -> (plugin name, instance, contribution name) of every contribution
        # ever created (the reference keeps ids unique); _live: the ids of those still loaded.
        self._owners: dict[int, tuple[str, Any, str]] = {}
        self._live: set[int] = set()

    def _read_budget(self, default_policy: Literal["warn", "disable"]) -> Budget:
        """The `Budget` from the settings (``plugins/budget_ms``, ``plugins/budget_overruns``,
        ``plugins/budget_policy``); values of the wrong type or range are ignored."""
        b = Budget(policy=default_policy)
        ms = self.settings.get(BUDGET_MS_KEY)
        if isinstance(ms, int | float) and not isinstance(ms, bool) and math.isfinite(ms):
            b.ms = float(ms)
        n = self.settings.get(BUDGET_OVERRUNS_KEY)
        if isinstance(n, int) and not isinstance(n, bool) and n >= 1:
            b.overruns = n
        policy = self.settings.get(BUDGET_POLICY_KEY)
        if policy in ("warn", "disable"):
            b.policy = policy
        return b

    # -- discovery ---------------------------------------------------------------------------
    def discover(self, paths: Iterable[str | Path] = ()) -> PluginRegistry:
        """Find the plugins of the entry point group (and manifest files in ``paths``).

        Reads manifests only; imports no plugin code. Replaces what was known before.
        Returns self.
        """
        self.records = {}
        self._owners = {}
        self._live = set()
        seen: set[tuple[str, str]] = set()
        eps = sorted(
            _plugin_entry_points(), key=lambda e: (_dist_name(e) != BUILTIN_DISTRIBUTION, e.name)
        )
        for ep in eps:
            if (ep.name, ep.value) in seen:  # the same distribution found twice on sys.path
                continue
            seen.add((ep.name, ep.value))
            try:
                self._discover_one(ep)
            except Exception as exc:  # noqa: BLE001  hostile metadata: one plugin's problem, not discovery's
                self._add_invalid(_clip(ep.name), ep.value, describe_exception(exc), False)
        for p in paths:
            self.add_path(p)
        return self

    def _discover_one(self, ep: md.EntryPoint) -> None:
        dist = ep.dist
        try:
            source = f"{dist.metadata['Name']} {dist.version}" if dist else ep.value
        except Exception:  # noqa: BLE001  unreadable METADATA: the entry point still names the manifest
            source = ep.value
        builtin = _dist_name(ep) == BUILTIN_DISTRIBUTION
        try:
            manifest = read_manifest(locate_manifest(ep.value))
            if manifest.name != ep.name:
                raise ManifestError(
                    f"entry point name {_clip(ep.name)!r} differs from manifest name "
                    f"{manifest.name!r}"
                )
        except ManifestError as exc:
            self._add_invalid(_clip(ep.name), source, str(exc), builtin)
            return
        self._add(manifest, source, builtin)

    def add_path(self, path: str | Path) -> PluginRecord:
        """Register the plugin described by a manifest file (its targets must be importable
        from sys.path). An invalid manifest gives a 'failed' record named after the file."""
        p = Path(path)
        try:
            manifest = read_manifest(p)
        except ManifestError as exc:
            return self._add_invalid(p.stem, str(p), str(exc), False)
        return self._add(manifest, str(p), False)

    def _add(self, manifest: Manifest, source: str, builtin: bool) -> PluginRecord:
        name = manifest.name
        if name in self.records:
            other = self.records[name].source
            return self._add_invalid(
                f"{name} ({source})", source, f"duplicate plugin name {name!r}: {other}", builtin
            )
        enabled = self._stored_choice(name, default=True)
        rec = PluginRecord(
            name, manifest, source, builtin, enabled, "ok" if enabled else "disabled"
        )
        self.records[name] = rec
        return rec

    def _add_invalid(self, name: str, source: str, error: str, builtin: bool) -> PluginRecord:
        error = _clip(" ".join(error.split()), MAX_MESSAGE_CHARS)
        rec = PluginRecord(name, None, source, builtin, False, "failed", error)
        self.records[name] = rec
        # INFO, not WARNING: every command discovers every plugin, and a broken one nobody
        # asked for must not print into unrelated commands; `plugins list` shows it.
        log.info("plugin %s disabled: invalid manifest: %s", name, error)
        return rec

    # -- state -------------------------------------------------------------------------------
    def __iter__(self):
        return iter(self.records.values())

    def __len__(self) -> int:
        return len(self.records)

    def __contains__(self, name: object) -> bool:
        return name in self.records

    def get(self, name: str) -> PluginRecord:
        """The record of plugin ``name``; KeyError names the known plugins."""
        try:
            return self.records[name]
        except KeyError:
            known = ", ".join(sorted(self.records)) or "none"
            raise KeyError(f"no plugin named {name!r} (known: {known})") from None

    def _stored_choice(self, name: str, default: bool) -> bool:
        choices = self.settings.get(ENABLED_KEY, {})
        if isinstance(choices, dict) and isinstance(choices.get(name), bool):
            return choices[name]
        return default

    def _store_choice(self, name: str, enabled: bool) -> None:
        choices = self.settings.get(ENABLED_KEY, {})
        choices = dict(choices) if isinstance(choices, dict) else {}
        choices[name] = enabled
        self.settings.set(ENABLED_KEY, choices)

    def enable(self, name: str) -> PluginRecord:
        """Enable a plugin (persisted). Clears a failure of this session, so its
        contributions are tried again. A plugin with an invalid manifest stays failed."""
        rec = self.get(name)
        if rec.manifest is None:
            return rec
        self._store_choice(name, True)
        rec.enabled, rec.status, rec.error, rec.traceback = True, "ok", None, None
        rec.failures.clear()
        rec.overruns, rec.budget_warned = {}, False
        return rec

    def disable(self, name: str) -> PluginRecord:
        """Disable a plugin (persisted) and drop its loaded contributions."""
        rec = self.get(name)
        if rec.manifest is not None:
            self._store_choice(name, False)
        self._unload(rec)
        rec.enabled = False
        if rec.status != "failed":
            rec.status = "disabled"
        return rec

    def _unload(self, rec: PluginRecord, only: str | None = None) -> None:
        """Drop the loaded contributions of ``rec`` (only contribution ``only`` if given);
        a tool is deactivated first."""
        names = [only] if only is not None else list(rec.loaded)
        for name in names:
            lc = rec.loaded.pop(name, None)
            if lc is None:
                continue
            self._live.discard(id(lc.instance))
            if isinstance(lc.instance, Tool):
                before = _sigint_count
                try:
                    lc.instance.deactivate()
                except BaseException as exc:  # a failing cleanup must not stop the unload
                    if _is_user_interrupt(exc, before):
                        raise
                    log.debug(
                        "plugin %s: deactivate failed: %s",
                        rec.name,
                        describe_exception(exc),
                        exc_info=True,
                    )

    # -- host objects --------------------------------------------------------------------
    def attach(self, **host: Any) -> None:
        """Change what contexts hand plugins: any of scene, terrain, camera, renderer."""
        unknown = set(host) - set(self._host)
        if unknown:
            raise TypeError(f"unknown host objects: {sorted(unknown)}")
        self._host.update(host)
        for rec in self.records.values():
            if rec.context is not None:
                for k, v in host.items():
                    setattr(rec.context, k, v)

    def context(self, name: str) -> PluginContext:
        """The `PluginContext` of plugin ``name`` (created on first use)."""
        rec = self.get(name)
        if rec.context is None:
            from globeview.plugins.api import NullRendererHooks

            rec.context = PluginContext(
                name=name,
                scene=self._host["scene"],
                terrain=self._host["terrain"],
                camera=self._host["camera"],
                renderer=self._host["renderer"] or NullRendererHooks(),
                settings=PluginSettings(self.settings, name),
                logger=logging.getLogger(f"globeview.plugins.{name}"),
                host=self,  # PluginContext.lod_provider delegates through this registry
            )
        return rec.context

    # -- loading -----------------------------------------------------------------------------
    def load_contribution(self, plugin: str, name: str) -> Any | None:
        """The object of contribution ``name`` of ``plugin``, created on first request.

        Imports the target module, calls the factory with the plugin's context, checks the
        object has the methods of its kind, and applies the stored setting values
        (``configure``). Returns None if the plugin is disabled or failed, or this contribution
        failed; any error on the way fails this contribution (see `report_failure`) and
        returns None — the plugin's other contributions are not affected.
        """
        rec = self.get(plugin)
        if rec.manifest is None or not rec.contribution_active(name):
            return None
        if name in rec.loaded:
            return rec.loaded[name].instance
        contrib = rec.manifest.contribution(name)
        before = _sigint_count
        try:
            module = importlib.import_module(contrib.module)
            factory: Any = module
            for part in contrib.attribute.split("."):
                factory = getattr(factory, part)
            instance = factory(self.context(plugin))
            missing = [
                m
                for m in _REQUIRED_METHODS[contrib.kind]
                if not callable(getattr(instance, m, None))
            ]
            if missing:
                raise TypeError(
                    f"{contrib.target} made a {type(instance).__name__} without "
                    f"{', '.join(missing)}(), not a {contrib.kind.value} contribution"
                )
            if not getattr(instance, "name", ""):
                with contextlib.suppress(AttributeError):
                    instance.name = contrib.name
            configure = getattr(instance, "configure", None)
            if callable(configure):
                stored = self.settings.get(f"plugins/{plugin}/contributions/{name}", {})
                configure(stored if isinstance(stored, dict) else {})
        except BaseException as exc:  # SystemExit from an import is the plugin's fault too
            if _is_user_interrupt(exc, before):
                raise
            self.report_failure(plugin, exc, contribution=name)
            return None
        rec.loaded[name] = LoadedContribution(plugin, name, contrib.kind, contrib.label, instance)
        self._owners[id(instance)] = (plugin, instance, name)
        self._live.add(id(instance))
        return instance

    def contributions(self, kind: PluginKind | str) -> list[LoadedContribution]:
        """The loaded contributions of ``kind`` from all enabled plugins (loading them now).

        When two plugins contribute the same name, the first (built-ins first, then by plugin
        name) wins and the other is skipped with a logged warning.
        """
        kind = PluginKind(kind)
        out: list[LoadedContribution] = []
        names: set[str] = set()
        for rec in list(self.records.values()):
            if rec.manifest is None:
                continue
            for c in rec.manifest.contributions:
                if c.kind != kind or not rec.contribution_active(c.name):
                    continue
                if c.name in names:
                    log.warning(
                        "plugin %s: %s %r already provided; skipped", rec.name, kind, c.name
                    )
                    continue
                if self.load_contribution(rec.name, c.name) is None:
                    continue  # this contribution failed; the plugin's others still load
                names.add(c.name)
                out.append(rec.loaded[c.name])
        return out

    def find(self, kind: PluginKind | str, name: str) -> Any | None:
        """The contribution ``name`` of ``kind``, loading only the plugin that declares it
        (the manifests say which), so asking for one provider imports no other plugin.

        The same precedence as `contributions`: the first enabled plugin declaring it wins;
        if that one fails to load, the next one declaring it is tried. None if no enabled
        plugin provides it."""
        kind = PluginKind(kind)
        for rec in list(self.records.values()):
            if rec.manifest is None or not rec.contribution_active(name):
                continue
            if any(c.kind == kind and c.name == name for c in rec.manifest.contributions):
                instance = self.load_contribution(rec.name, name)
                if instance is not None:
                    return instance
        return None

    def offers(self, kind: PluginKind | str, name: str) -> bool:
        """True when an enabled plugin's manifest declares contribution ``name`` of ``kind``
        (nothing is imported)."""
        kind = PluginKind(kind)
        return any(
            rec.manifest is not None
            and rec.contribution_active(name)
            and any(c.kind == kind and c.name == name for c in rec.manifest.contributions)
            for rec in self.records.values()
        )

    def declared(self, kind: PluginKind | str) -> list[str]:
        """Names of the contributions of ``kind`` the enabled plugins declare (from their
        manifests; nothing is imported), in precedence order without duplicates."""
        kind = PluginKind(kind)
        names: dict[str, None] = {}
        for rec in self.records.values():
            if rec.manifest is not None:
                for c in rec.manifest.contributions:
                    if c.kind == kind and rec.contribution_active(c.name):
                        names.setdefault(c.name)
        return list(names)

    def lod_providers(self) -> dict[str, LodProvider]:
        """Contribution name -> LOD provider, from the enabled plugins."""
        return {c.name: c.instance for c in self.contributions(PluginKind.LOD)}

    def tools(self) -> dict[str, Tool]:
        """Contribution name -> tool, from the enabled plugins."""
        return {c.name: c.instance for c in self.contributions(PluginKind.TOOL)}

    def layer_types(self) -> dict[str, Any]:
        """Contribution name -> layer type, from the enabled plugins."""
        return {c.name: c.instance for c in self.contributions(PluginKind.LAYER)}

    def configure(self, instance: Any, values: dict[str, Any]) -> None:
        """Persist a contribution's setting values and apply them (isolated). Does nothing
        for a contribution whose plugin has failed or been disabled since (the UI may still
        hold it)."""
        plugin, name = self.contribution_of(instance)
        if id(instance) not in self._live:
            return
        self.settings.set(f"plugins/{plugin}/contributions/{name}", dict(values))
        self.invoke(instance, "configure", values)

    # -- isolation ---------------------------------------------------------------------------
    def owner_of(self, instance: Any) -> str:
        """The name of the plugin that made a contribution object (loaded now or before)."""
        return self.contribution_of(instance)[0]

    def contribution_of(self, instance: Any) -> tuple[str, str]:
        """(plugin name, contribution name) of a contribution object (loaded now or before)."""
        try:
            plugin, _instance, name = self._owners[id(instance)]
        except KeyError:
            raise KeyError(f"{instance!r} is not a loaded plugin contribution") from None
        return plugin, name

    def failure_of(self, name: str, kind: PluginKind | str | None = None) -> str | None:
        """Why contribution ``name`` (of ``kind``, if given) failed this session —
        ``"ExcType: message"``, its own failure or its plugin's — or None when no plugin
        declaring it has failed it (it may still be disabled by the user, or unknown)."""
        kind = PluginKind(kind) if kind is not None else None
        for rec in self.records.values():
            if rec.manifest is None or not any(
                c.name == name and (kind is None or c.kind == kind)
                for c in rec.manifest.contributions
            ):
                continue
            if name in rec.failures:
                return rec.failures[name].error
            if rec.status == "failed":
                return rec.error or "failed"
        return None

    def is_active(self, name: str) -> bool:
        """True when plugin ``name`` is enabled and has not failed as a whole (it may have
        failed contributions: status 'partial')."""
        rec = self.records.get(name)
        return rec is not None and rec.enabled and rec.status in ("ok", "partial")

    def contribution_active(self, plugin: str, name: str) -> bool:
        """True when contribution ``name`` of plugin ``plugin`` may be called: the plugin is
        enabled and neither it nor that contribution has failed."""
        rec = self.records.get(plugin)
        return rec is not None and rec.contribution_active(name)

    def call(
        self,
        plugin_name: str,
        fn: Callable[..., T],
        *args: Any,
        default: Any = None,
        user_errors: bool = False,
        budgeted: bool = False,
        contribution: str | None = None,
        pass_not_ready: bool = False,
        **kwargs: Any,
    ) -> T | Any:
        """Run ``fn(*args, **kwargs)`` — plugin code — isolated.

        Returns ``default`` without calling when the plugin (or ``contribution`` of it) is
        not active, and when ``fn`` raises any `BaseException` (SystemExit, GeneratorExit, a
        KeyboardInterrupt of its own...): ``contribution`` — or, without one, the whole
        plugin — is then disabled for the session (`report_failure`). Only a real Ctrl-C — a
        SIGINT delivered while ``fn`` ran, see `install_sigint_marker` — is re-raised. With
        ``user_errors``, a `GlobeviewError` (bad input the user gave, e.g. a broken file to a
        layer type's ``open``) propagates to the caller instead: the plugin is not at fault.
        With ``budgeted`` (frame-path calls) the call is timed against `budget` (see
        `Budget`). With ``pass_not_ready``, `TileNotReady` (a remote tile not fetched yet,
        read on a thread that never waits for the network) propagates: the data is late, the
        plugin is not at fault (`LodHost.select` draws that frame without it).
        """
        if contribution is not None:
            if not self.contribution_active(plugin_name, contribution):
                return default
        elif not self.is_active(plugin_name):
            return default
        before = _sigint_count
        t0 = time.perf_counter()
        try:
            result = fn(*args, **kwargs)
        except GlobeviewError as exc:
            if user_errors or (pass_not_ready and _not_ready(exc)):
                raise
            self.report_failure(plugin_name, exc, contribution=contribution)
            return default
        except BaseException as exc:
            if _is_user_interrupt(exc, before):
                raise
            self.report_failure(plugin_name, exc, contribution=contribution)
            return default
        if budgeted:
            ms = (time.perf_counter() - t0) * 1e3
            self._check_budget(plugin_name, fn, ms, contribution)
        return result

    def _check_budget(
        self, plugin_name: str, fn: Any, ms: float, contribution: str | None = None
    ) -> None:
        """Count a frame-path call of ``ms`` milliseconds against the budget of
        ``contribution`` (or of the plugin): after ``budget.overruns`` consecutive overruns
        the 'disable' policy disables it; the 'warn' policy logs one warning per plugin and
        session."""
        b = self.budget
        rec = self.records.get(plugin_name)
        if rec is None or b.ms <= 0:
            return
        key = contribution or ""
        if ms <= b.ms:
            rec.overruns[key] = 0
            return
        n = rec.overruns[key] = rec.overruns.get(key, 0) + 1
        if n < b.overruns:  # one slow call (a cold cache) is no verdict
            return
        what = f"{getattr(fn, '__name__', 'call')}()"
        if b.policy == "disable":
            self.report_failure(
                plugin_name,
                PluginTimeout(
                    f"{what} took {ms:.0f} ms, over the {b.ms:g} ms budget "
                    f"({BUDGET_MS_KEY}) {n} calls in a row"
                ),
                contribution=contribution,
            )
        elif not rec.budget_warned:
            rec.budget_warned = True
            log.warning(
                "plugin %s: %s took %.0f ms, over the %g ms frame budget (%s) %d calls in a "
                "row; kept running (%s is 'warn')",
                plugin_name,
                what,
                ms,
                b.ms,
                BUDGET_MS_KEY,
                n,
                BUDGET_POLICY_KEY,
            )

    def invoke(
        self,
        instance: Any,
        method: str,
        *args: Any,
        default: Any = None,
        user_errors: bool = False,
        budgeted: bool | None = None,
        pass_not_ready: bool = False,
        **kwargs: Any,
    ) -> Any:
        """``call`` a method of a loaded contribution, e.g.
        ``registry.invoke(tool, "on_mouse", event, default=False)``.

        A failure (any exception, or no such method) fails that contribution only; the
        plugin's other contributions keep working. Returns ``default`` for an object whose
        contribution or plugin was disabled or failed since (the host may still hold it),
        without calling it.

        ``user_errors=True``: a `globeview.errors.GlobeviewError` raised by the method is the
        user's bad input, not a plugin bug (e.g. a layer type's ``open`` given a broken
        file): it propagates to the caller — which shows its one line — and the
        contribution stays enabled. Any other exception still fails the contribution.
        Use it only for methods whose input comes from the user (``open`` of a file).

        ``budgeted`` defaults to whether ``method`` is one of `FRAME_PATH_METHODS` (timed
        against the budget)."""
        if budgeted is None:
            budgeted = method in FRAME_PATH_METHODS
        plugin, name = self.contribution_of(instance)
        if id(instance) not in self._live:
            return default
        fn = getattr(instance, method, None)
        if not callable(fn):
            self.report_failure(
                plugin,
                TypeError(f"{type(instance).__name__} has no {method}()"),
                contribution=name,
            )
            return default
        return self.call(
            plugin,
            fn,
            *args,
            default=default,
            user_errors=user_errors,
            budgeted=budgeted,
            contribution=name,
            pass_not_ready=pass_not_ready,
            **kwargs,
        )

    def call_for(
        self, instance: Any, fn: Callable[..., T], *args: Any, default: Any = None, **kwargs: Any
    ) -> T | Any:
        """`call` ``fn`` (plugin code that belongs to contribution object ``instance``, e.g.
        a method of the layer a layer type opened), failing that contribution if it raises.
        Takes `call`'s keyword arguments."""
        plugin, name = self.contribution_of(instance)
        if id(instance) not in self._live:
            return default
        return self.call(plugin, fn, *args, default=default, contribution=name, **kwargs)

    def select(
        self,
        provider: LodProvider,
        view: Any,
        terrain: Any,
        check: Callable[[Any], None] | None = None,
    ) -> Any | None:
        """``provider.select(view, terrain)`` isolated and timed (frame path), checking it
        returned a RenderSet — and, with ``check`` (e.g. `RenderSet.validate` with the
        renderer's limits), a valid one: ``check`` raising fails the provider's plugin.

        Returns None when the provider failed (the host then falls back to another)."""
        from globeview.lod.render_set import RenderSet

        failed = object()
        result = self.invoke(
            provider, "select", view, terrain, default=failed, budgeted=True, pass_not_ready=True
        )
        if result is failed:
            return None
        if not isinstance(result, RenderSet):
            self.fail(
                provider, TypeError(f"select() returned {type(result).__name__}, not a RenderSet")
            )
            return None
        if check is not None:
            before = _sigint_count
            try:
                check(result)  # may run plugin code: a RenderSet subclass's properties
            except BaseException as exc:
                if _is_user_interrupt(exc, before):
                    raise
                self.fail(provider, exc)
                return None
        return result

    def fail(self, instance: Any, exc: BaseException) -> None:
        """Fail the contribution object ``instance`` after ``exc`` (found by the host, e.g.
        garbage it returned or a shader of it that does not compile): `report_failure` for
        that contribution only."""
        plugin, name = self.contribution_of(instance)
        self.report_failure(plugin, exc, contribution=name)

    def report_failure(
        self, plugin_name: str, exc: BaseException, contribution: str | None = None
    ) -> None:
        """Mark a contribution — or, without ``contribution``, the whole plugin — failed
        after ``exc`` (raised by it, or found by the host such as a shader compile error).

        A failed contribution is dropped and recorded in `PluginRecord.failures`; the
        plugin's other contributions keep working and its status reads 'partial'. When no
        contribution of the plugin is left working, or without ``contribution``, the plugin
        is 'failed': all its contributions are dropped and it counts as disabled for the
        session. The error is logged as one WARNING line, its traceback at DEBUG and in the
        log file. The persisted enable choice is unchanged."""
        rec = self.records.get(plugin_name)
        message = describe_exception(exc)
        try:
            tb = "".join(traceback.format_exception(exc)).rstrip()
        except Exception:  # noqa: BLE001  a hostile exception object
            tb = message
        declared = (
            {c.name: c for c in rec.manifest.contributions}
            if rec is not None and rec.manifest is not None
            else {}
        )
        if contribution is not None and contribution not in declared:
            contribution = None  # not one of its contributions: blame the plugin
        whole = contribution is None or set(declared) <= set(rec.failures) | {contribution}
        # One WARNING line (the host carries on; a terminal sees exactly this line); the
        # traceback at DEBUG, in the log file and on the record (`plugins list --json`).
        if contribution is None or len(declared) == 1:
            what = f"plugin {plugin_name}"
        else:
            what = f"plugin {plugin_name}: {declared[contribution].kind.value} {contribution}"
        where = _append_failure_log(what, tb)
        details = f" (details in {where})" if where is not None else ""
        rest = "" if whole else "; its other contributions keep working"
        log.warning("%s failed and was disabled: %s%s%s", what, message, rest, details)
        log.debug("%s failure traceback:\n%s", what, tb)
        if rec is None:
            return
        if contribution is not None:
            rec.failures[contribution] = ContributionFailure(
                declared[contribution].kind, message, tb
            )
        rec.traceback = tb
        if whole:
            self._unload(rec)
            rec.enabled = False
            rec.status = "failed"
        else:
            self._unload(rec, only=contribution)
            rec.status = "partial"
        rec.error = message if contribution is None else _failure_summary(rec, message)


def _failure_summary(rec: PluginRecord, message: str) -> str:
    """`PluginRecord.error` after a contribution failed with ``message``: the message for a
    plugin of one contribution, or when every contribution failed with that same error
    (a shared module that does not import); else ``"NAME: error"`` per distinct error, the
    names that share one joined by ``", "`` and the groups by ``"; "``."""
    declared = len(rec.manifest.contributions) if rec.manifest is not None else 0
    if declared <= 1 or not rec.failures:
        return message
    by_error: dict[str, list[str]] = {}
    for name, f in rec.failures.items():
        by_error.setdefault(f.error, []).append(name)
    if len(by_error) == 1 and len(rec.failures) == declared:
        return message
    text = "; ".join(f"{', '.join(names)}: {error}" for error, names in by_error.items())
    return _clip(text, 2 * MAX_MESSAGE_CHARS)


#: Size past which the log is moved to ``globeview.log.1`` before appending.
LOG_MAX_BYTES = 4 * 1024 * 1024


def failure_log_path() -> Path:
    """Where plugin failure tracebacks are appended: the log the CLI and the window write
    internal errors to (`globeview.paths.log_path`)."""
    return log_path()


def _append_failure_log(what: str, tb: str) -> Path | None:
    """Append a plugin failure's traceback to the log under the heading ``what`` (``"plugin
    NAME"`` or ``"plugin NAME: KIND CONTRIBUTION"``); best effort (None when the log cannot
    be written: a read-only cache must not turn a plugin failure into a host failure)."""
    path = failure_log_path()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(OSError):
            if path.stat().st_size > LOG_MAX_BYTES:
                os.replace(path, path.with_name(path.name + ".1"))
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")
        with path.open("a", encoding="utf-8", errors="replace") as f:
            f.write(f"{stamp} {what} failed and was disabled:\n{tb}\n\n")
    except OSError:
        return None
    return path


def _is_user_interrupt(exc: BaseException, sigints_before: int) -> bool:
    """True for a KeyboardInterrupt from a SIGINT delivered since ``sigints_before`` was read
    (the user's Ctrl-C); False for one plugin code raised itself, and for anything else."""
    return isinstance(exc, KeyboardInterrupt) and _sigint_count != sigints_before


def _clip(text: str, limit: int = 100) -> str:
    """``text`` cut to ``limit`` characters (hostile names and values are huge)."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _plugin_entry_points() -> list[md.EntryPoint]:
    """The entry points of group `ENTRY_POINT_GROUP`, read distribution by distribution: one
    installed distribution with unreadable metadata (not UTF-8, malformed) is skipped with a
    one-line warning instead of hiding every plugin (`importlib.metadata.entry_points` reads
    them all at once and raises)."""
    out: list[md.EntryPoint] = []
    try:
        dists = list(md.distributions())
    except Exception as exc:  # noqa: BLE001  installed metadata may be broken any way: skip, never fail discovery
        log.warning("plugin discovery failed: %s", describe_exception(exc))
        return out
    for dist in dists:
        try:
            out.extend(ep for ep in dist.entry_points if ep.group == ENTRY_POINT_GROUP)
        except Exception as exc:  # noqa: BLE001  installed metadata may be broken any way: skip, never fail discovery
            where = getattr(dist, "_path", None) or "a distribution"
            log.info(
                "plugins of %s skipped: unreadable metadata: %s", where, describe_exception(exc)
            )
    return out


def _dist_name(ep: md.EntryPoint) -> str:
    """The normalised name of the distribution of ``ep`` ("" when unknown or unreadable)."""
    try:
        dist = ep.dist
        if dist is None:
            return ""
        return (dist.metadata["Name"] or "").lower().replace("_", "-")
    except Exception:  # noqa: BLE001  installed metadata may be broken any way: skip, never fail discovery
        return ""
