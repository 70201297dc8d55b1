"""Lazy loading of contributions: a contribution's module is imported the first time the
host asks for it (`load_contribution`, `find`, `contributions`, `lod_providers`, `tools`,
`layer_types`), and only if its plugin is enabled; the factory gets the plugin's
`PluginContext` (``attach`` changes what contexts hand plugins), the object is checked for
the methods of its kind, and its stored setting values are applied (``configure``). One
part of `globeview.plugins.registry.PluginRegistry`.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
from typing import Any

from globeview.plugins.api import (
    LodProvider,
    NullRendererHooks,
    PluginContext,
    PluginKind,
    Tool,
)
from globeview.plugins.isolation import _is_user_interrupt, describe_exception, sigint_count
from globeview.plugins.records import LoadedContribution, PluginRecord
from globeview.plugins.settings import PluginSettings, SettingsBackend

__all__ = ["ContributionLoading"]

log = logging.getLogger("globeview.plugins")

# Methods a contribution of each kind must have.
_REQUIRED_METHODS: dict[PluginKind, tuple[str, ...]] = {
    PluginKind.LOD: ("select",),
    PluginKind.TOOL: ("on_mouse", "on_key", "overlay"),
    PluginKind.LAYER: ("open",),
}


class ContributionLoading:
    """The part of the registry that creates contributions and hands them out. Uses the
    registry's ``settings``, ``records``, ``get``, ``_host`` (what contexts hand plugins),
    ``_owners``/``_live``, ``invoke`` and ``report_failure`` (`Isolation`)."""

    settings: SettingsBackend
    records: dict[str, PluginRecord]
    _host: dict[str, Any]
    _owners: dict[int, tuple[str, Any, str]]
    _live: set[int]

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

    def host_objects(self) -> dict[str, Any]:
        """What contexts hand plugins now (scene, terrain, camera, renderer), as `attach`
        takes it: a host that attaches its own for a while puts these back after."""
        return dict(self._host)

    def context(self, name: str) -> PluginContext:
        """The `PluginContext` of plugin ``name`` (created on first use)."""
        rec = self.get(name)
        if rec.context is None:
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
        before = sigint_count()
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
                before = sigint_count()
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
