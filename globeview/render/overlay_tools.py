"""Tool overlays: the active tool's markers and polylines drawn over the terrain.

A tool's ``overlay(view)`` returns `Marker` and `Polyline` primitives (globeview.plugins.api;
duck-typed here so ``render`` does not import the plugin layer). `ToolOverlayRenderer` draws
them into the framebuffer the terrain was just drawn into:

- markers are screen-space discs of ``size_px`` diameter (filled, with a dark rim so they
  read on any terrain colour); polyline segments are quads ``width_px`` wide in screen space.
- **Drawn on top** (no depth test), not depth-tested against the terrain: tool primitives are
  interaction feedback and must stay visible where the terrain's relief would hide them (the
  collapse tool's fold lines run along the ellipsoid, under the mountains). Instead, what lies
  beyond the ellipsoid's horizon is dropped on the CPU (`facing_eye`): a point is drawn when
  the ellipsoid's normal there faces the eye, so nothing from the far side of the globe shows
  through it. A segment is drawn when both its ends are.
- Positions are formed **relative to the eye in float64** on the CPU and only then rounded to
  float32 for the GPU: no absolute ECEF coordinate is ever rounded to float32.
- ``displace`` (the active tool's ``displacement_numpy``) is applied to every position first,
  so primitives sit where the displaced (e.g. collapsed) terrain is drawn.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from importlib import resources
from typing import Any

import moderngl
import numpy as np

from globeview.render.view_state import INV_AXES2, ViewState

#: Floats per instance: a (3), b (3), colour (4), size, kind.
FLOATS = 12

Displace = Callable[[np.ndarray], np.ndarray]


def _shader(name: str) -> str:
    return resources.files("globeview.render").joinpath("shaders", name).read_text()


def facing_eye(points_ecef: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """(N,) bool: the ellipsoid normal at each point (N, 3) faces the eye, i.e. the point is
    on the near side of the ellipsoid's horizon (a small tolerance keeps points at the limb)."""
    p = np.asarray(points_ecef, np.float64).reshape(-1, 3)
    inv = np.array(INV_AXES2)
    normal = p * inv
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    to_eye = np.asarray(eye, np.float64) - p
    dist = np.linalg.norm(to_eye, axis=1)
    return np.einsum("ij,ij->i", normal, to_eye) > -1e-3 * np.maximum(dist, 1.0)


def overlay_instances(
    view: ViewState, primitives: Sequence[Any], displace: Displace | None = None
) -> np.ndarray:
    """The (K, FLOATS) float32 instance table of markers and segments for ``view``.

    Markers are objects with ``position`` (ECEF m), ``color`` RGBA and ``size_px``; polylines
    objects with ``points`` (N, 3), ``color``, ``width_px`` and ``closed``. Hidden ones (beyond
    the horizon) are left out. Positions are displaced, then made relative to ``view.eye`` in
    float64, then rounded to float32."""
    eye = np.asarray(view.eye, np.float64)
    rows: list[np.ndarray] = []
    markers = [p for p in primitives if hasattr(p, "position")]
    lines = [p for p in primitives if hasattr(p, "points")]

    def place(points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        if displace is not None and len(pts):
            pts = np.asarray(displace(pts), np.float64).reshape(-1, 3)
        return pts

    if markers:
        pos = place(np.array([m.position for m in markers], np.float64))
        keep = facing_eye(pos, eye) & np.all(np.isfinite(pos), axis=1)
        rel = pos - eye
        for i in np.nonzero(keep)[0]:
            m = markers[i]
            rows.append(
                np.concatenate([rel[i], rel[i], _rgba(m.color), [float(m.size_px), 0.0]])[None]
            )
    for line in lines:
        pts = place(line.points)
        if len(pts) < 2:
            continue
        if getattr(line, "closed", False):
            pts = np.concatenate([pts, pts[:1]])
        ok = facing_eye(pts, eye) & np.all(np.isfinite(pts), axis=1)
        seg = ok[:-1] & ok[1:]
        if not seg.any():
            continue
        rel = pts - eye
        a, b = rel[:-1][seg], rel[1:][seg]
        n = len(a)
        style = np.concatenate([_rgba(line.color), [float(line.width_px), 1.0]])
        rows.append(np.concatenate([a, b, np.tile(style, (n, 1))], axis=1))
    if not rows:
        return np.zeros((0, FLOATS), np.float32)
    return np.concatenate(rows).astype(np.float32)


def _rgba(color: Sequence[float]) -> np.ndarray:
    c = [float(v) for v in color]
    return np.array([*c, 1.0, 1.0, 1.0, 1.0][:4], np.float64)


class ToolOverlayRenderer:
    """Draws tool overlay primitives (see the module docstring) with one instanced draw.

    Args:
        ctx: the moderngl context the terrain renders with.
    """

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.program = ctx.program(
            vertex_shader=_shader("overlay_tool.vert"),
            fragment_shader=_shader("overlay_tool.frag"),
        )
        self._capacity = 64
        self.instances = ctx.buffer(reserve=self._capacity * FLOATS * 4, dynamic=True)
        self.vao = self._make_vao()
        self.drawn = 0

    def _make_vao(self) -> moderngl.VertexArray:
        return self.ctx.vertex_array(
            self.program,
            [(self.instances, "3f 3f 4f 1f 1f/i", "in_a", "in_b", "in_color", "in_size",
              "in_kind")],
        )  # fmt: skip

    def draw(
        self,
        view: ViewState,
        primitives: Sequence[Any],
        target: moderngl.Framebuffer,
        displace: Displace | None = None,
    ) -> int:
        """Draw ``primitives`` over what ``target`` holds; returns the instances drawn."""
        data = overlay_instances(view, primitives, displace)
        n = len(data)
        self.drawn = n
        if n == 0:
            return 0
        if n > self._capacity:
            while self._capacity < n:
                self._capacity *= 2
            self.vao.release()
            self.instances.orphan(self._capacity * FLOATS * 4)
            self.vao = self._make_vao()
        self.instances.write(data.tobytes())
        p = self.program
        p["u_rot"].write(view.rotation.T.astype("f4").tobytes())
        p["u_proj"].write(view.proj.T.astype("f4").tobytes())
        p["u_viewport"].value = (float(view.viewport[0]), float(view.viewport[1]))
        ctx = self.ctx
        target.use()
        ctx.disable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)
        # Colour: 'over'; alpha: keep the destination's (opaque). Qt composites the widget's
        # framebuffer as premultiplied, so a translucent alpha written here would show as
        # wrong colours in the window.
        ctx.blend_func = (
            moderngl.SRC_ALPHA,
            moderngl.ONE_MINUS_SRC_ALPHA,
            moderngl.ZERO,
            moderngl.ONE,
        )
        # Lines first, markers over them.
        kinds = data[:, 11]
        order = np.argsort(-kinds, kind="stable")
        if not np.array_equal(order, np.arange(n)):
            self.instances.write(data[order].tobytes())
        self.vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=n)
        ctx.disable(moderngl.BLEND)
        ctx.enable(moderngl.DEPTH_TEST)
        return n

    def release(self) -> None:
        for obj in (self.vao, self.instances, self.program):
            obj.release()
