"""`GlobeSession`: the headless application model — a `GlobeScene` whose LOD provider and
tools come from the plugin registry, each call isolated (a failing plugin is disabled and the
session falls back to the built-in `chunked-sse`). The CLI's headless renders and the Qt
window both drive a session."""

from __future__ import annotations

import logging

import moderngl
import numpy as np

from globeview.errors import GlobeviewError
from globeview.geodesy import ecef_to_lonlat
from globeview.plugins.api import NullRendererHooks, Tool
from globeview.plugins.registry import PluginRegistry
from globeview.render.camera import Camera
from globeview.render.picking import Pick
from globeview.render.render_set import RenderSet
from globeview.render.renderer import DisplacementHook
from globeview.render.scene import FrameResult, GlobeScene
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
        self.active_tool: str | None = None
        self.overlay_layers: list = []
        self._tool_overlay = None  # ToolOverlayRenderer, made on first use
        self._marker_heights: dict[tuple[float, float, float], float] = {}
        # Plugins get redraw/status hooks, not the GL renderer: headless they are recorded,
        # and the window attaches its own (redraw = widget.update, status = status bar).
        self.hooks = NullRendererHooks()
        self.registry.attach(scene=self, terrain=terrain, camera=self.camera, renderer=self.hooks)
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

    def reset_lod(self) -> None:
        """Make the active provider forget its per-view cache (before a measured frame)."""
        provider = self.lod_providers().get(self.lod_name)
        if provider is not None:
            self.registry.invoke(provider, "reset")

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

    # -- tools ---------------------------------------------------------------------------------
    def tools(self) -> dict:
        """Name -> tool of every enabled tool plugin contribution."""
        return self.registry.tools()

    def activate_tool(self, name: str | None) -> None:
        """Make ``name`` the active tool (None: no tool). A tool's displacement hook is
        compiled into the terrain shader now; if it does not compile the tool's plugin is
        disabled and reported, and the terrain keeps the plain shader."""
        if name is not None and name not in self.tools():
            raise GlobeviewError(f"no enabled tool named {name!r}")
        previous = self.tool()
        if previous is not None and name != self.active_tool:
            self.registry.invoke(previous, "deactivate")
        self.active_tool = name
        tool = self.tool()
        glsl = self.registry.invoke(tool, "displacement_glsl") if tool is not None else None
        if not glsl:
            if self.renderer._hook is not None:
                self.renderer.set_displacement_hook(None)
            return
        owner = self.registry.owner_of(tool)
        try:
            self.renderer.set_displacement_hook(DisplacementHook(owner, glsl))
        except Exception as exc:  # moderngl.Error: the plugin's GLSL failed to compile
            self.registry.report_failure(owner, exc)
            self.active_tool = None
            if self.renderer._hook is not None:
                self.renderer.set_displacement_hook(None)

    def tool(self):
        """The active tool object, or None (also None once its plugin has failed)."""
        if self.active_tool is None:
            return None
        tool = self.tools().get(self.active_tool)
        if tool is None:  # its plugin was disabled or failed
            self.active_tool = None
            if self.renderer._hook is not None:
                self.renderer.set_displacement_hook(None)
        return tool

    def _displace(self, points: np.ndarray) -> np.ndarray:
        tool = self.tool()
        if tool is None:
            return points
        return self.registry.invoke(tool, "displacement_numpy", points, default=points)

    def _bend(self, points: np.ndarray, displaced: np.ndarray | None = None) -> np.ndarray:
        """The active tool's bend bound (`Tool.displacement_bend_m`); the exact measure when
        it returns None or its plugin has failed."""
        from globeview.render.culling import displacement_chord_error_m

        tool = self.tool()
        bend = None
        if tool is not None:
            bend = self.registry.invoke(tool, "displacement_bend_m", points, displaced)
        if bend is None:
            return displacement_chord_error_m(self._displace, points, displaced)
        return np.asarray(bend, dtype=np.float64)

    def view_state(self, viewport: tuple[int, int]):
        """The base view, plus the active tool's CPU displacement (``displace``), its
        ``displacement_key()`` if it has one and, when the tool overrides
        `Tool.displacement_bend_m`, its bend bound (``displacement_bend``)."""
        view = super().view_state(viewport)
        tool = self.tool()
        if tool is None or self.renderer._hook is None:
            return view
        from dataclasses import replace

        own_bend = getattr(type(tool), "displacement_bend_m", None) not in (
            None,
            Tool.displacement_bend_m,
        )
        key = None
        if callable(getattr(tool, "displacement_key", None)):  # tools need not subclass Tool
            key = self.registry.invoke(tool, "displacement_key")
        return replace(
            view,
            displace=self._displace,
            displacement_bend=self._bend if own_bend else None,
            displacement_key=key,
        )

    def render(self, fbo: moderngl.Framebuffer, viewport: tuple[int, int]) -> FrameResult:
        tool = self.tool()
        hook = self.renderer._hook
        if tool is not None and hook is not None:
            view = self.view_state(viewport)
            uniforms = self.registry.invoke(tool, "displacement_uniforms", view, default=None)
            if uniforms is None:  # the tool failed: drop its hook this frame
                self.renderer.set_displacement_hook(None)
            else:
                hook.uniforms = dict(uniforms)
        return super().render(fbo, viewport)

    def pick(self, x_px: float, y_px: float) -> Pick | None:
        """The true (un-displaced) terrain point under a pixel of the last frame."""
        p = super().pick(x_px, y_px)
        tool = self.tool()
        if p is None or tool is None or self.renderer._hook is None:
            return p
        true = self.registry.invoke(
            tool, "displacement_inverse_numpy", p.ecef[None, :], default=p.ecef[None, :]
        )
        ecef = np.asarray(true, dtype=np.float64).reshape(3)
        lon, lat, h = ecef_to_lonlat(ecef)
        return Pick(ecef, float(lon), float(lat), float(h), p.on_terrain)

    # -- overlay layers (imagery, thematic, vectors, points) ------------------------------------
    def add_overlay(self, path: str, **style):
        """Open a raster or vector file as an overlay layer (its type decided by content) and
        show it. Bad files raise a one-line `GlobeviewError`; the layers plugin stays enabled."""
        from globeview.plugins.builtin.layers import detect_layer_type

        kind = detect_layer_type(str(path))
        layer_type = self.registry.layer_types().get(kind)
        if layer_type is None:
            raise GlobeviewError(f"no enabled layer plugin opens {kind} files ({path})")
        layer = self.registry.invoke(layer_type, "open", str(path), user_errors=True, **style)
        if layer is None:
            raise GlobeviewError(f"the layer plugin failed to open {path} (see the plugin list)")
        layer.attach(self.renderer)
        self.overlay_layers.append(layer)
        return layer

    def add_embedded_overlays(self, imagery: bool = False) -> list:
        """The embedded default overlays: Natural Earth borders and coastlines (and the Blue
        Marble imagery with ``imagery``)."""
        from globeview.plugins.builtin.layers import embedded_layers

        if "layers" not in self.registry or not self.registry.is_active("layers"):
            return []
        layers = embedded_layers(imagery=imagery)
        for layer in layers:
            layer.attach(self.renderer)
        self.overlay_layers.extend(layers)
        return layers

    def remove_overlay(self, layer) -> None:
        layer.detach(self.renderer)
        self.overlay_layers.remove(layer)

    def release_gl(self) -> None:
        """Release the GL objects the session owns (with its context current)."""
        if self._tool_overlay is not None:
            self._tool_overlay.release()
            self._tool_overlay = None
        self.renderer.release()

    # -- the active tool's overlay (markers, fold lines) ----------------------------------------
    def draw_tool_overlay(self, fbo: moderngl.Framebuffer, view=None) -> int:
        """Draw the active tool's overlay primitives over the frame just rendered into
        ``fbo`` (the window and the CLI both call this); returns the instances drawn."""
        tool = self.tool()
        view = view if view is not None else (self.last.view if self.last else None)
        if tool is None or view is None:
            return 0
        prims = self.registry.invoke(tool, "overlay", view, default=None) or []
        if not prims:
            return 0
        if self._tool_overlay is None:
            from globeview.render.overlay_tools import ToolOverlayRenderer

            self._tool_overlay = ToolOverlayRenderer(self.ctx)
        prims = [self._drape_marker(p) for p in prims]
        displace = self._displace if self.renderer._hook is not None else None
        return self._tool_overlay.draw(view, prims, fbo, displace)

    def _drape_marker(self, prim):
        """A marker on the ellipsoid (height < 1 m) lifted to the terrain surface (with the
        exaggeration), so it marks the ground the user clicked in oblique views too."""
        from dataclasses import replace

        from globeview.geodesy import lonlat_to_ecef

        pos = getattr(prim, "position", None)
        if pos is None:
            return prim
        lon, lat, h = (float(v) for v in np.asarray(ecef_to_lonlat(np.asarray(pos))).ravel())
        if abs(h) >= 1.0 or not self.terrain.visible_layers:
            return prim
        exag = float(self.settings.exaggeration)
        key = (round(lon, 9), round(lat, 9), exag)
        ground = self._marker_heights.get(key)
        if ground is None:
            try:
                ground = float(self.terrain.height_at(lon, lat)) * exag
            except GlobeviewError:  # no data there: keep it on the ellipsoid
                ground = 0.0
            if len(self._marker_heights) > 256:
                self._marker_heights.clear()
            self._marker_heights[key] = ground
        new = tuple(float(v) for v in np.asarray(lonlat_to_ecef(lon, lat, ground)).ravel())
        return replace(prim, position=new)
