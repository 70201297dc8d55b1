"""What the registry knows about each plugin (`PluginRecord`: its manifest, where it comes
from, its state and failures) and about each created contribution (`LoadedContribution`):
plain data, read by ``globeview plugins list``, the window's plugin panel and the hosts."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from globeview.plugins.api import PluginContext, PluginKind
from globeview.plugins.manifest import Manifest

__all__ = ["ContributionFailure", "LoadedContribution", "PluginRecord", "Status"]

#: 'partial': enabled, and some (not all) of its contributions failed this session.
Status = Literal["ok", "partial", "disabled", "failed"]


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
