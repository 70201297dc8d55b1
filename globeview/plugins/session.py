"""`GlobeSession`: the headless application model — a `GlobeScene` whose LOD provider and
tools come from the plugin registry, each call isolated (a failing plugin is disabled and the
session falls back to the built-in `chunked-sse`). The CLI's headless renders and the Qt
window both drive a session."""

from __future__ import annotations

import logging

import moderngl

from globeview.errors import GlobeviewError
from globeview.plugins.registry import PluginRegistry
from globeview.render.camera import Camera
from globeview.render.render_set import RenderSet
from globeview.render.scene import GlobeScene
from globeview.render.view_state import ViewState
from globeview.terrain.stack import TerrainStack

DEFAULT_LOD = "chunked-sse"
log = logging.getLogger("globeview.session")


class GlobeSession(GlobeScene):
    """A globe scene driven by plugins.

    Args:
        ctx: moderngl context; terrain: the DEM layers; camera: the initial camera.
        registry: a discovered `PluginRegistry` (default: discover the installed plugins).
        lod: name of the LOD provider to start with.
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        terrain: TerrainStack,
        camera: Camera | None = None,
        registry: PluginRegistry | None = None,
        lod: str = DEFAULT_LOD,
    ) -> None:
        super().__init__(ctx, terrain, camera, lod=self._select)
        if registry is None:
            registry = PluginRegistry()
            registry.discover()
        self.registry = registry
        self.registry.attach(
            scene=self, terrain=terrain, camera=self.camera, renderer=self.renderer
        )
        self.set_lod(lod)

    # -- LOD providers -------------------------------------------------------------------------
    def lod_providers(self) -> dict:
        """Name -> provider of every enabled LOD plugin contribution."""
        return self.registry.lod_providers()

    def set_lod(self, name: str) -> None:
        """Make ``name`` the active LOD provider (takes effect on the next frame)."""
        providers = self.lod_providers()
        if name not in providers:
            known = ", ".join(sorted(providers)) or "none"
            raise GlobeviewError(f"no enabled LOD provider named {name!r} (available: {known})")
        self.lod_name = name

    def _select(self, view: ViewState, terrain: TerrainStack) -> RenderSet:
        providers = self.lod_providers()
        provider = providers.get(self.lod_name)
        if provider is not None:
            rs = self.registry.select(provider, view, terrain)
            if rs is not None:
                return rs
            log.warning("LOD provider %s failed; falling back to %s", self.lod_name, DEFAULT_LOD)
        fallback = self.lod_providers().get(DEFAULT_LOD)
        if fallback is not None and self.lod_name != DEFAULT_LOD:
            self.lod_name = DEFAULT_LOD
            rs = self.registry.select(fallback, view, terrain)
            if rs is not None:
                return rs
        return RenderSet.empty()
