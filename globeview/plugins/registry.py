"""The plugin registry: discovery, enable/disable, lazy loading and failure isolation.

Discovery reads the manifests named by the entry points of group ``globeview.plugins``
(`importlib.metadata`) — the built-ins ship through the same group from globeview's own
pyproject — and never imports plugin code. A contribution's module is imported the first time
the host asks for it (`load_contribution`, `lod_providers`, `tools`, `layer_types`), and only
if its plugin is enabled.

Isolation: every call into plugin code goes through `PluginRegistry.call` (or `invoke`). An
exception there marks the plugin 'failed' for this session (its contributions are dropped, so
the host stops calling them), is logged with its traceback to the ``globeview.plugins``
logger, and the call returns a default. A failure found by the host itself (e.g. a
displacement shader that does not compile) is reported with `report_failure`. A failure is
not persisted: the next start tries the plugin again. The user's enable/disable choices are
persisted in the settings backend (``plugins/enabled``); plugins the user never touched are
enabled (built-in or installed with pip alike).
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.metadata as md
import logging
import sys
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

from globeview.errors import GlobeviewError
from globeview.plugins.api import LodProvider, PluginContext, PluginKind, RendererHooks, Tool
from globeview.plugins.manifest import Manifest, ManifestError, locate_manifest, read_manifest
from globeview.plugins.settings import (
    ENABLED_KEY,
    PluginSettings,
    SettingsBackend,
    default_settings,
)

__all__ = ["ENTRY_POINT_GROUP", "LoadedContribution", "PluginRecord", "PluginRegistry"]

#: Entry point group plugins register under.
ENTRY_POINT_GROUP = "globeview.plugins"
#: Distribution whose entry points are the built-in plugins.
BUILTIN_DISTRIBUTION = "globeview"

log = logging.getLogger("globeview.plugins")

Status = Literal["ok", "disabled", "failed"]
T = TypeVar("T")

# Methods a contribution of each kind must have.
_REQUIRED_METHODS: dict[PluginKind, tuple[str, ...]] = {
    PluginKind.LOD: ("select",),
    PluginKind.TOOL: ("on_mouse", "on_key", "overlay"),
    PluginKind.LAYER: ("open",),
}


def describe_exception(exc: BaseException) -> str:
    """``"ExcType: message"`` on one line."""
    msg = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


@dataclass
class LoadedContribution:
    """A created contribution and where it came from."""

    plugin: str
    name: str
    kind: PluginKind
    label: str
    instance: Any


@dataclass
class PluginRecord:
    """What the registry knows about one plugin.

    Attributes:
        name: the plugin's name (the entry point's name; the manifest must agree).
        manifest: the validated manifest, or None when it could not be read.
        source: where it comes from: ``"<distribution> <version>"`` or a manifest path.
        builtin: shipped with globeview.
        enabled: the user's choice (False also after a failure this session).
        status: 'ok' (enabled, no failure), 'disabled' (by the user) or 'failed'.
        error: ``"ExcType: message"`` (or the manifest problem) when status is 'failed'.
    """

    name: str
    manifest: Manifest | None
    source: str
    builtin: bool = False
    enabled: bool = True
    status: Status = "ok"
    error: str | None = None
    context: PluginContext | None = field(default=None, repr=False)
    loaded: dict[str, LoadedContribution] = field(default_factory=dict, repr=False)

    @property
    def version(self) -> str:
        return self.manifest.version if self.manifest else ""

    @property
    def kinds(self) -> tuple[str, ...]:
        return tuple(k.value for k in self.manifest.kinds) if self.manifest else ()

    def as_dict(self) -> dict[str, Any]:
        """JSON-able summary (what ``globeview plugins list --json`` prints)."""
        return {
            "name": self.name,
            "version": self.version,
            "kinds": list(self.kinds),
            "description": self.manifest.description if self.manifest else "",
            "api_version": self.manifest.api_version if self.manifest else "",
            "enabled": self.enabled,
            "status": self.status,
            "error": self.error,
            "builtin": self.builtin,
            "source": self.source,
            "contributions": [
                {"name": c.name, "kind": c.kind.value, "target": c.target, "label": c.label}
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
    """

    def __init__(
        self,
        settings: SettingsBackend | None = None,
        *,
        scene: Any = None,
        terrain: Any = None,
        camera: Any = None,
        renderer: RendererHooks | None = None,
    ) -> None:
        self.settings: SettingsBackend = settings if settings is not None else default_settings()
        self._host: dict[str, Any] = {
            "scene": scene,
            "terrain": terrain,
            "camera": camera,
            "renderer": renderer,
        }
        self.records: dict[str, PluginRecord] = {}
        # id(instance) -> (plugin name, instance) of every contribution ever created (the
        # reference keeps ids unique); _live holds the ids of those still loaded.
        self._owners: dict[int, tuple[str, Any]] = {}
        self._live: set[int] = set()

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
            md.entry_points(group=ENTRY_POINT_GROUP),
            key=lambda e: (_dist_name(e) != BUILTIN_DISTRIBUTION, e.name),
        )
        for ep in eps:
            if (ep.name, ep.value) in seen:  # the same distribution found twice on sys.path
                continue
            seen.add((ep.name, ep.value))
            dist = ep.dist
            source = f"{dist.metadata['Name']} {dist.version}" if dist else ep.value
            builtin = _dist_name(ep) == BUILTIN_DISTRIBUTION
            try:
                manifest = read_manifest(locate_manifest(ep.value))
                if manifest.name != ep.name:
                    raise ManifestError(
                        f"entry point name {ep.name!r} differs from manifest name {manifest.name!r}"
                    )
            except ManifestError as exc:
                self._add_invalid(ep.name, source, str(exc), builtin)
                continue
            self._add(manifest, source, builtin)
        for p in paths:
            self.add_path(p)
        return self

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
        rec = PluginRecord(name, None, source, builtin, False, "failed", error)
        self.records[name] = rec
        log.error("plugin %s disabled: invalid manifest: %s", name, error)
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
        rec.enabled, rec.status, rec.error = True, "ok", None
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

    def _unload(self, rec: PluginRecord) -> None:
        for lc in rec.loaded.values():
            self._live.discard(id(lc.instance))
            if isinstance(lc.instance, Tool):
                try:
                    lc.instance.deactivate()
                except Exception:  # a failing cleanup must not stop the unload
                    log.exception("plugin %s: deactivate failed", rec.name)
        rec.loaded.clear()

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
            )
        return rec.context

    # -- loading -----------------------------------------------------------------------------
    def load_contribution(self, plugin: str, name: str) -> Any | None:
        """The object of contribution ``name`` of ``plugin``, created on first request.

        Imports the target module, calls the factory with the plugin's context, checks the
        object has the methods of its kind, and applies the stored setting values
        (``configure``). Returns None if the plugin is disabled or failed; any error on the
        way fails the plugin (see `report_failure`) and returns None.
        """
        rec = self.get(plugin)
        if not rec.enabled or rec.status != "ok" or rec.manifest is None:
            return None
        if name in rec.loaded:
            return rec.loaded[name].instance
        contrib = rec.manifest.contribution(name)
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
        except Exception as exc:
            self.report_failure(plugin, exc)
            return None
        rec.loaded[name] = LoadedContribution(plugin, name, contrib.kind, contrib.label, instance)
        self._owners[id(instance)] = (plugin, instance)
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
            if rec.manifest is None or not rec.enabled or rec.status != "ok":
                continue
            for c in rec.manifest.contributions:
                if c.kind != kind:
                    continue
                if c.name in names:
                    log.warning(
                        "plugin %s: %s %r already provided; skipped", rec.name, kind, c.name
                    )
                    continue
                if self.load_contribution(rec.name, c.name) is None:
                    break  # the plugin failed: skip the rest of it
                names.add(c.name)
                out.append(rec.loaded[c.name])
        return out

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
        """Persist a contribution's setting values and apply them (isolated)."""
        plugin = self.owner_of(instance)
        rec = self.get(plugin)
        name = next(n for n, lc in rec.loaded.items() if lc.instance is instance)
        self.settings.set(f"plugins/{plugin}/contributions/{name}", dict(values))
        self.call(plugin, instance.configure, values)

    # -- isolation ---------------------------------------------------------------------------
    def owner_of(self, instance: Any) -> str:
        """The name of the plugin that made a contribution object (loaded now or before)."""
        try:
            return self._owners[id(instance)][0]
        except KeyError:
            raise KeyError(f"{instance!r} is not a loaded plugin contribution") from None

    def is_active(self, name: str) -> bool:
        """True when plugin ``name`` is enabled and has not failed."""
        rec = self.records.get(name)
        return rec is not None and rec.enabled and rec.status == "ok"

    def call(
        self,
        plugin_name: str,
        fn: Callable[..., T],
        *args: Any,
        default: Any = None,
        user_errors: bool = False,
        **kwargs: Any,
    ) -> T | Any:
        """Run ``fn(*args, **kwargs)`` — plugin code — isolated.

        Returns ``default`` without calling when the plugin is not active, and when ``fn``
        raises: the plugin is then disabled for the session (`report_failure`). With
        ``user_errors``, a `GlobeviewError` (bad input the user gave, e.g. a broken file to a
        layer type's ``open``) propagates to the caller instead: the plugin is not at fault.
        """
        if not self.is_active(plugin_name):
            return default
        try:
            return fn(*args, **kwargs)
        except GlobeviewError:
            if user_errors:
                raise
            self.report_failure(plugin_name, sys.exc_info()[1])  # type: ignore[arg-type]
            return default
        except Exception as exc:
            self.report_failure(plugin_name, exc)
            return default

    def invoke(
        self,
        instance: Any,
        method: str,
        *args: Any,
        default: Any = None,
        user_errors: bool = False,
        **kwargs: Any,
    ) -> Any:
        """``call`` a method of a loaded contribution, e.g.
        ``registry.invoke(tool, "on_mouse", event, default=False)``.

        Returns ``default`` for an object whose plugin was disabled or failed since (the host
        may still hold it), without calling it."""
        plugin = self.owner_of(instance)
        if id(instance) not in self._live:
            return default
        fn = getattr(instance, method, None)
        if not callable(fn):
            self.report_failure(plugin, TypeError(f"{type(instance).__name__} has no {method}()"))
            return default
        return self.call(plugin, fn, *args, default=default, user_errors=user_errors, **kwargs)

    def select(self, provider: LodProvider, view: Any, terrain: Any) -> Any | None:
        """``provider.select(view, terrain)`` isolated, checking it returned a RenderSet.

        Returns None when the provider failed (the host then falls back to another)."""
        from globeview.render.render_set import RenderSet

        result = self.invoke(provider, "select", view, terrain, default=None)
        if result is not None and not isinstance(result, RenderSet):
            self.report_failure(
                self.owner_of(provider),
                TypeError(f"select() returned {type(result).__name__}, not a RenderSet"),
            )
            return None
        return result

    def report_failure(self, plugin_name: str, exc: BaseException) -> None:
        """Mark a plugin failed after ``exc`` (raised by it, or found by the host such as a
        shader compile error): status 'failed', error "ExcType: message", contributions
        dropped, and the error logged with its traceback. The persisted choice is unchanged."""
        rec = self.records.get(plugin_name)
        message = describe_exception(exc)
        tb = "".join(traceback.format_exception(exc)).rstrip()
        log.error("plugin %s failed and was disabled: %s\n%s", plugin_name, message, tb)
        if rec is None:
            return
        self._unload(rec)
        rec.enabled = False
        rec.status = "failed"
        rec.error = message


def _dist_name(ep: md.EntryPoint) -> str:
    dist = ep.dist
    if dist is None:
        return ""
    return (dist.metadata["Name"] or "").lower().replace("_", "-")
