"""`FramePipeline`: one frame of the globe, top to bottom.

Every frame anyone draws — the window's ``paintGL``, ``globeview render``, ``globeview bench``,
the benchmarks/ scripts, the plugin-author fixture ``rendered`` — runs `FramePipeline.run`,
which reads as the data flow of a frame:

1. **GPU objects** the model asks for (the host's ``prepare_gpu``: e.g. the active tool's
   displacement hook compiled into the terrain shader).
2. **View**: the camera's speed from its history (eye positions and the frames' time stamps),
   the active tool's animation step, then the `ViewState`, built once, with the tool's
   displacement and its shader uniforms.
3. **LOD**: the active provider selects a `RenderSet` for that view (the host's ``select``).
4. **Tile loading and upload**: the render set fitted to the tile pool, missing tiles built
   and uploaded (all of them headless; a budget per frame from worker threads in the window).
5. **Draw**: the terrain tiles in one multi-draw call, with the imagery drape.
6. **Overlays**: vector and point layers, depth-tested against the terrain.
7. **Tool overlay**: the active tool's markers and lines over the frame.
8. **Stats**: the frame's figures (`FrameStats`), returned in a `FrameResult`.

The pipeline knows the plugin host only through two small protocols, `FrameHost` and
`FrameTool` (render sits below app in the layers): the host checks what plugin code
returns before it reaches the pipeline.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol

import moderngl
import numpy as np

from globeview.lod.render_set import FrameStats, RenderSet
from globeview.lod.view_state import ViewState
from globeview.model.camera import Camera

if TYPE_CHECKING:
    from globeview.render.overlay_tools import ToolOverlayRenderer
    from globeview.render.renderer import GlobeRenderer
    from globeview.terrain.compose.stack import TerrainStack

#: Frames further apart than this (seconds) are a pause, not a move: the speed is 0.
PAUSE_S = 0.5


@dataclass
class FrameResult:
    """What one frame drew.

    Attributes:
        view: the frame's `ViewState` (the one the provider, the tool and the draw saw);
            ``view.speed_mps`` is the camera speed the pipeline derived.
        render_set: the render set the LOD provider selected.
        stats: the frame's figures.
        overlay_drawn: tool overlay instances drawn (markers and line segments).
        animating: the active tool's ``animate`` asked for another frame (the window keeps
            a repaint timer running while it does).
        target: the framebuffer the frame was drawn into (picking reads its depth).
    """

    view: ViewState
    render_set: RenderSet
    stats: FrameStats
    overlay_drawn: int = 0
    animating: bool = False
    target: moderngl.Framebuffer | None = None


class FrameTool(Protocol):
    """The active tool's part in a frame, as the plugin host offers it: each method runs the
    plugin's code behind the host's checks and isolation, so a failure disables the tool and
    the method returns the neutral value instead of raising."""

    def animate(self, now_s: float) -> bool:
        """Advance the tool's animation to ``now_s`` (seconds); True while it moves."""
        ...

    def shape_view(self, view: ViewState) -> ViewState:
        """``view`` with the tool's CPU displacement (``displace``, ``displacement_bend``,
        ``displacement_key``), or ``view`` itself when the tool displaces nothing."""
        ...

    def uniforms(self, view: ViewState) -> dict[str, object] | None:
        """The displacement hook's uniforms for this frame (``{}`` without a hook); None
        when the tool failed (the pipeline then draws the frame without its displacement)."""
        ...

    def overlay(self, view: ViewState) -> tuple[Sequence[Any], Callable | None]:
        """The checked overlay primitives (`Marker`, `Polyline`) to draw over the frame and
        the displacement to draw them with (None: none)."""
        ...


class FrameHost(Protocol):
    """What the pipeline reads from the application model each frame (`GlobeSession`, or a
    bare `GlobeScene` with an LOD function)."""

    camera: Camera
    tau_px: float
    terrain: TerrainStack
    lod_name: str  # the provider that drew, read after ``select`` (it may fall back)

    def prepare_gpu(self) -> None:
        """Create the GPU objects the model's state needs before drawing."""
        ...

    def select(self, view: ViewState) -> RenderSet:
        """The active LOD provider's render set for ``view``."""
        ...

    def frame_tool(self) -> FrameTool | None:
        """The active tool's frame adapter, or None."""
        ...


