"""`GlobeScene`: camera + terrain + renderer + one `FramePipeline`, rendering into any
framebuffer. `GlobeSession` (plugins) is a scene whose LOD provider and tool come from
plugins; a bare scene takes an LOD function (tests, the layer-blend benchmark)."""

from __future__ import annotations

from collections.abc import Callable

import moderngl
import numpy as np

from globeview.errors import StoreError
from globeview.lod.render_set import RenderSet
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera
from globeview.model.display import DisplaySettings
from globeview.render.frame_pipeline import FramePipeline, FrameResult, FrameTool
from globeview.render.gpu_objects import make_current
from globeview.render.picking import Pick, pick
from globeview.render.renderer import GlobeRenderer
from globeview.terrain.compose.stack import TerrainStack
from globeview.validate import check_tau

LodFunction = Callable[[ViewState, TerrainStack], RenderSet]

__all__ = ["FrameResult", "GlobeScene", "LodFunction"]


class GlobeScene:
    """One globe view: render it with ``render(fbo, viewport, now_s)``, pick with
    ``pick(x, y)``. It is the `FrameHost` of its pipeline.

    ``lod`` is the function choosing the render set (an LOD provider's ``select``; the
    plugin layer's `GlobeSession` supplies the active provider); tau_px is the screen-space
    error threshold in pixels.
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
                "plugin-driven scene use globeview.app.session.GlobeSession(ctx, terrain, "
                "camera, lod='chunked-sse')"
            )
        self.ctx = ctx
        self.terrain = terrain
        self.camera = camera or Camera.from_lonlat(0.0, 20.0, 2.0e7)
        self.pipeline = FramePipeline(GlobeRenderer(ctx, terrain), self)
        self.lod: LodFunction = lod
        self.lod_name = getattr(lod, "__qualname__", "lod")
        self.tau_px = 2.0
        self.last: FrameResult | None = None

    @property
    def renderer(self) -> GlobeRenderer:
        """The terrain renderer the pipeline draws with."""
        return self.pipeline.renderer

    @renderer.setter
    def renderer(self, renderer: GlobeRenderer) -> None:
        self.pipeline.renderer = renderer

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
    def settings(self) -> DisplaySettings:
        return self.renderer.settings

    # -- the FrameHost the pipeline reads ------------------------------------------------------
    def prepare_gpu(self) -> None:
        """Nothing to prepare for a bare scene (the session compiles tool hooks here)."""

    def select(self, view: ViewState) -> RenderSet:
        """The LOD function's render set for ``view``."""
        return self.lod(view, self.terrain)

    def frame_tool(self) -> FrameTool | None:
        """A bare scene has no tools."""
        return None

    # -- frames --------------------------------------------------------------------------------
    def view_state(self, viewport: tuple[int, int]) -> ViewState:
        """The view of the current camera (no speed, no tool): for callers between frames,
        e.g. navigation's ray casts and placing tool points."""
        return ViewState.from_camera(
            self.camera,
            viewport,
            tau_px=self.tau_px,
            exaggeration=self.renderer.settings.exaggeration,
        )

    def render(
        self,
        fbo: moderngl.Framebuffer,
        viewport: tuple[int, int],
        now_s: float | None = None,
    ) -> FrameResult:
        """Run one frame through the pipeline (`FramePipeline.run`), its context current."""
        make_current(self.ctx)
        self.last = self.pipeline.run(fbo, viewport, now_s)
        return self.last

    def pick(
        self,
        x_px: float,
        y_px: float,
        to_true: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> Pick | None:
        """The terrain point under a pixel of the last rendered frame (``to_true``: drawn ->
        true ECEF points of a displacing tool, see `picking.refine_on_terrain`)."""
        if self.last is None or self.last.target is None:
            return None
        terrain = self.terrain if self.terrain.visible_layers else None
        height_at = None
        if terrain is not None:
            # The surface the LOD converges to, the finest level (as `globeview height`
            # answers); the default level is capped at 12 and Crater Lake's DEM has 13.
            def height_at(lon: float, lat: float) -> float:
                return terrain.height_at(lon, lat, level=terrain.max_level)

        try:
            return pick(self.last.view, self.last.target, x_px, y_px, height_at, to_true)
        except StoreError:
            # The finest tile under the pixel cannot be read now (a remote store's tile that
            # failed, or one not fetched yet on the window's UI thread, which never waits for
            # the network): the depth buffer's point, on the mesh drawn, unrefined.
            return pick(self.last.view, self.last.target, x_px, y_px, None, to_true)
