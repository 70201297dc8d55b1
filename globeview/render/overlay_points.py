"""Point objects on the terrain: placemarks (camera-facing billboards), boxes and cones (3-D,
scale in metres, heading in degrees clockwise from north), and text labels.

Objects are **paged by tile** (TREND §5.1.2): when the render set changes, only objects lying
in drawn tiles are made resident (their instance data uploaded); each gets its height from the
drawn mesh at the drawn stride (the same drape as the vectors, overlay_vectors.py), so objects
sit on the surface the user sees. One instanced draw per object type (TREND §5.1.1), plus one
for the labels: glyph strings rendered once with Pillow's default font into a text atlas.

Boxes are drawn in two ways, chosen per box and per frame on the CPU (`sprite_classes`,
vectorised): a box whose image is small and lies inside the viewport is one point sprite,
ray-cast in the fragment shader (overlay_box_sprite.*), the others (near, large, at the
viewport's edge) are instanced meshes; boxes wholly outside the view are not drawn.
Placemarks likewise (`placemark_classes`): a point sprite each (overlay_placemark_sprite.*)
inside the viewport, a billboard quad at its edges. On
llvmpipe an instanced draw costs about 3 us per instance whatever its vertex count, and vertex
work runs on one core while fragments run on all. In the scene of issue #17 (10 000 boxes
over Europe from 4 000 km, 320x240) the boxes add about 40 ms as meshes and 4.5 ms as sprites
to a 3.9 ms frame (benchmarks/bench_overlays.py). What is left: llvmpipe's point setup with
the sprite's flat inputs (~2.5 ms for 10 000, ~1.3 ms for plain 1-pixel points) and the
ray-cast fragments (~1 ms).
"""

from __future__ import annotations

import math
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
#: Boxes whose sprite would be wider than this (pixels) are drawn as meshes (GL's point size
#: limit on Mesa is 255; a larger sprite also wastes fragments outside the box).
SPRITE_MAX_PX = 64.0
#: Bounding-sphere radius of the unit box (x, y in -0.5..0.5, z 0..1) about its centre.
BOX_RADIUS = math.sqrt(0.75)


def box_axes(ground: np.ndarray, heading_rad: np.ndarray, size_m: np.ndarray) -> np.ndarray:
    """(N, 3, 3) ECEF axes (m) of boxes standing at ECEF ``ground`` points (N, 3): rows x
    (east turned clockwise by the heading), y (north, turned likewise) and z (the geodetic
    up), each ``size_m`` long; the float64 twin of overlay_object.vert's frame."""
    up = ground * np.asarray(INV_AXES2)
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    east = np.cross([0.0, 0.0, 1.0], up) + np.array([1e-9, 0.0, 0.0])
    east /= np.linalg.norm(east, axis=1, keepdims=True)
    north = np.cross(up, east)
    ch, sh = np.cos(heading_rad)[:, None], np.sin(heading_rad)[:, None]
    axes = np.stack([ch * east - sh * north, sh * east + ch * north, up], axis=1)
    return axes * np.asarray(size_m, np.float64)[:, None, None]


def ndc_to_ecef(view: ViewState) -> np.ndarray:
    """(3, 3) matrix taking (x, y, 1) in normalised device coordinates to the ECEF direction
    of that pixel's ray, scaled to view depth 1 (camera z = -1)."""
    p = np.asarray(view.proj, np.float64)
    to_cam = np.array(
        [
            [1.0 / p[0, 0], 0.0, p[0, 2] / p[0, 0]],
            [0.0, 1.0 / p[1, 1], p[1, 2] / p[1, 1]],
            [0.0, 0.0, -1.0],
        ]
    )
    return np.asarray(view.rotation, np.float64).T @ to_cam