class CameraMotion:
    """Camera speed from its history: the distance the eye moved since the previous frame
    over the time between the frames' stamps (metres per second, ECEF).

    The speed is 0 on the first frame, after a pause longer than ``pause_s`` (default
    `PAUSE_S`: the window was idle, the next move starts from rest), when the time stamp did
    not advance (or went back), and when the camera object was replaced (a new camera is a
    cut, not a move). A recorded flight sampled sparsely sets ``pause_s`` to infinity: its
    camera never rests between samples."""

    def __init__(self, pause_s: float = PAUSE_S) -> None:
        self.pause_s = pause_s
        self._camera: Camera | None = None
        self._eye: np.ndarray | None = None
        self._t: float = 0.0

    def reset(self) -> None:
        """Forget the history: the next frame's speed is 0."""
        self._camera = None
        self._eye = None

    def speed(self, camera: Camera, now_s: float) -> float:
        """Record ``camera``'s eye at ``now_s`` and return its speed since the last call."""
        eye = np.array(camera.eye, dtype=np.float64).reshape(3)
        speed = 0.0
        if self._eye is not None and camera is self._camera:
            dt = now_s - self._t
            if 0.0 < dt <= self.pause_s:
                speed = float(np.linalg.norm(eye - self._eye)) / dt
        self._camera, self._eye, self._t = camera, eye, now_s
        return speed if math.isfinite(speed) else 0.0


def check_time(now_s: object) -> float:
    """``now_s`` as float seconds; ValueError (one line) for a non-number or a non-finite one."""
    if isinstance(now_s, bool) or not isinstance(now_s, int | float | np.integer | np.floating):
        raise ValueError(f"now_s must be a number of seconds, not {type(now_s).__name__}")
    t = float(now_s)
    if not math.isfinite(t):
        raise ValueError(f"now_s must be a finite number of seconds, not {t}")
    return t


class FramePipeline:
    """Runs the frames of one globe view (module docstring).

    Args:
        renderer: the terrain renderer (replaceable: ``pipeline.renderer = ...``).
        host: the application model the frame is drawn from (`FrameHost`).
        clock: seconds for frames drawn without a time stamp (default `time.monotonic`).
    """

    def __init__(
        self,
        renderer: GlobeRenderer,
        host: FrameHost,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.renderer = renderer
        self.host = host
        self.clock = clock
        self.motion = CameraMotion()
        self._tool_overlay: ToolOverlayRenderer | None = None  # made on first use

    def run(
        self,
        fbo: moderngl.Framebuffer,
        viewport: tuple[int, int],
        now_s: float | None = None,
    ) -> FrameResult:
        """Draw one frame of ``viewport`` (pixels) into ``fbo`` at time ``now_s`` (seconds on
        any steady clock; default ``clock()``) and return what it drew."""
        host, renderer = self.host, self.renderer
        now_s = self.clock() if now_s is None else check_time(now_s)

        # 1. GPU objects the model's state asks for (the tool's displacement hook).
        host.prepare_gpu()

        # 2. View: speed from the camera's history, the tool's animation step, then the
        #    ViewState, once, with the tool's displacement and uniforms.
        camera = host.camera
        speed = self.motion.speed(camera, now_s)
        tool = host.frame_tool()
        animating = bool(tool.animate(now_s)) if tool is not None else False
        view = ViewState.from_camera(
            camera,
            viewport,
            tau_px=host.tau_px,
            exaggeration=renderer.settings.exaggeration,
            speed_mps=speed,
        )
        uniforms: dict[str, object] | None = None
        if tool is not None:
            view = tool.shape_view(view)
            uniforms = tool.uniforms(view)
            if uniforms is None:  # the tool failed: this frame is drawn without it
                tool = None
                view = replace(view, displace=None, displacement_bend=None, displacement_key=None)

        # 3. LOD: the provider's render set for this view.
        render_set = host.select(view)

        # 4. Tile loading and upload (draw_ms runs from here to the GPU's finish).
        t0 = time.perf_counter()
        stats = FrameStats()
        drawn = renderer.load(render_set, stats)

        # 5. Draw the terrain.
        triangles = renderer.draw_terrain(view, drawn, fbo, uniforms)

        # 6. Overlays: vectors and point objects over the terrain.
        stats.extra.update(renderer.draw_overlays(view, drawn))

        # 7. The tool's overlay: markers and lines.
        overlay_drawn = self._draw_tool_overlay(tool, view, fbo)
        renderer.ctx.finish()

        # 8. Stats.
        renderer.finish_stats(stats, view, drawn, triangles, t0)
        stats.lod_provider = host.lod_name
        # The host keeps the last frame (`GlobeScene.last`); the pipeline keeps none.
        return FrameResult(view, render_set, stats, overlay_drawn, animating, fbo)

    def _draw_tool_overlay(
        self, tool: FrameTool | None, view: ViewState, fbo: moderngl.Framebuffer
    ) -> int:
        """Draw the tool's overlay primitives over ``fbo``; returns the instances drawn."""
        if tool is None:
            return 0
        prims, displace = tool.overlay(view)
        if not prims:
            return 0
        if self._tool_overlay is None:
            from globeview.render.overlay_tools import ToolOverlayRenderer

            self._tool_overlay = ToolOverlayRenderer(self.renderer.ctx)
        return self._tool_overlay.draw(view, list(prims), fbo, displace)

    def release(self) -> None:
        """Release the pipeline's own GL objects (the tool overlay's); with the context
        current. The renderer is released by its owner."""
        if self._tool_overlay is not None:
            self._tool_overlay.release()
            self._tool_overlay = None
