"""Headless rendering: an EGL standalone context and an offscreen framebuffer to draw into."""

from __future__ import annotations

import moderngl
import numpy as np

from globeview.errors import GlobeviewError


class RenderError(GlobeviewError):
    """OpenGL is not available or not capable enough."""


def create_headless_context() -> moderngl.Context:
    """A moderngl context without a display (EGL; Mesa llvmpipe works with no GPU)."""
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as exc:  # moderngl raises plain Exception subclasses from glcontext
        raise RenderError(
            "cannot create a headless OpenGL context through EGL "
            f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__}); "
            "install Mesa's EGL (Debian: libegl1 libegl-mesa0 libgl1-mesa-dri)"
        ) from None
    return ctx


class OffscreenTarget:
    """A colour + depth framebuffer of a given size (pixels)."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.ctx = ctx
        self.size = (int(size[0]), int(size[1]))
        self.color = ctx.texture(self.size, 4)
        self.depth = ctx.depth_texture(self.size)
        self.fbo = ctx.framebuffer(color_attachments=[self.color], depth_attachment=self.depth)

    def read_rgb(self) -> np.ndarray:
        """(height, width, 3) uint8, row 0 at the top of the image."""
        w, h = self.size
        data = np.frombuffer(self.fbo.read(components=3, alignment=1), dtype=np.uint8)
        return data.reshape(h, w, 3)[::-1].copy()

    def read_depth(self) -> np.ndarray:
        """(height, width) float32 window depth in 0..1 (1 = nothing drawn), row 0 at top."""
        w, h = self.size
        data = np.frombuffer(
            self.fbo.read(attachment=-1, components=1, dtype="f4", alignment=1), np.float32
        )
        return data.reshape(h, w)[::-1].copy()

    def release(self) -> None:
        for obj in (self.fbo, self.color, self.depth):
            obj.release()
