"""Enable state: the user's choice per plugin, persisted in the settings backend
(``plugins/enabled``; plugins the user never touched are enabled, built-in or installed with
pip alike), and whether a plugin or one of its contributions may be called now (enabled, and
not failed this session). One part of `globeview.plugins.registry.PluginRegistry`.
"""

from __future__ import annotations

from globeview.plugins.records import PluginRecord
from globeview.plugins.settings import ENABLED_KEY, SettingsBackend

__all__ = ["EnableState"]


class EnableState:
    """The part of the registry that enables and disables plugins (``enable``, ``disable``,
    persisted) and answers ``is_active`` / ``contribution_active``. Uses the registry's
    ``settings``, ``records``, ``get`` and ``_unload`` (a disabled plugin's contributions are
    dropped)."""

    settings: SettingsBackend
    records: dict[str, PluginRecord]

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
