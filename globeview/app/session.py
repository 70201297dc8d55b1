"""`GlobeSession`: the headless application model — a `GlobeScene` whose LOD provider and
tools come from the plugin registry, each call isolated (a failing plugin is disabled and the
session falls back to the built-in `chunked-sse`). The CLI's headless renders and the Qt
window both drive a session.

The session is the host boundary: what plugin code returns is checked before the renderer or
another plugin uses it — the provider's `RenderSet` every frame (`RenderSet.validate`), a
tool's displaced points, bend bounds, uniforms, overlay primitives and cache key, a layer
type's layer — and garbage fails the plugin that returned it (one line, see
`PluginRegistry.report_failure`). Only the contributions in use are loaded: choosing a
provider, tool or layer type imports that plugin alone (`PluginRegistry.find`).
"""

from __future__ import annotations

import logging

import moderngl

from globeview.app.lod_host import LodHost
from globeview.app.overlay_host import OverlayHost
from globeview.app.tool_host import ToolFrame, ToolHost
from globeview.geodesy import ecef_to_lonlat
from globeview.lod.render_set import RenderSet
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera
from globeview.model.display import DisplaySettings
from globeview.model.globe import DEFAULT_LOD, Globe
from globeview.plugins.api import NullRendererHooks
from globeview.plugins.registry import PluginRegistry
from globeview.render.frame_pipeline import FramePipeline
from globeview.render.gpu_objects import make_current
from globeview.render.picking import Pick
from globeview.render.renderer import GlobeRenderer
from globeview.render.scene import FrameResult, GlobeScene
from globeview.terrain.compose.stack import TerrainStack

log = logging.getLogger("globeview.session")


