"""Point objects on the terrain: placemarks (camera-facing billboards), boxes and cones (3-D,
scale in metres, heading in degrees clockwise from north), and text labels.

Objects are **paged by tile** (TREND §5.1.2): when the render set changes, only objects lying
in drawn tiles are made resident (their instance data uploaded); each gets its height from the
drawn mesh at the drawn stride (the same drape as the vectors, overlay_vectors.py), so objects
sit on the surface the user sees. One instanced draw per object type (TREND §5.1.1), plus one
for the labels: glyph strings rendered once with Pillow's default font into a text atlas.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from globeview.geodesy import lonlat_to_ecef
from globeview.lod.render_set import RenderSet
from globeview.lod.view_state import INV_AXES2, ViewState
from globeview.render.gpu_objects import gpu_objects
from globeview.render.overlay_vectors import (
    render_set_signature,
    render_set_strides,
    set_uniforms,
    split_hi_lo,
    view_uniforms,
)
from globeview.render.shader_source import load_shader
from globeview.terrain.vectors import drape_heights

KINDS = ("placemark", "box", "cone")


def _box_mesh() -> np.ndarray:
    """(36, 6) float32 triangles of a unit box (x, y in -0.5..0.5, z 0..1): position, normal."""
    faces = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            v = np.cross(n, u)
            c = n * 0.5
            quad = [
                c - 0.5 * u - 0.5 * v,
                c + 0.5 * u - 0.5 * v,
                c + 0.5 * u + 0.5 * v,
                c - 0.5 * u + 0.5 * v,
            ]
            for i in (0, 1, 2, 0, 2, 3):
                faces.append(np.concatenate([quad[i], n]))
    m = np.array(faces)
    m[:, 2] += 0.5
    return m.astype(np.float32)


def _cone_mesh(segments: int = 16) -> np.ndarray:
    """(6 * segments, 6) float32 triangles of a unit cone (base radius 0.5 at z 0, apex z 1)."""
    a = np.linspace(0, 2 * np.pi, segments + 1)
    p0 = np.stack([0.5 * np.cos(a[:-1]), 0.5 * np.sin(a[:-1]), np.zeros(segments)], 1)
    p1 = np.stack([0.5 * np.cos(a[1:]), 0.5 * np.sin(a[1:]), np.zeros(segments)], 1)
    apex = np.tile([0.0, 0.0, 1.0], (segments, 1))
    mid = 0.5 * (a[:-1] + a[1:])
    side_n = np.stack([np.cos(mid), np.sin(mid), np.full(segments, 0.5)], 1)
    side_n /= np.linalg.norm(side_n, axis=1, keepdims=True)
    down = np.tile([0.0, 0.0, -1.0], (segments, 1))
    centre = np.zeros((segments, 3))
    tris = np.stack(
        [
            np.concatenate([p0, side_n], 1),
            np.concatenate([p1, side_n], 1),
            np.concatenate([apex, side_n], 1),
            np.concatenate([p1, down], 1),
            np.concatenate([p0, down], 1),
            np.concatenate([centre, down], 1),
        ],
        1,
    )
    return tris.reshape(-1, 6).astype(np.float32)


def text_atlas(labels: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Render each distinct label once with Pillow's default bitmap font.

    Returns the atlas (H, W) uint8 coverage and per-label rects (N, 4) float32 in pixels
    (x0, y0, width, height), row 0 at the top."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default()
    sizes = []
    for text in labels:
        _x0, _y0, x1, y1 = font.getbbox(text or " ")
        sizes.append((max(x1, 1) + 2, max(y1, 1) + 2))
    width = 1024
    rects = np.zeros((len(labels), 4), np.float32)
    x = y = row_h = 0
    for i, (w, h) in enumerate(sizes):
        w = min(w, width)
        if x + w > width:
            x, y, row_h = 0, y + row_h, 0
        rects[i] = (x, y, w, h)
        x += w
        row_h = max(row_h, h)
    height = max(int(y + row_h), 1)
    img = Image.new("L", (width, height), 0)
    draw = ImageDraw.Draw(img)
    for text, (rx, ry, _w, _h) in zip(labels, rects, strict=True):
        draw.text((int(rx) + 1, int(ry) + 1), text, fill=255, font=font)
    return np.asarray(img, np.uint8), rects


@dataclass
class PointStyle:
    """Placemark size (pixels) or 3-D object scale (metres), colour RGBA 0..1, labels on/off."""

    kind: str = "placemark"
    size_px: float = 10.0
    scale_m: float = 1000.0
    color: tuple[float, float, float, float] = (1.0, 0.25, 0.15, 1.0)
    labels: bool = True
    label_color: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)


class PointOverlay:
    """Point objects of one kind, instanced.

    Args:
        ctx: moderngl context; lon, lat: (N,) degrees; names: N labels (or None);
        style: PointStyle; heading_deg, scale: optional (N,) per-object heading and scale
        factor (times style.scale_m for 3-D kinds, style.size_px for placemarks).
    """

    FLOATS = 9  # hi (3), lo (3), scale, heading (rad), label index

    def __init__(
        self,
        ctx: moderngl.Context,
        lon: np.ndarray,
        lat: np.ndarray,
        names: list[str] | None = None,
        style: PointStyle | None = None,
        heading_deg: np.ndarray | None = None,
        scale: np.ndarray | None = None,
        name: str = "points",
    ) -> None:
        self.ctx = ctx
        self.name = name
        self.style = style or PointStyle()
        if self.style.kind not in KINDS:
            raise ValueError(f"point kind must be one of {KINDS}, got {self.style.kind!r}")
        self.visible = True
        self.lon = np.asarray(lon, np.float64)
        self.lat = np.asarray(lat, np.float64)
        n = len(self.lon)
        self.heading = np.radians(np.zeros(n) if heading_deg is None else heading_deg)
        self.scale = np.ones(n) if scale is None else np.asarray(scale, np.float64)
        self.names = list(names) if names is not None else []
        fmt = "3f 3f 1f 1f 1f/i"
        attrs = ("in_hi", "in_lo", "in_scale", "in_heading", "in_label")
        self.instances = gpu_objects(ctx).buffer(reserve=max(n, 1) * self.FLOATS * 4, dynamic=True)
        if self.style.kind == "placemark":
            self.program = gpu_objects(ctx).program(
                vertex_shader=load_shader("overlay_billboard.vert"),
                fragment_shader=load_shader("overlay_billboard.frag"),
            )
            self.mesh = None
            self.vao = gpu_objects(ctx).vertex_array(
                self.program, [(self.instances, fmt, *attrs)], skip_errors=True
            )
        else:
            self.program = gpu_objects(ctx).program(
                vertex_shader=load_shader("overlay_object.vert"),
                fragment_shader=load_shader("overlay_object.frag"),
            )
            mesh = _box_mesh() if self.style.kind == "box" else _cone_mesh()
            self.mesh = gpu_objects(ctx).buffer(mesh.tobytes())
            self.n_mesh = len(mesh)
            self.vao = gpu_objects(ctx).vertex_array(
                self.program,
                [(self.mesh, "3f 3f", "in_vpos", "in_vnrm"), (self.instances, fmt, *attrs)],
                skip_errors=True,
            )
        self.label_prog = self.label_vao = self.atlas = self.rects = None
        if self.style.labels and self.names:
            uniq, inv = np.unique(np.array(self.names, dtype=object), return_inverse=True)
            self.label_of = inv.astype(np.float64)
            atlas, self.rects = text_atlas([str(u) for u in uniq])
            self.atlas = gpu_objects(ctx).texture(
                (atlas.shape[1], atlas.shape[0]), 1, atlas.tobytes()
            )
            self.atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
            rect_tex = np.ascontiguousarray(self.rects, np.float32)
            self.rect_tex = gpu_objects(ctx).texture(
                (len(rect_tex), 1), 4, rect_tex.tobytes(), dtype="f4"
            )
            self.rect_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self.label_prog = gpu_objects(ctx).program(
                vertex_shader=load_shader("overlay_label.vert"),
                fragment_shader=load_shader("overlay_label.frag"),
            )
            self.label_vao = gpu_objects(ctx).vertex_array(
                self.label_prog, [(self.instances, fmt, *attrs)], skip_errors=True
            )
        else:
            self.label_of = np.zeros(n)
        self._sig: tuple | None = None
        self.resident = 0

    def update(self, view: ViewState, render_set: RenderSet, terrain, exaggeration: float) -> int:
        """Page in the objects of the drawn tiles (when the mesh changed); returns how many."""
        sig = render_set_signature(render_set, exaggeration)
        if sig == self._sig and view.displace is None:
            return self.resident
        self._sig = sig
        h, drawn, _ = drape_heights(
            terrain.heights, render_set.keys, render_set_strides(render_set), self.lon, self.lat
        )
        idx = np.nonzero(drawn)[0]
        pts = lonlat_to_ecef(self.lon[idx], self.lat[idx], h[idx] * exaggeration)
        pts = np.asarray(pts, np.float64).reshape(-1, 3)
        if view.displace is not None and len(idx):
            pts = np.asarray(view.displace(pts), np.float64)
        hi, lo = split_hi_lo(pts)
        base = self.style.size_px if self.style.kind == "placemark" else self.style.scale_m
        data = np.concatenate(
            [
                hi,
                lo,
                (self.scale[idx] * base)[:, None],
                self.heading[idx, None],
                self.label_of[idx, None],
            ],
            axis=1,
        ).astype(np.float32)
        if len(idx):
            self.instances.write(data.tobytes())
        self.resident = len(idx)
        return self.resident

    def draw(self, view: ViewState, render_set: RenderSet, terrain, exaggeration: float) -> int:
        if not self.visible:
            return 0
        n = self.update(view, render_set, terrain, exaggeration)
        if n == 0:
            return 0
        uni = view_uniforms(view)
        uni.update(
            u_color=tuple(float(c) for c in self.style.color),
            u_inv_axes2=INV_AXES2,
            u_light=tuple(float(v) for v in view.rotation[2]),
        )
        ctx = self.ctx
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<="
        set_uniforms(self.program, uni)
        if self.mesh is None:
            self.vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=n)
        else:
            self.vao.render(moderngl.TRIANGLES, vertices=self.n_mesh, instances=n)
        if self.label_vao is not None:
            uni.update(
                u_color=tuple(float(c) for c in self.style.label_color),
                u_atlas=0,
                u_rects=1,
                u_atlas_size=(float(self.atlas.width), float(self.atlas.height)),
                u_offset_px=float(self.style.size_px * 0.5 + 3.0),
            )
            set_uniforms(self.label_prog, uni)
            self.atlas.use(0)
            self.rect_tex.use(1)
            # Labels stand beside their point over terrain that may be nearer the eye: no
            # depth test (their point's visibility is decided by tile paging and the marker).
            ctx.disable(moderngl.DEPTH_TEST)
            ctx.enable(moderngl.BLEND)
            ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
            self.label_vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=n)
            ctx.disable(moderngl.BLEND)
            ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        return n

    def release(self) -> None:
        for obj in (
            self.vao,
            self.instances,
            self.program,
            self.mesh,
            self.label_vao,
            self.label_prog,
            self.atlas,
            getattr(self, "rect_tex", None),
        ):
            if obj is not None:
                obj.release()
