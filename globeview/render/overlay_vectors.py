"""Polylines draped on the current LOD mesh, drawn as screen-space-wide quads.

How a line stays on the terrain (TREND §5.2: vectors must follow the LOD mesh actually drawn):
each densified vertex takes its height **from the drawn tile at the drawn index stride**
(`globeview.terrain.vectors.drape_heights`, bilinear on that stride's grid), recomputed when
the render set changes; so when the LOD coarsens the line comes down with the mesh instead of
floating above it, and when it refines the line rises with it instead of sinking. Between the
densified vertices, and where a provider triangulates differently from the bilinear grid
(stitched edges, quadtree-clod's own triangles), the line and the mesh may differ by a fraction
of the tile's geometric error; a small depth bias (a fixed fraction of the view distance in the
logarithmic depth, i.e. the same relative pull at every distance) hides that while terrain in
front of the line still occludes it. Where the mesh rises over a segment's chord (a ridge
between two vertices kilometres apart), each segment also carries that rise (`chord_sag`,
sampled on the drawn mesh when the heights are redone) and the shader pulls its depth toward
the eye by it over the cosine of the incidence, so the line does not break there.
Positions are sent as float32 hi/lo pairs of absolute ECEF
(emulated double precision), the eye likewise, so no re-upload is needed while the camera moves.

Only segments whose two ends lie in drawn tiles are uploaded (vectors paged by tile), each
from the level of detail of the line work its distance from the eye calls for (the far part
of an oblique view from coarse levels, the near part from fine ones). The
active tool's displacement (`view.displace`) is applied on the CPU to the vertices, every frame
while a displacement is active.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import moderngl
import numpy as np

from globeview.geodesy import WGS84, lonlat_to_ecef
from globeview.lod.render_set import RenderSet
from globeview.lod.view_state import INV_AXES2, ViewState
from globeview.render.gpu_objects import gpu_objects
from globeview.render.shader_source import load_shader
from globeview.terrain.vectors import Polylines, drape_heights

#: Coarser line levels are used while their segments span fewer pixels than this.
SEGMENT_PX = 6.0
#: The eye moves this fraction of its height before the levels' distance bands are redone.
BAND_STEP = 0.05
#: Depth pull toward the eye, as a fraction of the view distance.
DEPTH_BIAS_FRACTION = 0.004
#: Fractions along each segment where the terrain's rise over the chord is sampled.
SAG_FRACTIONS = (0.25, 0.5, 0.75)


def render_set_strides(render_set: RenderSet) -> np.ndarray:
    """(N,) index stride each drawn tile uses (1 for providers' custom triangulations; for a
    tile drawn with block strides its coarsest block's, the stride of most of its blocks)."""
    if len(render_set.keys) == 0:
        return np.ones(0, np.int64)
    table = np.array([v.stride for v in render_set.variants], dtype=np.int64)
    strides = table[render_set.variant_ids]
    blocks = render_set.block_strides
    if blocks is not None:
        coarsest = blocks.reshape(len(blocks), -1).max(axis=1).astype(np.int64)
        strides = np.where(coarsest >= 0, np.left_shift(1, np.maximum(coarsest, 0)), strides)
    if render_set.custom_indices:
        strides = strides.copy()
        strides[np.array(sorted(render_set.custom_indices), np.int64)] = 1
    return strides


def render_set_signature(render_set: RenderSet, exaggeration: float) -> tuple:
    """A hashable stand-in for 'the same mesh': keys, strides and exaggeration."""
    keys = np.ascontiguousarray(render_set.keys, np.int64)
    return (keys.tobytes(), render_set_strides(render_set).tobytes(), float(exaggeration))


def chord_sag(
    heights: Callable[[tuple[int, int, int]], np.ndarray],
    keys: np.ndarray,
    strides: np.ndarray,
    lines: Polylines,
    a: np.ndarray,
    b: np.ndarray,
    h_a: np.ndarray,
    h_b: np.ndarray,
) -> np.ndarray:
    """(S,) metres the drawn mesh rises above each segment's chord (0 where it does not).

    Sampled at `SAG_FRACTIONS` of each segment (lon/lat linear: segments are short) on the
    drawn mesh, against the chord's height there (linear between the draped ends ``h_a``,
    ``h_b``, metres; the chord's own sag below the ellipsoid is millimetres at kilometres).
    The line shader pulls each segment's depth toward the eye by it, so a straight line seen
    from above stays visible over a ridge between its vertices (issue #26 review)."""
    n = len(a)
    if n == 0:
        return np.zeros(0)
    t = np.asarray(SAG_FRACTIONS, np.float64)
    dlon = (lines.lon[b] - lines.lon[a] + 180.0) % 360.0 - 180.0  # across the antimeridian
    lon = (lines.lon[a, None] + dlon[:, None] * t).ravel()
    lat = (lines.lat[a, None] + (lines.lat[b] - lines.lat[a])[:, None] * t).ravel()
    h, drawn, _ = drape_heights(heights, keys, strides, lon, lat)
    chord = (h_a[:, None] * (1.0 - t) + h_b[:, None] * t).ravel()
    rise = np.where(drawn, h - chord, 0.0).reshape(n, len(t))
    return np.maximum(rise.max(axis=1), 0.0)


def split_hi_lo(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float64 (..., 3) -> float32 hi and lo parts with hi + lo == p to ~1e-9 relative."""
    hi = p.astype(np.float32)
    lo = (p - hi.astype(np.float64)).astype(np.float32)
    return hi, lo


def view_uniforms(view: ViewState) -> dict[str, object]:
    """Uniforms shared by the overlay shaders (camera, projection, eye hi/lo, depth)."""
    eye_hi, eye_lo = split_hi_lo(np.asarray(view.eye, np.float64))
    w, h = view.viewport
    return {
        "u_rot": view.rotation.T.astype("f4").tobytes(),
        "u_proj": view.proj.T.astype("f4").tobytes(),
        "u_eye_hi": tuple(float(v) for v in eye_hi),
        "u_eye_lo": tuple(float(v) for v in eye_lo),
        "u_viewport": (float(w), float(h)),
        "u_log_far": 1.0 / math.log2(1.0 + view.far),
        "u_depth_bias": -math.log2(1.0 - DEPTH_BIAS_FRACTION) / math.log2(1.0 + view.far),
        # metres per pixel at unit distance
        "u_px_m": 2.0 * math.tan(math.radians(view.fovy_deg) / 2.0) / h,
    }


def set_uniforms(program: moderngl.Program, uni: dict[str, object]) -> None:
    """Set the uniforms of ``uni`` that ``program`` has (the GLSL compiler drops unused
    ones): bytes are written, other values assigned. Looked up with ``get`` (a dict lookup):
    ``name in program`` walks the program's members one by one in Python."""
    for name, value in uni.items():
        member = program.get(name, None)
        if member is None:
            continue
        if isinstance(value, bytes):
            member.write(value)
        else:
            member.value = value


@dataclass
class LineStyle:
    """Colour (RGBA 0..1), width in screen pixels, dash length in pixels (0 = solid)."""

    color: tuple[float, float, float, float] = (1.0, 0.9, 0.2, 1.0)
    width_px: float = 2.0
    dash_px: float = 0.0


class VectorOverlay:
    """One vector layer on the GPU.

    Args:
        ctx: moderngl context; lines: densified polylines (lon/lat degrees); style: LineStyle.
    """

    FLOATS = 15  # A hi, A lo, B hi, B lo (3 each), along A, along B (m), sag (m)

    def __init__(
        self,
        ctx: moderngl.Context,
        lines: Polylines,
        style: LineStyle | None = None,
        name: str = "vectors",
        coarser: list[tuple[float, Polylines]] | None = None,
    ) -> None:
        self.ctx = ctx
        self.name = name
        self.style = style or LineStyle()
        self.visible = True
        # Levels of detail of the line work: (max segment m, lines), finest first; the draw
        # uses the coarsest whose segments stay under SEGMENT_PX pixels at the eye's altitude.
        self.levels = [(0.0, lines), *sorted(coarser or [], key=lambda t: t[0])]
        self._prep = [self._prepare(ly) for _, ly in self.levels]
        self.level = 0  # the level below the eye (the band of the nearest segments)
        n_max = max(len(p[1]) for p in self._prep)
        self.program = gpu_objects(ctx).program(
            vertex_shader=load_shader("overlay_line.vert"),
            fragment_shader=load_shader("overlay_line.frag"),
        )
        self.buffer = gpu_objects(ctx).buffer(reserve=max(n_max, 1) * self.FLOATS * 4, dynamic=True)
        self.vao = gpu_objects(ctx).vertex_array(
            self.program,
            [
                (
                    self.buffer,
                    "3f 3f 3f 3f 1f 1f 1f/i",
                    "in_a_hi",
                    "in_a_lo",
                    "in_b_hi",
                    "in_b_lo",
                    "in_along_a",
                    "in_along_b",
                    "in_sag",
                )
            ],
        )
        self._sig: tuple | None = None
        self.count = 0

    @staticmethod
    def _prepare(lines: Polylines):
        a, b = lines.segments()
        # Length along each polyline (chords on the ellipsoid), metres, for dashes.
        base = lonlat_to_ecef(lines.lon, lines.lat, 0.0)
        along = np.zeros(len(lines.lon))
        along[b] = np.linalg.norm(base[b] - base[a], axis=1)
        along = np.cumsum(along)
        along = along - np.repeat(along[lines.starts[:-1]], np.diff(lines.starts))
        mid = 0.5 * (base[a] + base[b])  # segment midpoints on the ellipsoid, for the bands
        return lines, a, b, along, mid

    @staticmethod
    def _eye_height(view: ViewState) -> float:
        """The eye's height above the ellipsoid along the radius (within metres of the
        geodetic height at these heights; the polar radius would add ~10 km at
        mid-latitudes, and thinned levels of dense lines be chosen twice too coarse)."""
        eye = np.asarray(view.eye, np.float64)
        r = float(np.linalg.norm(eye))
        sin2 = (eye[2] / r) ** 2 if r > 0 else 0.0
        radius = WGS84.a * WGS84.b / math.sqrt(WGS84.b**2 * (1.0 - sin2) + WGS84.a**2 * sin2)
        return max(r - radius, 1.0)

    def _band_key(self, view: ViewState) -> tuple:
        """What the distance bands depend on, coarsely: the eye's height in quarter octaves
        and its position in steps of `BAND_STEP` of that height, the field of view and the
        viewport's height (bands are redone when one of these changes)."""
        octave = round(math.log2(self._eye_height(view)) * 4.0)
        step = BAND_STEP * 2.0 ** (octave / 4.0)
        cell = tuple(int(v) for v in np.round(np.asarray(view.eye, np.float64) / step))
        return (octave, cell, float(view.fovy_deg), int(view.viewport[1]))

    def choose_level(self, view: ViewState) -> int:
        """Index of the coarsest level whose segments span at most SEGMENT_PX pixels on the
        ground below the eye."""
        alt = self._eye_height(view)
        m_per_px = alt * 2.0 * math.tan(math.radians(view.fovy_deg) / 2.0) / view.viewport[1]
        ok = [i for i, (sp, _) in enumerate(self.levels) if sp <= SEGMENT_PX * m_per_px]
        return max(ok)

    def _band_starts(self, view: ViewState) -> np.ndarray:
        """(L,) the distance (m) from the eye from which each level is drawn: where its
        spacing spans SEGMENT_PX pixels (level 0: from the eye)."""
        px_m = 2.0 * math.tan(math.radians(view.fovy_deg) / 2.0) / view.viewport[1]
        return np.array([sp for sp, _ in self.levels], np.float64) / (SEGMENT_PX * px_m)

    def update(self, view: ViewState, render_set: RenderSet, terrain, exaggeration: float) -> int:
        """Recompute heights on the drawn mesh and upload the visible segments if the mesh (or
        a displacement, or the distance bands) changed; returns the number of segments to
        draw. Each segment is drawn from the coarsest level whose spacing spans at most
        SEGMENT_PX pixels at its distance from the eye (bands of distance per level), so the
        far part of an oblique view draws coarse levels and the near part fine ones."""
        sig = (*render_set_signature(render_set, exaggeration), self._band_key(view))
        if sig == self._sig and view.displace is None:
            return self.count
        self._sig = sig
        self.level = self.choose_level(view)
        starts = self._band_starts(view)
        eye = np.asarray(view.eye, np.float64)
        keys, strides = render_set.keys, render_set_strides(render_set)
        rows = []
        for k, (lines, a_all, b_all, along, mid) in enumerate(self._prep):
            if not len(a_all):
                continue
            d = np.linalg.norm(mid - eye, axis=1)
            sel = d >= starts[k]
            if k + 1 < len(starts):
                sel &= d < starts[k + 1]
            if not sel.any():
                continue
            a, b = a_all[sel], b_all[sel]
            idx = np.unique(np.concatenate([a, b]))
            lon, lat = lines.lon[idx], lines.lat[idx]
            h, drawn, _ = drape_heights(terrain.heights, keys, strides, lon, lat)
            pts = lonlat_to_ecef(lon, lat, h * exaggeration)
            if view.displace is not None:
                pts = np.asarray(view.displace(pts), np.float64)
            ia, ib = np.searchsorted(idx, a), np.searchsorted(idx, b)
            keep = drawn[ia] & drawn[ib]
            ia, ib, a, b = ia[keep], ib[keep], a[keep], b[keep]
            sag = chord_sag(terrain.heights, keys, strides, lines, a, b, h[ia], h[ib])
            hi, lo = split_hi_lo(pts)
            rows.append(
                np.concatenate(
                    [
                        hi[ia],
                        lo[ia],
                        hi[ib],
                        lo[ib],
                        along[a, None],
                        along[b, None],
                        sag[:, None] * exaggeration,
                    ],
                    axis=1,
                ).astype(np.float32)
            )
        data = np.concatenate(rows) if rows else np.zeros((0, self.FLOATS), np.float32)
        if data.nbytes > self.buffer.size:
            self.buffer.orphan(data.nbytes)
        if len(data):
            self.buffer.write(data.tobytes())
        self.count = len(data)
        return self.count

    def draw(self, view: ViewState, render_set: RenderSet, terrain, exaggeration: float) -> int:
        if not self.visible:
            return 0
        n = self.update(view, render_set, terrain, exaggeration)
        if n == 0:
            return 0
        uni = view_uniforms(view)
        uni.update(
            u_color=tuple(float(c) for c in self.style.color),
            u_width=float(self.style.width_px),
            u_dash=float(self.style.dash_px),
            u_inv_axes2=INV_AXES2,
        )
        set_uniforms(self.program, uni)
        self.ctx.enable(moderngl.DEPTH_TEST | moderngl.BLEND)
        self.ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        self.ctx.depth_func = "<="
        self.vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=n)
        self.ctx.disable(moderngl.BLEND)
        self.ctx.depth_func = "<"
        return n

    def release(self) -> None:
        for obj in (self.vao, self.buffer, self.program):
            obj.release()
