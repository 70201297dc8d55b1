"""The UI's side of the plugin contract: the registry and the `GlobeSession` wired to the
window.

`PluginHost` lists the plugins and LOD providers for the panel, applies provider settings,
and turns plugin failures into one-line notices. The active LOD provider is the model's
(``Globe.lod``): choosing one sets it, and the host follows the model's ``lod`` event, so a
provider set from code, or the session's fallback when a provider fails in a frame (the
registry disables it, the session switches the model to the built-in provider on that same
frame), reaches the panel and the status bar with the reason. It is also the
`RendererHooks` object plugin contexts get (``request_redraw``, ``set_status``).

`QSettingsBackend` is a `SettingsBackend` over the window's QSettings (JSON strings). The
application itself keeps plugin settings in ``settings.json`` like the command line
(`globeview.ui.app.plugin_registry`, which copies over once what an older globeview kept in
QSettings); a window built without a registry (tests) still uses QSettings.
"""

from __future__ import annotations

import json
import logging
from typing import Any

from PyQt6.QtCore import QObject, QSettings, pyqtSignal

from globeview.app.lod_host import LodHost
from globeview.app.session import DEFAULT_LOD, GlobeSession
from globeview.errors import GlobeviewError
from globeview.model.globe import Globe
from globeview.plugins.api import PluginKind
from globeview.plugins.records import PluginRecord
from globeview.plugins.registry import PluginRegistry
from globeview.ui.subscriptions import Subscriptions

log = logging.getLogger("globeview.ui")


class QSettingsBackend:
    """The plugins' `SettingsBackend` over a QSettings (values JSON-encoded)."""

    def __init__(self, settings: QSettings, prefix: str = "") -> None:
        self.qsettings = settings
        self.prefix = prefix

    def get(self, key: str, default: Any = None) -> Any:
        raw = self.qsettings.value(self.prefix + key)
        if raw is None:
            return default
        try:
            return json.loads(str(raw))
        except ValueError:
            return default

    def set(self, key: str, value: Any) -> None:
        self.qsettings.setValue(self.prefix + key, json.dumps(value))


