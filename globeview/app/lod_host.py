"""`LodHost`: which LOD provider chooses the tiles, and falling back when it fails.

The active provider is a name on the `Globe` (``globe.lod``, an event). Choosing one imports
only the plugin that provides it; a name no enabled plugin declares is the user's error (one
line), a provider whose plugin fails to load or later fails a frame (raises, returns garbage:
`RenderSet.validate`) is the plugin's: the registry reports it in one line and the globe
falls back to the built-in `DEFAULT_LOD`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from globeview.errors import GlobeviewError
from globeview.lod.render_set import RenderSet
from globeview.lod.view_state import ViewState
from globeview.model.globe import DEFAULT_LOD, Globe
from globeview.plugins.api import PluginKind
from globeview.plugins.registry import PluginRegistry
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.store.backend import TileNotReady

__all__ = ["LodHost", "check_lod_name"]

log = logging.getLogger("globeview.session")


def _declared_by_failed(registry: PluginRegistry, name: str) -> bool:
    """Whether LOD provider ``name`` is declared by a plugin whose contribution failed (it
    did not load): the host falls back instead of refusing the name."""
    return any(
        rec.manifest is not None
        and any(
            c.kind == PluginKind.LOD
            and c.name == name
            and rec.contribution_status(name) == "failed"
            for c in rec.manifest.contributions
        )
        for rec in registry
    )


def _unavailable(registry: PluginRegistry, name: str) -> GlobeviewError:
    """The one line for a name no enabled plugin provides: unknown, disabled, or declared by a
    plugin that failed as a whole (an invalid manifest), with the names available."""
    known = ", ".join(sorted(registry.declared(PluginKind.LOD))) or "none"
    rec = registry.records.get(name)
    if rec is not None and rec.status == "failed":  # e.g. its manifest is invalid
        return GlobeviewError(
            f"no enabled LOD provider named {name!r}: plugin {name} failed: {rec.error} "
            f"(available: {known})"
        )
    if rec is not None and not rec.enabled:
        return GlobeviewError(
            f"LOD provider {name!r} is disabled; `globeview plugins enable {name}` "
            f"(available: {known})"
        )
    return GlobeviewError(f"no enabled LOD provider named {name!r:.80} (available: {known})")


def check_lod_name(registry: PluginRegistry, name: str) -> None:
    """Raise the one-line `GlobeviewError` `LodHost.choose` would for ``name`` (no enabled
    plugin declares it), from the manifests alone: nothing is imported, so a command line
    is checked before any work. A provider that is declared but fails when it loads passes
    here (the host falls back to `DEFAULT_LOD` then, saying why)."""
    if registry.offers(PluginKind.LOD, name) or _declared_by_failed(registry, name):
        return
    raise _unavailable(registry, name)


class LodHost:
    """The LOD provider of ``globe``, its calls isolated by ``registry``."""

    def __init__(self, globe: Globe, registry: PluginRegistry) -> None:
        self.globe = globe
        self.registry = registry
        # The last selection: drawn again while a selection waits for remote metadata
        # (`TileNotReady`), so the view stays drawn (its tiles or their stand-ins), not blank.
        self._last: RenderSet | None = None

    def providers(self) -> dict:
        """Name -> provider of every enabled LOD plugin contribution (imports them all: for
        listing; the frame path loads only the active one)."""
        return self.registry.lod_providers()

    def choose(self, name: str) -> None:
        """Make ``name`` the active LOD provider (takes effect on the next frame).

        A name no enabled plugin declares is the user's error (`GlobeviewError`). A provider
        whose plugin fails to load is the plugin's: the registry reports it in one line and
        the globe falls back to `DEFAULT_LOD`, as it does for a provider failing later."""
        registry = self.registry
        if registry.find(PluginKind.LOD, name) is not None:
            self.globe.lod = name
            return
        if _declared_by_failed(registry, name) and name != DEFAULT_LOD:
            log.info("LOD provider %s failed to load; using %s", name, DEFAULT_LOD)
            self.choose(DEFAULT_LOD)
            return
        raise _unavailable(registry, name)

    def reset(self) -> None:
        """Make the active provider forget its per-view cache (before a measured frame)."""
        provider = self.registry.find(PluginKind.LOD, self.globe.lod)
        if provider is not None:
            self.registry.invoke(provider, "reset")

    def select(
        self,
        view: ViewState,
        terrain: TerrainStack,
        check: Callable[[RenderSet], None],
    ) -> RenderSet:
        """The active provider's render set for ``view`` (``check`` raises for garbage: the
        provider fails); after a failure the `DEFAULT_LOD` provider's, else an empty set."""
        provider = self.registry.find(PluginKind.LOD, self.globe.lod)
        if provider is not None:
            try:
                rs = self.registry.select(provider, view, terrain, check=check)
            except TileNotReady:
                # The provider read a remote tile that is not here yet (the UI thread never
                # waits for the network; the store fetches it in the background): late data,
                # not the provider's fault. This frame is the default provider's selection
                # (or the last one), the user's provider stays chosen and selects again next
                # frame.
                return self._select_default(provider, view, terrain, check)
            if rs is not None:
                self._last = rs
                return rs
        # The registry already reported the failure in one line; this is detail.
        log.info("LOD provider %s unavailable; falling back to %s", self.globe.lod, DEFAULT_LOD)
        if self.globe.lod != DEFAULT_LOD:
            self.globe.lod = DEFAULT_LOD
            fallback = self.registry.find(PluginKind.LOD, DEFAULT_LOD)
            if fallback is not None:
                rs = self.registry.select(fallback, view, terrain, check=check)
                if rs is not None:
                    return rs
        return RenderSet.empty()

    def _select_default(
        self,
        tried: object,
        view: ViewState,
        terrain: TerrainStack,
        check: Callable[[RenderSet], None],
    ) -> RenderSet:
        """The `DEFAULT_LOD` provider's render set for one frame (``tried``, the provider that
        could not select, is not asked again); where it too waits for remote metadata, the
        last selection (`_late`); else an empty set."""
        fallback = self.registry.find(PluginKind.LOD, DEFAULT_LOD)
        if fallback is None or fallback is tried:
            return self._late()
        try:
            rs = self.registry.select(fallback, view, terrain, check=check)
        except TileNotReady:
            return self._late()
        return rs if rs is not None else RenderSet.empty()

    def _late(self) -> RenderSet:
        """The selection of a frame whose metadata is still on its way (a remote layer just
        added: its shards are fetched in the background): the last selection, drawn by the
        renderer with what is resident, else an empty set (issue #25 item 4: adding a
        remote layer does not blank the view)."""
        return self._last if self._last is not None else RenderSet.empty()
