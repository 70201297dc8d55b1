"""Headless rendering: an EGL standalone context and an offscreen framebuffer to draw into."""

from __future__ import annotations

import moderngl
import numpy as np

from globeview.errors import GlobeviewError
from globeview.render.gpu_objects import gpu_objects, make_current


class RenderError(GlobeviewError):
    """OpenGL is not available or not capable enough."""


#: A released headless context kept for the next `create_headless_context` (at most one).
#: moderngl 5.13 never frees a context's own bookkeeping (its C dealloc drops none of its
#: references: ~40 kB per context), so a process that opens and closes globes again and again
#: grew by that much per globe; handing contexts back with `release_headless_context` reuses one.
_SPARE: list[moderngl.Context] = []


def create_headless_context(*, fresh: bool = False) -> moderngl.Context:
    """A moderngl context without a display (EGL; Mesa llvmpipe works with no GPU): the one
    handed back by `release_headless_context` when there is one, else a new one. ``fresh``:
    always a new one, for a context that lives on a thread of its own (the spare is current
    on the thread that handed it back, and EGL makes a context current on one thread only);
    release it with ``ctx.release()`` on that thread."""
    if _SPARE and not fresh:
        ctx = _SPARE.pop()
        ctx.__enter__()  # make it current on this thread again (no __exit__: it stays current)
        return ctx
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as exc:  # noqa: BLE001  moderngl raises plain Exception subclasses from glcontext
        raise RenderError(
            "cannot create a headless OpenGL context through EGL "
            f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__}); "
            "install Mesa's EGL (Debian: libegl1 libegl-mesa0 libgl1-mesa-dri)"
        ) from None
    ctx.extra = {"globeview_headless": True}
    return ctx


def release_headless_context(ctx: moderngl.Context) -> None:
    """Close a context from `create_headless_context` once everything made in it has been
    released (session.release_gl, target.release): it is kept, with its state back to the
    defaults, for the next `create_headless_context`, instead of being destroyed (see
    `_SPARE`). Any other context, or one more than the spare, is released."""
    if _SPARE or not (isinstance(ctx.extra, dict) and ctx.extra.get("globeview_headless")):
        ctx.release()
        return
    ctx.enable_only(moderngl.NOTHING)
    ctx.depth_func = "<"
    ctx.blend_func = moderngl.DEFAULT_BLENDING
    ctx.blend_equation = moderngl.FUNC_ADD
    ctx.wireframe = False
    ctx.front_face = "ccw"
    ctx.cull_face = "back"
    ctx.polygon_offset = (0.0, 0.0)
    ctx.point_size = 1.0
    ctx.line_width = 1.0
    ctx.finish()
    _SPARE.append(ctx)


class OffscreenTarget:
    """A colour + depth framebuffer of a given size (pixels)."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.ctx = ctx  # current while its objects are made: gpu_objects enters it
        self.size = (int(size[0]), int(size[1]))
        self.color = gpu_objects(ctx).texture(self.size, 4)
        self.depth = gpu_objects(ctx).depth_texture(self.size)
        self.fbo = gpu_objects(ctx).framebuffer(
            color_attachments=[self.color], depth_attachment=self.depth
        )

    def read_rgb(self) -> np.ndarray:
        """(height, width, 3) uint8, row 0 at the top of the image."""
        make_current(self.ctx)
        w, h = self.size
        data = np.frombuffer(self.fbo.read(components=3, alignment=1), dtype=np.uint8)
        return data.reshape(h, w, 3)[::-1].copy()

    def read_depth(self) -> np.ndarray:
        """(height, width) float32 window depth in 0..1 (1 = nothing drawn), row 0 at top."""
        make_current(self.ctx)
        w, h = self.size
        data = np.frombuffer(
            self.fbo.read(attachment=-1, components=1, dtype="f4", alignment=1), np.float32
        )
        return data.reshape(h, w)[::-1].copy()

    def release(self) -> None:
        make_current(self.ctx)
        for obj in (self.fbo, self.color, self.depth):
            obj.release()