class GlobeSession(GlobeScene):
    """A globe scene driven by plugins.

    Args:
        ctx: moderngl context; terrain: the DEM layers; camera: the initial camera.
        registry: a discovered `PluginRegistry` (default: discover the installed plugins).
        lod: name of the LOD provider to start with (default: the globe's, else
            `DEFAULT_LOD`).
        globe: the `Globe` model to show (default: a new one of ``terrain`` and ``camera``);
            its ``terrain`` must be ``terrain``.
        overlay_host: the `OverlayHost` that opens overlays onto ``globe`` (default: a new
            one); a window makes it with its model, before any GL exists, and opens overlays
            with it from the start.
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        terrain: TerrainStack,
        camera: Camera | None = None,
        registry: PluginRegistry | None = None,
        lod: str | None = None,
        *,
        globe: Globe | None = None,
        overlay_host: OverlayHost | None = None,
    ) -> None:
        # The state (camera, tau, LOD and tool names, overlays, display settings) lives in
        # the Globe model, which emits the change events; the session's properties below
        # delegate to it, so there is one copy. A window may make the Globe before any GL
        # context exists and hand it in.
        if globe is None:
            globe = Globe(terrain, camera, lod=lod or DEFAULT_LOD)
        elif globe.terrain is not terrain:
            raise ValueError("GlobeSession: terrain is not the globe's terrain")
        elif camera is not None:
            globe.camera = camera
        if overlay_host is not None:
            if registry is None:
                registry = overlay_host.registry
            if overlay_host.globe is not globe or overlay_host.registry is not registry:
                raise ValueError("GlobeSession: overlay_host is not for this globe and registry")
        self.globe = globe
        self.ctx = ctx
        # The frame pipeline draws every frame (window, CLI, bench); this session is its
        # host (camera, tau, prepare_gpu, select, frame_tool).
        self.pipeline = FramePipeline(GlobeRenderer(ctx, terrain), self)
        self.renderer.settings = globe.display  # the renderer draws the model's settings
        self.last: FrameResult | None = None
        if registry is None:
            registry = PluginRegistry()
            registry.discover()
        self.registry = registry
        self.lod_host = LodHost(globe, registry)
        self.tool_host = ToolHost(globe, registry)
        self.overlay_host = overlay_host or OverlayHost(globe, registry)
        # Plugins get redraw/status hooks, not the GL renderer: headless they are recorded,
        # and the window attaches its own (redraw = widget.update, status = status bar).
        self.hooks = NullRendererHooks()
        self.registry.attach(scene=self, terrain=terrain, camera=self.camera, renderer=self.hooks)
        try:
            self.set_lod(lod or globe.lod)
        except BaseException:
            # No session comes back to release the renderer: release its GL objects here
            # (a refused LOD name leaked a whole tile pool per attempt in a kept context).
            self.release_gl()
            raise

    # -- the model's state (one copy: the Globe's) ---------------------------------------------
    @property
    def terrain(self) -> TerrainStack:
        return self.globe.terrain

    @property
    def camera(self) -> Camera:
        return self.globe.camera

    @camera.setter
    def camera(self, camera: Camera) -> None:
        self.globe.camera = camera

    @property
    def tau_px(self) -> float:
        """Screen-space error threshold (pixels); refused where set (`Globe.tau_px`)."""
        return self.globe.tau_px

    @tau_px.setter
    def tau_px(self, value: float) -> None:
        self.globe.tau_px = value

    @property
    def lod_name(self) -> str:
        """Name of the active LOD provider (`Globe.lod`)."""
        return self.globe.lod

    @lod_name.setter
    def lod_name(self, name: str) -> None:
        self.globe.lod = name

    @property
    def active_tool(self) -> str | None:
        """Name of the active tool (`Globe.tool`), None for none."""
        return self.globe.tool

    @active_tool.setter
    def active_tool(self, name: str | None) -> None:
        self.globe.tool = name

    @property
    def settings(self) -> DisplaySettings:
        """The display settings (`Globe.display`, evented)."""
        return self.globe.display

    @property
    def overlay_errors(self) -> list[str]:
        """One line per overlay dropped at a frame because the GPU side refused it."""
        return self.overlay_host.errors

    def take_overlay_errors(self) -> list[str]:
        """The `overlay_errors` not taken yet (oldest first), cleared: a window reports each
        line once after the frame that produced it."""
        taken = list(self.overlay_host.errors)
        self.overlay_host.errors.clear()
        return taken

    @property
    def overlay_layers(self) -> list:
        """The overlay layers, bottom first (`Globe.overlays`)."""
        return self.globe.overlays

    # -- LOD providers (app/lod_host.py) ---------------------------------------------------
    def lod_providers(self) -> dict:
        """Name -> provider of every enabled LOD plugin contribution (imports them all)."""
        return self.lod_host.providers()

    def set_lod(self, name: str) -> None:
        """Make ``name`` the active LOD provider, next frame (`LodHost.choose`: one-line
        `GlobeviewError` for a name no enabled plugin provides; fallback to `DEFAULT_LOD`
        when its plugin fails to load)."""
        self.lod_host.choose(name)

    def reset_lod(self) -> None:
        """Make the active provider forget its per-view cache (before a measured frame)."""
        self.lod_host.reset()

    def _check_render_set(self, rs: RenderSet) -> None:
        """`RenderSet.validate` against this renderer's tiles (raises InvalidRenderSet)."""
        rs.validate(self.renderer.size, self.renderer.pool.verts_per_tile)

    def select(self, view: ViewState) -> RenderSet:
        """The active provider's render set for ``view`` (`LodHost.select`; the frame
        pipeline asks)."""
        return self.lod_host.select(view, self.terrain, self._check_render_set)

    # -- tools ---------------------------------------------------------------------------------
    def tools(self) -> dict:
        """Name -> tool of every enabled tool plugin contribution (imports them all)."""
        return self.registry.tools()

    def find_tool(self, name: str):
        """The enabled tool ``name`` (importing only its plugin), or None."""
        return self.tool_host.find(name)

    def activate_tool(self, name: str | None) -> None:
        """Make ``name`` the active tool (None: no tool). Changes the model only
        (`Globe.tool`): the tool's displacement hook is compiled at the next frame
        (`prepare_gpu`); if it does not compile the tool fails (reported) and the globe's
        tool becomes None. See `globeview.app.tool_host`."""
        self.tool_host.activate(name)

    def tool(self):
        """The active tool object, or None (also None once its plugin has failed)."""
        return self.tool_host.tool()

    def tool_plot(self):
        """The plot the active tool publishes now, checked (`ToolHost.plot`), or None."""
        return self.tool_host.plot()

    def tool_plot_csv(self) -> str | None:
        """The CSV text of that plot (`ToolHost.plot_csv`), or None."""
        return self.tool_host.plot_csv()

    @property
    def displacing(self) -> bool:
        """Whether the active tool moves the terrain (`ToolHost.displaces`)."""
        return self.tool_host.displaces

    def prepare_gpu(self) -> None:
        """Make the GPU objects the model's state needs now (the frame pipeline calls this
        first in every frame, with the context current): the tool's displacement hook and
        the overlay layers' GPU twins. A layer the GL refuses (its limits) is dropped from
        the globe with a one-line message in ``overlay_errors`` (and the log)."""
        self.tool_host.prepare_gpu(self.renderer)
        self.overlay_host.prepare_gpu(self.renderer)

    # -- the frame (FramePipeline's host) ----------------------------------------------------
    def view_state(self, viewport: tuple[int, int]) -> ViewState:
        """The current camera's view with the active tool's displacement, as the next frame
        builds it (no speed): for callers between frames (placing tool points, tests)."""
        view = super().view_state(viewport)
        tool = self.frame_tool()
        return view if tool is None else tool.shape_view(view)

    def frame_tool(self) -> ToolFrame | None:
        """The active tool's part in the next frame (`ToolHost.frame_tool`), or None."""
        return self.tool_host.frame_tool(self.renderer)

    def pick(self, x_px: float, y_px: float) -> Pick | None:
        """The true (un-displaced) terrain point under a pixel of the last frame."""
        tool = self.tool()
        if tool is None or self.renderer.displacement_hook is None:
            return super().pick(x_px, y_px)

        to_true = self.tool_host.to_true
        # The pick is refined against the terrain the pixel shows (the true place's), not the
        # DEM under the drawn place (issue #16: picked heights off by hundreds of metres).
        p = super().pick(x_px, y_px, to_true)
        if p is None:
            return p
        ecef = to_true(p.ecef[None, :]).reshape(3)
        lon, lat, h = ecef_to_lonlat(ecef)
        return Pick(ecef, float(lon), float(lat), float(h), p.on_terrain)

    # -- overlay layers (any layer type, built-in or installed: app/overlay_host.py) ------
    def layer_types(self) -> list:
        """The enabled layer types in dispatch order (`OverlayHost.layer_types`)."""
        return self.overlay_host.layer_types()

    def overlay_file_filter(self) -> str:
        """The Open Overlay dialog's filter: every enabled layer type's patterns."""
        return self.overlay_host.file_filter()

    def layer_type_for(self, path: str, layer_type: str | None = None) -> str:
        """The name of the layer type that opens ``path`` (`OverlayHost.layer_type_for`)."""
        return self.overlay_host.layer_type_for(path, layer_type)

    def add_overlay(self, path: str, layer_type: str | None = None, **style):
        """Open a file as an overlay layer and show it on top (`OverlayHost.open`): one-line
        `GlobeviewError` for a bad file or a failing layer type; no GL."""
        return self.overlay_host.open(path, layer_type, **style)

    def add_embedded_overlays(self, imagery: bool = False) -> list:
        """The embedded default overlays (`OverlayHost.open_embedded`)."""
        return self.overlay_host.open_embedded(imagery)

    def remove_overlay(self, layer) -> None:
        """Take ``layer`` off the globe (its GPU twin is released at the next frame)."""
        self.overlay_host.remove(layer)

    def release_gl(self) -> None:
        """Release the GL objects the session owns (with its context current), and stop
        listening to the globe, which may outlive the session (a window's model)."""
        make_current(self.ctx)  # never another headless context's names
        self.tool_host.close()
        self.pipeline.release()
        self.renderer.release()
