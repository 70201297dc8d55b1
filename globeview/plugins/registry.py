"""The plugin registry: all known plugins, their state, and the contributions of the enabled
ones. Every call into plugin code goes through it.

`PluginRegistry` is put together from parts with one job each, every one in its module:

- `PluginDiscovery` (`globeview.plugins.discovery`): the manifests of the entry point group
  ``globeview.plugins`` and of files given by path, read into `PluginRecord`s without
  importing plugin code;
- `EnableState` (`globeview.plugins.enable_state`): the user's enable/disable choices,
  persisted (``plugins/enabled``), and what may be called now;
- `ContributionLoading` (`globeview.plugins.loading`): contributions imported and created
  the first time the host asks for one, with their plugin's `PluginContext`;
- `Isolation` (`globeview.plugins.isolation`): ``call`` / ``invoke`` / ``select`` run plugin
  code isolated and timed; a failure fails the contribution it came from, never the host.

The records themselves are plain data (`globeview.plugins.records`). This module holds the
state the parts share (records, created contributions, what contexts hand plugins, the
settings and the frame-time budget) and the container protocol.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Literal

from globeview.plugins.api import RendererHooks
from globeview.plugins.discovery import PluginDiscovery
from globeview.plugins.enable_state import EnableState
from globeview.plugins.isolation import Isolation, install_sigint_marker, read_budget
from globeview.plugins.loading import ContributionLoading
from globeview.plugins.records import PluginRecord
from globeview.plugins.settings import SettingsBackend, default_settings

__all__ = ["PluginRegistry"]


class PluginRegistry(PluginDiscovery, EnableState, ContributionLoading, Isolation):
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
        self.budget = read_budget(self.settings, budget_policy)
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

    # -- the records -------------------------------------------------------------------------
    def __iter__(self) -> Iterator[PluginRecord]:
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