class PluginHost(QObject):
    """Plugin state for the UI, around a `PluginRegistry`, the `Globe` model and (once GL is
    up) a session. The active LOD provider is the model's (``model.lod``): a choice here sets
    it, and a change made anywhere (code, a fallback) comes back through its event.

    Signals:
        changed(): plugin records or the provider list changed (the panel refreshes).
        lodChanged(str): the model's LOD provider changed (a user choice, code or a fallback).
        redrawRequested(): a plugin or a setting asks for a frame.
        notice(str): a one-line message for the status bar (a failure: logged at WARNING).
        statusText(str): a plugin's own status line (`set_status`): the status bar only.
    """

    changed = pyqtSignal()
    lodChanged = pyqtSignal(str)
    redrawRequested = pyqtSignal()
    notice = pyqtSignal(str)
    statusText = pyqtSignal(str)

    def __init__(
        self,
        registry: PluginRegistry,
        model: Globe,
        parent: QObject | None = None,
        subscriptions: Subscriptions | None = None,
    ) -> None:
        super().__init__(parent)
        self.registry = registry
        self.model = model
        self.session: GlobeSession | None = None
        self._statuses: dict[str, str] = {}
        #: Why the last fallback happened ("" when the chosen provider is the one drawing):
        #: the window keeps it visible (LOD field tooltip, plugin panel) after notices pass.
        self.fallback_reason = ""
        #: The provider in use before the model's last LOD event (whose going is a fallback).
        self._lod_before = model.lod
        #: Validates a chosen name before the model changes (the session's `LodHost` does
        #: the same on the same model and registry; this one works before GL is up).
        self._lod_host = LodHost(model, registry)
        #: The model subscriptions, the window's (cleared when it closes), or its own.
        self.subscriptions = Subscriptions() if subscriptions is None else subscriptions
        self.subscriptions.connect(model.events.lod, self._model_lod)

    @property
    def active(self) -> str:
        """The active LOD provider: the model's."""
        return self.model.lod

    def _model_lod(self, *_args: object) -> None:
        """The model's LOD provider changed (a choice here, code, or a fallback): the panel
        and status bar are told (`lodChanged`). When the provider left is no longer available
        (it failed in a frame and the session fell back, or its plugin was disabled), the
        notice says why and `fallback_reason` keeps it; any other change clears it."""
        name, old = self.model.lod, self._lod_before
        if name == old:
            return
        self._lod_before = name
        if self.registry.find(PluginKind.LOD, old) is None:
            self._announce_fallback(old, name)
        else:
            self.fallback_reason = ""
        self.lodChanged.emit(name)

    def _announce_fallback(self, old: str, new: str) -> None:
        """Say once why provider ``old`` gave way to ``new`` (and only here: `reported`)."""
        why = self.failure_reason("lod", old)
        self.fallback_reason = f"LOD provider {old} failed: {why}" if why else ""
        text = self.fallback_reason or f"LOD provider {old} is not available"
        self.notice.emit(f"{text}; using {new}")
        self.reported("lod", old)

    def reported(self, kind: str, name: str) -> None:
        """A notice has named the failure of contribution ``name`` of ``kind``: `refresh`
        does not announce its plugin's failure again."""
        for rec in self.registry:
            if self._declares(rec, kind, name):
                self._statuses[rec.name] = rec.status

    # -- RendererHooks (what PluginContext.renderer offers plugins) -------------------------
    def request_redraw(self) -> None:
        self.redrawRequested.emit()

    def set_status(self, text: str) -> None:
        """A plugin's one-line status ("click two places"): shown in the status bar and
        logged at INFO — it is no warning (`notice` is, for failures)."""
        line = " ".join(str(text).split())
        log.info("plugin status: %s", line)
        self.statusText.emit(line)

    # -- discovery and state -------------------------------------------------------------
    def discover(self) -> None:
        """Discover the installed plugins; a failure becomes a notice, never a crash."""
        try:
            self.registry.discover()
        except Exception as exc:
            log.exception("plugin discovery failed")
            self.notice.emit(f"plugin discovery failed: {exc}")
        self.refresh()

    def records(self) -> list[PluginRecord]:
        return list(self.registry)

    def providers(self) -> dict[str, str]:
        """Name -> menu label of the enabled LOD providers (loading them now; a plugin that
        fails to load is disabled and reported)."""
        try:
            return {c.name: c.label or c.name for c in self.registry.contributions("lod")}
        except Exception as exc:
            log.exception("loading LOD providers failed")
            self.notice.emit(f"loading LOD providers failed: {exc}")
            return {}

    def provider(self) -> Any:
        """The active LOD provider object, or None."""
        return self.registry.lod_providers().get(self.active)

    def failure_reason(self, kind: str, name: str) -> str:
        """Why contribution ``name`` of ``kind`` failed: its own failure (``"ExcType:
        message"``) or its plugin's; "" when it did not fail (e.g. the user disabled it)."""
        return self.registry.failure_of(name, kind) or ""

    def refresh(self) -> None:
        """Reload providers, report newly failed plugins, keep a valid active provider.

        A fallback's notice carries the real reason (the provider's failure), so it is never
        replaced by a bare "not available" line; the reason stays in `fallback_reason`."""
        available = self.providers()
        old = self.active
        falls_back = old not in available and bool(available)
        for rec in self.registry:
            if rec.status in ("failed", "partial") and self._statuses.get(rec.name) != rec.status:
                if falls_back and self._declares(rec, "lod", old):
                    continue  # said once, with the fallback, below
                if rec.status == "partial":
                    # Per-contribution isolation: the plugin stays enabled.
                    self.notice.emit(
                        f"plugin {rec.name}: {rec.error}; its other contributions keep working"
                    )
                else:
                    self.notice.emit(f"plugin {rec.name} failed and was disabled: {rec.error}")
        self._statuses = {rec.name: rec.status for rec in self.registry}
        if falls_back:
            # The model's event announces it (`_model_lod`: the provider left is unavailable).
            self.model.lod = DEFAULT_LOD if DEFAULT_LOD in available else next(iter(available))
        self.changed.emit()

    @staticmethod
    def _declares(rec: PluginRecord, kind: str, name: str) -> bool:
        m = rec.manifest
        return m is not None and any(c.kind == kind and c.name == name for c in m.contributions)

    def set_enabled(self, name: str, enabled: bool) -> None:
        """Enable or disable a plugin (persisted) and reload the providers."""
        if enabled:
            self.registry.enable(name)
        else:
            self.registry.disable(name)
        self.refresh()
        self.redrawRequested.emit()

    # -- the session -----------------------------------------------------------------------
    def bind(self, session: GlobeSession) -> None:
        """Use ``session`` (created by the globe widget once GL is up)."""
        self.session = session
        self.registry.attach(renderer=self)  # the session attached scene, terrain, camera
        self.refresh()

    def unbind(self) -> None:
        """Forget the session (its window closed): plugin contexts stop handing it out, so
        nothing here keeps the released session, its renderer and terrain caches alive."""
        self.session = None
        self.registry.attach(scene=None)

    def choose(self, name: str) -> None:
        """Make ``name`` the model's LOD provider from the next frame on (a user's choice).

        The name is checked before the model changes: one no enabled plugin provides is a
        notice and nothing changes; a provider whose plugin fails to load falls back to the
        built-in one (the notice says why)."""
        if name == self.active:
            return
        try:
            self._lod_host.choose(name)
        except GlobeviewError as exc:  # the user's (or code's) error: no such provider
            self.notice.emit(str(exc))
            return
        if self.model.lod != name:  # its plugin failed to load: LodHost fell back
            self._announce_fallback(name, self.model.lod)
            self.refresh()  # the panel lists the failed plugin, its choice goes back

    def configure(self, values: dict[str, Any]) -> None:
        """Apply and persist setting values of the active provider (isolated)."""
        provider = self.provider()
        if provider is None:
            return
        self.registry.configure(provider, values)
        self.after_frame()
        self.redrawRequested.emit()

    def after_frame(self) -> None:
        """Report plugins that failed during a frame (their records changed)."""
        if self.session is None:
            return
        # A provider failing in a frame made the session fall back: that came as a model
        # event (`_model_lod` said why); here only the plugin list catches up.
        if any(rec.status != self._statuses.get(rec.name) for rec in self.registry):
            self.refresh()