def placemark_classes(
    view: ViewState, points_rel: np.ndarray, size_px: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Which placemarks (ground points relative to the eye, ECEF metres (N, 3); squares of
    ``size_px`` pixels standing on them) to draw as point sprites and which as billboard
    quads: (sprite, quad) boolean (N,). Sprites: in front of the eye, at most
    ``SPRITE_MAX_PX`` wide, the square wholly inside the viewport (GL clips a point by its
    centre); quads: the rest of those whose square may reach into the view."""
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        cam = points_rel @ np.asarray(view.rotation, np.float64).T
        w = -cam[:, 2]
        ws = np.where(w > 0.0, w, 1.0)
        p = np.asarray(view.proj, np.float64)
        x = (p[0, 0] * cam[:, 0] + p[0, 2] * cam[:, 2]) / ws
        y = (p[1, 1] * cam[:, 1] + p[1, 2] * cam[:, 2]) / ws
        w_px, h_px = view.viewport
        # The square in NDC: x +- s/W, y from the point up by 2 s/H (one pixel of margin).
        hx = (size_px + 2.0) / w_px
        sy, my = 2.0 * size_px / h_px, 2.0 / h_px
        ok = (w > 0.0) & (size_px > 0.0)
        seen = ok & (np.abs(x) <= 1.0 + hx) & (y >= -1.0 - sy - my) & (y <= 1.0 + my)
        inside = (np.abs(x) <= 1.0 - hx) & (y >= -1.0 + my) & (y + sy <= 1.0 - my)
        sprite = seen & inside & (size_px <= SPRITE_MAX_PX)
    return sprite, seen & ~sprite


def sprite_classes(
    view: ViewState, centres_rel: np.ndarray, radius_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Which objects (bounding spheres: centres relative to the eye, ECEF metres (N, 3), radii
    (N,) metres) to draw as point sprites and which as meshes: (sprite, mesh) boolean (N,).

    Sprites: in front of the eye, at most ``SPRITE_MAX_PX`` wide, and wholly inside the
    viewport (GL clips a point by its centre, so a sprite at the edge would vanish at once).
    Meshes: the rest of those that may be visible; spheres wholly outside the view volume's
    sides or behind the eye are in neither. The half-width is the vertex shader's:
    r d / (w^2 px_m) pixels for a sphere at distance d and view depth w."""
    # Non-finite rows (NaN or infinite positions or sizes) fail every comparison below.
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        cam = centres_rel @ np.asarray(view.rotation, np.float64).T
        w = -cam[:, 2]
        d = np.sqrt(np.einsum("ij,ij->i", cam, cam))
        w_h, h_px = view.viewport
        px_m = 2.0 * math.tan(math.radians(view.fovy_deg) / 2.0) / h_px
        # The eye close to (or inside) the sphere: a mesh (wholly behind the eye: not drawn).
        near = (w > -radius_m) & (w <= 2.0 * radius_m)
        ws = np.where(near, 1.0, w)
        half = 1.05 * radius_m * d / (ws * ws * px_m) + 1.0
        p = np.asarray(view.proj, np.float64)
        ndc_x = (p[0, 0] * cam[:, 0] + p[0, 2] * cam[:, 2]) / ws
        ndc_y = (p[1, 1] * cam[:, 1] + p[1, 2] * cam[:, 2]) / ws
        hx, hy = 2.0 * half / w_h, 2.0 * half / h_px
        ax, ay = np.abs(ndc_x), np.abs(ndc_y)
        seen = near | ((w > 0.0) & (ax <= 1.0 + hx) & (ay <= 1.0 + hy))
        # A box of no size (a scale of 0) draws nothing; non-finite input fails every test above.
        seen &= radius_m > 0.0
        sprite = (
            seen
            & ~near
            & (w > 0.0)
            & (2.0 * half <= SPRITE_MAX_PX)
            & (ax <= 1.0 - hx)
            & (ay <= 1.0 - hy)
        )
    return sprite, seen & ~sprite


def _view_key(view: ViewState) -> bytes:
    """What `sprite_classes` and `placemark_classes` read of a view (eye, rotation,
    projection, viewport, field of view), as bytes: equal keys choose the same split."""
    w, h = view.viewport
    extra = np.array([w, h, view.fovy_deg], np.float64)
    return b"".join(
        np.ascontiguousarray(a, np.float64).tobytes()
        for a in (view.eye, view.rotation, view.proj, extra)
    )


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
        factor (times style.scale_m for 3-D kinds, style.size_px for placemarks); colors:
        optional (N, 4) RGBA 0..1 per object (default: style.color for all).
    """

    FLOATS = 13  # hi (3), lo (3), scale, heading (rad), label index, RGBA (4)
    #: The instance rows' layout, and the attributes the programs read from it.
    ROW_FORMAT = "3f 3f 1f 1f 1f 4f"
    ROW_ATTRS = ("in_hi", "in_lo", "in_scale", "in_heading", "in_label", "in_color")
    #: A box sprite's row: hi, lo, the three axes (ECEF m), RGBA.
    SPRITE_FLOATS = 19

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
        colors: np.ndarray | None = None,
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
        # One RGBA per object, read per instance (the shaders' in_color): a colour each
        # costs no more than one for all, and style edits rebuild the overlay anyway.
        self.colors = (
            np.tile(np.asarray(self.style.color, np.float64), (n, 1))
            if colors is None
            else np.asarray(colors, np.float64).reshape(n, 4)
        )
        self.names = list(names) if names is not None else []
        fmt = self.ROW_FORMAT + "/i"
        attrs = self.ROW_ATTRS
        self.instances = gpu_objects(ctx).buffer(reserve=max(n, 1) * self.FLOATS * 4, dynamic=True)
        if self.style.kind == "placemark":
            self.program = gpu_objects(ctx).program(
                vertex_shader=load_shader("overlay_billboard.vert"),
                fragment_shader=load_shader("overlay_billboard.frag"),
            )
            self.mesh = None
            # Placemarks inside the viewport are point sprites (one vertex each, the instance
            # rows read as plain per-vertex data); those at its edges are billboard quads.
            nbytes = max(n, 1) * self.FLOATS * 4
            self.meshes = gpu_objects(ctx).buffer(reserve=nbytes, dynamic=True)
            self.sprites = gpu_objects(ctx).buffer(reserve=nbytes, dynamic=True)
            self.vao = gpu_objects(ctx).vertex_array(
                self.program, [(self.meshes, fmt, *attrs)], skip_errors=True
            )
            self.sprite_prog = gpu_objects(ctx).program(
                vertex_shader=load_shader("overlay_placemark_sprite.vert"),
                fragment_shader=load_shader("overlay_placemark_sprite.frag"),
            )
            self.sprite_vao = gpu_objects(ctx).vertex_array(
                self.sprite_prog, [(self.sprites, fmt.removesuffix("/i"), *attrs)], skip_errors=True
            )
        else:
            self.program = gpu_objects(ctx).program(
                vertex_shader=load_shader("overlay_object.vert"),
                fragment_shader=load_shader("overlay_object.frag"),
            )
            mesh = _box_mesh() if self.style.kind == "box" else _cone_mesh()
            if self.style.kind == "box":
                # Small boxes as ray-cast point sprites (one vertex each): the instance rows
                # read as plain per-vertex data. Which boxes go where is chosen per frame.
                self.sprite_prog = gpu_objects(ctx).program(
                    vertex_shader=load_shader("overlay_box_sprite.vert"),
                    fragment_shader=load_shader("overlay_box_sprite.frag"),
                )
                nbytes = max(n, 1) * self.FLOATS * 4
                self.meshes = gpu_objects(ctx).buffer(reserve=nbytes, dynamic=True)
                self.sprites = gpu_objects(ctx).buffer(
                    reserve=max(n, 1) * self.SPRITE_FLOATS * 4, dynamic=True
                )
                self.sprite_vao = gpu_objects(ctx).vertex_array(
                    self.sprite_prog,
                    [
                        (
                            self.sprites,
                            "3f 3f 3f 3f 3f 4f",
                            *("in_hi", "in_lo", "in_ax", "in_ay", "in_az", "in_color"),
                        )
                    ],
                )
            self.mesh = gpu_objects(ctx).buffer(mesh.tobytes())
            self.n_mesh = len(mesh)
            if self.style.kind == "cone":
                # Cones draw only those in the view (the CPU culls them each frame, as boxes).
                nbytes = max(n, 1) * self.FLOATS * 4
                self.meshes = gpu_objects(ctx).buffer(reserve=nbytes, dynamic=True)
                self.sprite_prog = self.sprite_vao = self.sprites = None
            # The mesh instances come from their own buffer (those in view, not sprites).
            inst = self.meshes
            self.vao = gpu_objects(ctx).vertex_array(
                self.program,
                [(self.mesh, "3f 3f", "in_vpos", "in_vnrm"), (inst, fmt, *attrs)],
                skip_errors=True,
            )
        self.label_prog = self.label_vao = self.atlas = self.rects = None
        # Boxes: per resident box its instance row, its sprite row (hi, lo, the three axes in
        # ECEF metres), bounding centre (ECEF, float64) and radius (m), and the last frame's
        # split (sprite/mesh masks' bytes).
        self._rows = np.zeros((0, self.FLOATS), np.float32)
        self._sprite_rows = np.zeros((0, self.SPRITE_FLOATS), np.float32)
        self._centres = np.zeros((0, 3))
        self._radii = np.zeros(0)
        self._split: tuple[bytes, bytes] | None = None
        self._split_view: bytes | None = None  # the view the split was chosen for
        self.n_sprites = self.n_meshes = 0
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
                self.colors[idx],
            ],
            axis=1,
        ).astype(np.float32)
        if len(idx):
            self.instances.write(data.tobytes())
        if self.style.kind == "cone":
            size = (self.scale[idx] * base).astype(np.float64)
            up = pts * np.asarray(INV_AXES2)
            up /= np.linalg.norm(up, axis=1, keepdims=True)
            # The unit cone's bounding sphere about (0, 0, 0.5) has radius sqrt(0.5) < BOX_RADIUS.
            self._rows, self._centres = data, pts + up * (0.5 * size)[:, None]
            self._radii = BOX_RADIUS * size
        elif self.style.kind == "box":
            size = (self.scale[idx] * base).astype(np.float64)
            axes = box_axes(pts, self.heading[idx], size)
            self._rows, self._centres = data, pts + 0.5 * axes[:, 2]
            self._sprite_rows = np.concatenate(
                [hi, lo, axes.reshape(-1, 9), self.colors[idx]], axis=1
            ).astype(np.float32)
            self._radii = BOX_RADIUS * size
        elif self.style.kind == "placemark":
            self._rows = self._sprite_rows = data
            self._centres, self._radii = pts, data[:, 6].astype(np.float64)  # sizes in px
        self._split = None
        self.resident = len(idx)
        return self.resident

    def _split_sprites(self, view: ViewState) -> None:
        """Choose sprites and meshes (boxes) or quads (placemarks) for this frame
        (`sprite_classes`, `placemark_classes`) and upload each set's rows when the choice
        changed."""
        # A still camera over the same resident objects keeps last frame's choice: the view
        # is all the choice depends on (`update` resets it when the objects change).
        view_key = _view_key(view)
        if self._split is not None and view_key == self._split_view:
            return
        self._split_view = view_key
        rel = self._centres - np.asarray(view.eye, np.float64)
        classes = placemark_classes if self.style.kind == "placemark" else sprite_classes
        sprite, mesh = classes(view, rel, self._radii)
        if self.sprites is None:  # cones: every one in view is a mesh
            sprite, mesh = np.zeros_like(sprite), sprite | mesh
        key = (sprite.tobytes(), mesh.tobytes())
        if key == self._split:
            return
        self._split = key
        for buf, rows in ((self.sprites, self._sprite_rows), (self.meshes, self._rows)):
            if buf is None:
                continue
            rows = rows[sprite if buf is self.sprites else mesh]
            if len(rows):
                buf.write(rows.tobytes())
        self.n_sprites, self.n_meshes = int(sprite.sum()), int(mesh.sum())

    def draw(self, view: ViewState, render_set: RenderSet, terrain, exaggeration: float) -> int:
        if not self.visible:
            return 0
        n = self.update(view, render_set, terrain, exaggeration)
        if n == 0:
            return 0
        uni = view_uniforms(view)
        uni.update(
            u_inv_axes2=INV_AXES2,  # the objects' colours come per instance (in_color)
            u_light=tuple(float(v) for v in view.rotation[2]),
        )
        ctx = self.ctx
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<="
        set_uniforms(self.program, uni)
        self._split_sprites(view)
        if self.n_meshes and self.mesh is None:
            self.vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=self.n_meshes)
        elif self.n_meshes:
            self.vao.render(moderngl.TRIANGLES, vertices=self.n_mesh, instances=self.n_meshes)
        if self.n_sprites:
            set_uniforms(self.sprite_prog, uni)
            if self.mesh is not None:  # boxes: the pixel rays
                m = ndc_to_ecef(view).T.astype("f4").tobytes()
                self.sprite_prog["u_ndc_to_ecef"].write(m)
            ctx.enable(moderngl.PROGRAM_POINT_SIZE)
            self.sprite_vao.render(moderngl.POINTS, vertices=self.n_sprites)
            ctx.disable(moderngl.PROGRAM_POINT_SIZE)
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
            self.sprite_vao,
            self.sprite_prog,
            self.sprites,
            self.meshes,
            self.program,
            self.mesh,
            self.label_vao,
            self.label_prog,
            self.atlas,
            getattr(self, "rect_tex", None),
        ):
            if obj is not None:
                obj.release()
