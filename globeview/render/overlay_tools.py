"""Tool overlays: the active tool's markers (with labels) and polylines drawn over the terrain.

A tool's ``overlay(view)`` returns `Marker` and `Polyline` primitives (globeview.plugins.api;
duck-typed here so ``render`` does not import the plugin layer). `ToolOverlayRenderer` draws
them into the framebuffer the terrain was just drawn into:

- markers are screen-space discs of ``size_px`` diameter (filled, with a dark rim so they
  read on any terrain colour), their ``label`` text beside them (rasterised with Pillow's
  default bitmap font into an atlas texture, re-made only when the set of labels changes);
  polyline segments are quads ``width_px`` wide in screen space.
- A polyline chooses ``depth_test`` (default True): **depth-tested** lines are hidden where the
  terrain is in front of them (a London–New York chord, a straight ECEF segment, goes behind
  the globe), with the same small pull toward the eye as vector layers (a fixed fraction of
  the view distance in the logarithmic depth, overlay_vectors.DEPTH_BIAS_FRACTION) so a line
  lying on the surface is not lost in it; their segments are cut into pieces of at most
  `DEPTH_PIECE_M` so the depth, interpolated linearly on screen, follows the line. **On-top**
  lines (``depth_test=False``: interaction feedback that must stay visible where the relief
  would hide it, e.g. the collapse tool's fold lines along the ellipsoid) are drawn without
  depth test; for them, and for markers and labels (always on top), what lies beyond the
  ellipsoid's horizon is dropped on the CPU (`facing_eye`) so nothing from the far side of
  the globe shows through it. A segment is drawn when both its ends are.
- Positions are formed **relative to the eye in float64** on the CPU and only then rounded to
  float32 for the GPU: no absolute ECEF coordinate is ever rounded to float32.
- ``displace`` (the active tool's ``displacement_numpy``) is applied to every position first,
  so primitives sit where the displaced (e.g. collapsed) terrain is drawn. The displaced
  positions are kept between frames (`DisplacedMemo`) while the displacement stays the same
  (`lod.traversal.displacement_key`: the tool's key and where it moves fixed probe points),
  so a still collapse does not displace its fold lines again at every redraw.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import moderngl
import numpy as np

from globeview.lod.traversal import displacement_key
from globeview.lod.view_state import INV_AXES2, ViewState
from globeview.render.gpu_objects import gpu_objects
from globeview.render.overlay_vectors import view_uniforms
from globeview.render.shader_source import load_shader

#: Floats per instance: a (3), b (3), colour (4), size, kind, depth-tested (0/1).
FLOATS = 13
#: Longest piece (m) of a depth-tested segment: the depth is interpolated linearly on screen,
#: so a long straight segment is cut for its depth to follow it.
DEPTH_PIECE_M = 20_000.0
#: Most pieces one segment is cut into.
MAX_PIECES = 512
#: Most distinct labels in the atlas, and characters of one label.
MAX_LABELS = 1024
MAX_LABEL_CHARS = 80
#: Floats per label instance: anchor (3, relative to the eye), atlas rect (4), colour (4),
#: offset from the anchor (px).
LABEL_FLOATS = 12

Displace = Callable[[np.ndarray], np.ndarray]


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


class DisplacedMemo:
    """Displaced copies of the point arrays an overlay displaced, for one displacement: a
    frame whose displacement key (`lod.traversal.displacement_key`) is unchanged looks them
    up by their bytes instead of calling the tool again. At most `SIZE` arrays are kept."""

    SIZE = 64

    def __init__(self) -> None:
        self._key: tuple | None = None
        self._moved: dict[tuple, np.ndarray] = {}

    @property
    def key(self) -> tuple | None:
        """The displacement key of the last `wrap` (None before any)."""
        return self._key

    def wrap(self, view: ViewState, displace: Displace) -> Displace:
        """``displace`` memoised for this frame's displacement (the view's, with ``displace``)."""
        key = displacement_key(replace(view, displace=displace))
        if key != self._key:
            self._key, self._moved = key, {}

        def cached(points: np.ndarray) -> np.ndarray:
            p = np.ascontiguousarray(points, np.float64)
            k = (p.shape, p.tobytes())
            out = self._moved.get(k)
            if out is None:
                out = np.asarray(displace(p), np.float64)
                if len(self._moved) >= self.SIZE:
                    self._moved.clear()
                self._moved[k] = out
            return out

        return cached


def _view_key(view: ViewState) -> bytes:
    """What the instance tables read of a view: its eye (ECEF m), as bytes (a camera turning
    in place keeps its tables; the projection is a uniform)."""
    return np.ascontiguousarray(view.eye, np.float64).tobytes()


def _primitives_key(primitives: Sequence[Any]) -> tuple:
    """The primitives' values (what `overlay_instances` and `label_instances` read), hashable:
    a tool that returns equal primitives again gets the same tables."""
    out: list[tuple] = []
    for p in primitives:
        if hasattr(p, "position"):
            pos = np.asarray(p.position, np.float64).tobytes()
            rgba = np.asarray(p.color, np.float64).tobytes()
            out.append(("m", pos, rgba, float(p.size_px), str(getattr(p, "label", ""))))
        elif hasattr(p, "points"):
            pts = np.ascontiguousarray(p.points, np.float64).tobytes()
            rgba = np.asarray(p.color, np.float64).tobytes()
            flags = (bool(getattr(p, "closed", False)), bool(getattr(p, "depth_test", True)))
            out.append(("l", pts, rgba, float(p.width_px), flags))
        else:
            out.append(("?", id(p)))
    return tuple(out)


def _pieces(pts: np.ndarray) -> np.ndarray:
    """``pts`` (N, 3) with every segment cut into pieces of at most `DEPTH_PIECE_M`."""
    d = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    n = np.clip(np.ceil(d / DEPTH_PIECE_M), 1, MAX_PIECES).astype(np.int64)
    if (n == 1).all():
        return pts
    seg = np.repeat(np.arange(len(n)), n)
    # Piece j of segment i starts at t = j / n_i (one numpy pass, no loop over segments).
    t = (np.arange(seg.size) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
    out = pts[seg] + (pts[seg + 1] - pts[seg]) * t[:, None]
    return np.concatenate([out, pts[-1:]])


def overlay_instances(
    view: ViewState, primitives: Sequence[Any], displace: Displace | None = None
) -> np.ndarray:
    """The (K, FLOATS) float32 instance table of markers and segments for ``view``.

    Markers are objects with ``position`` (ECEF m), ``color`` RGBA and ``size_px``; polylines
    objects with ``points`` (N, 3), ``color``, ``width_px``, ``closed`` and ``depth_test``
    (default True). Markers and on-top segments beyond the horizon are left out. Positions are
    displaced, then made relative to ``view.eye`` in float64, then rounded to float32."""
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
                np.concatenate([rel[i], rel[i], _rgba(m.color), [float(m.size_px), 0.0, 0.0]])[None]
            )
    for line in lines:
        pts = np.asarray(line.points, np.float64).reshape(-1, 3)
        if len(pts) < 2:
            continue
        if getattr(line, "closed", False):
            pts = np.concatenate([pts, pts[:1]])
        tested = bool(getattr(line, "depth_test", True))
        if tested:
            pts = _pieces(pts)  # before displacing: the pieces follow the displaced line
        pts = place(pts)
        ok = np.all(np.isfinite(pts), axis=1)
        if not tested:
            ok &= facing_eye(pts, eye)
        seg = ok[:-1] & ok[1:]
        if not seg.any():
            continue
        rel = pts - eye
        a, b = rel[:-1][seg], rel[1:][seg]
        n = len(a)
        style = np.concatenate(
            [_rgba(line.color), [float(line.width_px), 1.0, 1.0 if tested else 0.0]]
        )
        rows.append(np.concatenate([a, b, np.tile(style, (n, 1))], axis=1))
    if not rows:
        return np.zeros((0, FLOATS), np.float32)
    return np.concatenate(rows).astype(np.float32)


def label_instances(
    view: ViewState, primitives: Sequence[Any], rect_of: dict[str, np.ndarray], displace=None
) -> np.ndarray:
    """(K, LABEL_FLOATS) float32: one row per visible marker with a label in ``rect_of``
    (label -> atlas rect x, y, w, h in pixels), placed to the right of the disc."""
    eye = np.asarray(view.eye, np.float64)
    marks = [p for p in primitives if hasattr(p, "position") and getattr(p, "label", "")]
    marks = [m for m in marks if str(m.label) in rect_of]
    if not marks:
        return np.zeros((0, LABEL_FLOATS), np.float32)
    pos = np.array([m.position for m in marks], np.float64).reshape(-1, 3)
    if displace is not None:
        pos = np.asarray(displace(pos), np.float64).reshape(-1, 3)
    keep = facing_eye(pos, eye) & np.all(np.isfinite(pos), axis=1)
    rows = [
        np.concatenate(
            [
                pos[i] - eye,
                rect_of[str(marks[i].label)],
                _rgba(getattr(marks[i], "label_color", (1.0, 1.0, 1.0, 1.0))),
                [0.5 * float(marks[i].size_px) + 3.0],
            ]
        )
        for i in np.nonzero(keep)[0]
    ]
    if not rows:
        return np.zeros((0, LABEL_FLOATS), np.float32)
    return np.array(rows, np.float32)


def _rgba(color: Sequence[float]) -> np.ndarray:
    c = [float(v) for v in color]
    return np.array([*c, 1.0, 1.0, 1.0, 1.0][:4], np.float64)


class ToolOverlayRenderer:
    """Draws tool overlay primitives (see the module docstring): depth-tested lines, on-top
    lines, markers, then marker labels.

    Args:
        ctx: the moderngl context the terrain renders with.
    """

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.program = gpu_objects(ctx).program(
            vertex_shader=load_shader("overlay_tool.vert"),
            fragment_shader=load_shader("overlay_tool.frag"),
        )
        self._capacity = 64
        self.instances = gpu_objects(ctx).buffer(reserve=self._capacity * FLOATS * 4, dynamic=True)
        self.vao = self._make_vao()
        self.label_program = gpu_objects(ctx).program(
            vertex_shader=load_shader("overlay_tool_label.vert"),
            fragment_shader=load_shader("overlay_tool_label.frag"),
        )
        self._label_capacity = 16
        self.label_buffer = gpu_objects(ctx).buffer(reserve=self._label_capacity * LABEL_FLOATS * 4)
        self.label_vao = self._make_label_vao()
        self.atlas: moderngl.Texture | None = None
        self._atlas_labels: tuple[str, ...] = ()
        self._rect_of: dict[str, np.ndarray] = {}
        self.drawn = 0
        self.labels_drawn = 0
        self._displaced = DisplacedMemo()
        # The last frame's (key, instance table, label table, atlas rects) (`draw`).
        self._tables: tuple[tuple, np.ndarray, np.ndarray, dict] | None = None

    def _make_vao(self) -> moderngl.VertexArray:
        return gpu_objects(self.ctx).vertex_array(
            self.program,
            [(self.instances, "3f 3f 4f 1f 1f 1f/i", "in_a", "in_b", "in_color", "in_size",
              "in_kind", "in_depth")],
        )  # fmt: skip

    def _make_label_vao(self) -> moderngl.VertexArray:
        return gpu_objects(self.ctx).vertex_array(
            self.label_program,
            [(self.label_buffer, "3f 4f 4f 1f/i", "in_rel", "in_rect", "in_color", "in_offset")],
        )  # fmt: skip

    def _ensure_atlas(self, primitives: Sequence[Any]) -> None:
        """(Re)make the label atlas when the set of marker labels changed."""
        from globeview.render.overlay_points import text_atlas

        labels = tuple(sorted({str(p.label) for p in primitives if getattr(p, "label", "")}))[
            :MAX_LABELS
        ]
        if labels == self._atlas_labels:
            return
        if self.atlas is not None:
            self.atlas.release()
            self.atlas = None
        self._atlas_labels = labels
        self._rect_of = {}
        if not labels:
            return
        img, rects = text_atlas([label[:MAX_LABEL_CHARS] for label in labels])
        self.atlas = gpu_objects(self.ctx).texture((img.shape[1], img.shape[0]), 1, img.tobytes())
        self.atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._rect_of = {label: rects[i].astype(np.float64) for i, label in enumerate(labels)}

    def _upload(self, data: np.ndarray) -> None:
        if len(data) > self._capacity:
            while self._capacity < len(data):
                self._capacity *= 2
            self.vao.release()
            self.instances.orphan(self._capacity * FLOATS * 4)
            self.vao = self._make_vao()
        self.instances.write(np.ascontiguousarray(data).tobytes())

    def draw(
        self,
        view: ViewState,
        primitives: Sequence[Any],
        target: moderngl.Framebuffer,
        displace: Displace | None = None,
    ) -> int:
        """Draw ``primitives`` over what ``target`` holds; returns the instances drawn
        (markers and segments; labels are counted in ``labels_drawn``)."""
        if displace is not None:
            displace = self._displaced.wrap(view, displace)
        self._ensure_atlas(primitives)
        # A still view of the same primitives under the same displacement has the same
        # instance tables: kept from the last frame instead of displaced and projected again.
        key = (
            _view_key(view),
            _primitives_key(primitives),
            None if displace is None else ("displaced", self._displaced.key),
            id(self._rect_of),
        )
        if self._tables is not None and self._tables[0] == key:
            data, labels = self._tables[1], self._tables[2]
        else:
            data = overlay_instances(view, primitives, displace)
            labels = label_instances(view, primitives, self._rect_of, displace)
            # The atlas' rects are held too, so their id in the key is not reused meanwhile.
            self._tables = (key, data, labels, self._rect_of)
        n = len(data)
        self.drawn = n
        self.labels_drawn = len(labels)
        if n == 0 and len(labels) == 0:
            return 0
        uni = view_uniforms(view)
        p = self.program
        p["u_rot"].write(uni["u_rot"])
        p["u_proj"].write(uni["u_proj"])
        p["u_viewport"].value = uni["u_viewport"]
        p["u_log_far"].value = uni["u_log_far"]
        p["u_depth_bias"].value = uni["u_depth_bias"]
        ctx = self.ctx
        target.use()
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
        kinds, tested = data[:, 11], data[:, 12]
        # Depth-tested lines (against the terrain's depth, not writing it), then on-top
        # lines, then markers over them. Each group is one instanced draw of the buffer.
        for group, depth in (
            ((kinds > 0.5) & (tested > 0.5), True),
            ((kinds > 0.5) & (tested < 0.5), False),
            (kinds < 0.5, False),
        ):
            rows = data[group]
            if not len(rows):
                continue
            if depth:
                ctx.enable(moderngl.DEPTH_TEST)
                ctx.depth_func = "<="
                target.depth_mask = False
            else:
                ctx.disable(moderngl.DEPTH_TEST)
            self._upload(rows)
            self.vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=len(rows))
            target.depth_mask = True
            ctx.depth_func = "<"
        if len(labels) and self.atlas is not None:
            ctx.disable(moderngl.DEPTH_TEST)
            if len(labels) > self._label_capacity:
                while self._label_capacity < len(labels):
                    self._label_capacity *= 2
                self.label_vao.release()
                self.label_buffer.orphan(self._label_capacity * LABEL_FLOATS * 4)
                self.label_vao = self._make_label_vao()
            self.label_buffer.write(labels.tobytes())
            lp = self.label_program
            lp["u_rot"].write(uni["u_rot"])
            lp["u_proj"].write(uni["u_proj"])
            lp["u_viewport"].value = uni["u_viewport"]
            lp["u_atlas_size"].value = (float(self.atlas.width), float(self.atlas.height))
            if "u_atlas" in lp:
                lp["u_atlas"].value = 0
            self.atlas.use(0)
            self.label_vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=len(labels))
        ctx.disable(moderngl.BLEND)
        ctx.enable(moderngl.DEPTH_TEST)
        return n

    def release(self) -> None:
        for obj in (
            self.vao,
            self.instances,
            self.program,
            self.label_vao,
            self.label_buffer,
            self.label_program,
            self.atlas,
        ):
            if obj is not None:
                obj.release()
