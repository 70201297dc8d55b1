"""`GlobeScene`: camera + terrain + display settings + renderer, rendering into any
framebuffer. The CLI's headless renders and the Qt window drive the same scene."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import moderngl

from globeview.lod.render_set import FrameStats, RenderSet
from globeview.lod.view_state import ViewState, check_tau
from globeview.model.camera import Camera
from globeview.render.picking import Pick, pick
from globeview.render.renderer import GlobeRenderer
from globeview.terrain.stack import TerrainStack

LodFunction = Callable[[ViewState, TerrainStack], RenderSet]


@dataclass
class FrameResult:
    view: ViewState
    render_set: RenderSet
    stats: FrameStats


class GlobeScene:
    """One globe view: render it with ``render(fbo, viewport)``, pick with ``pick(x, y)``.

    ``lod`` is the function choosing the render set (an LOD provider's ``select``; the
    plugin layer's `GlobeSession` supplies the active provider); tau_px is the screen-space
    error threshold in pixels; speed_mps the navigation speed (m/s).
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        terrain: TerrainStack,
        camera: Camera | None = None,
        lod: LodFunction | None = None,
    ) -> None:
        if lod is None:
            raise TypeError(
                "GlobeScene needs an LOD function (view, terrain) -> RenderSet; for the "
                "plugin-driven scene use globeview.plugins.session.GlobeSession(ctx, terrain, "
                "camera, lod='chunked-sse')"
            )
        self.ctx = ctx
        self.terrain = terrain
        self.camera = camera or Camera.from_lonlat(0.0, 20.0, 2.0e7)
        self.renderer = GlobeRenderer(ctx, terrain)
        self.lod: LodFunction = lod
        self.lod_name = getattr(lod, "__qualname__", "lod")
        self.tau_px = 2.0
        self.speed_mps = 0.0
        self.last: FrameResult | None = None
        self._last_fbo: moderngl.Framebuffer | None = None

    @property
    def tau_px(self) -> float:
        """Screen-space error threshold (pixels)."""
        return self._tau_px

    @tau_px.setter
    def tau_px(self, value: float) -> None:
        # Refused where it is set (ValueError, one line with the valid range), so neither the
        # window nor a plugin can leave a NaN or zero tau for the next frame to trip over.
        self._tau_px = check_tau(value)

    @property
    def settings(self):
        return self.renderer.settings

    def view_state(self, viewport: tuple[int, int]) -> ViewState:
        return ViewState.from_camera(
            self.camera,
            viewport,
            tau_px=self.tau_px,
            exaggeration=self.renderer.settings.exaggeration,
            speed_mps=self.speed_mps,
        )

    def render(self, fbo: moderngl.Framebuffer, viewport: tuple[int, int]) -> FrameResult:
        view = self.view_state(viewport)
        rs = self.lod(view, self.terrain)
        stats = self.renderer.draw(view, rs, fbo)
        stats.lod_provider = self.lod_name
        self.last = FrameResult(view, rs, stats)
        self._last_fbo = fbo
        return self.last

    def pick(self, x_px: float, y_px: float, to_true=None) -> Pick | None:
        """The terrain point under a pixel of the last rendered frame (``to_true``: drawn ->
        true ECEF points of a displacing tool, see `picking.refine_on_terrain`)."""
        if self.last is None or self._last_fbo is None:
            return None
        terrain = self.terrain if self.terrain.visible_layers else None
        height_at = None
        if terrain is not None:
            # The surface the LOD converges to, the finest level (as `globeview height`
            # answers); the default level is capped at 12 and Crater Lake's DEM has 13.
            def height_at(lon: float, lat: float) -> float:
                return terrain.height_at(lon, lat, level=terrain.max_level)

        return pick(self.last.view, self._last_fbo, x_px, y_px, height_at, to_true)
