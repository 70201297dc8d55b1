"""The imagery drape: per-tile RGBA textures in a texture array parallel to the tile pool.

Layer ``slot`` of ``ImageryDrape.tex`` holds the composed imagery (terrain/imagery.py
`ImageryStack`, premultiplied alpha, one-texel border) of the terrain tile in pool slot
``slot``, so the terrain shader samples it with the same ``v_layer`` it uses for heights and
normals. A slot is (re)written when the pool loaded another tile into it (pool.generation) or
the imagery changed (stack.version); mipmaps are rebuilt only on frames that wrote a slot and
sampling is trilinear with anisotropic filtering (TREND §4.1.2).

Also `OverlaySet`: what the renderer calls around its terrain pass (the drape before, the
vector and point overlays after).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import moderngl
import numpy as np

from globeview.render.gpu_objects import gpu_objects
from globeview.terrain.imagery import ImageryStack


class ImageryDrape:
    """GPU side of an `ImageryStack`.

    Args:
        ctx: moderngl context; capacity: the tile pool's slot count; stack: the imagery.
    """

    def __init__(self, ctx: moderngl.Context, capacity: int, stack: ImageryStack) -> None:
        self.ctx = ctx
        self.stack = stack
        self.capacity = capacity
        t = stack.tex_size
        self.tex = gpu_objects(ctx).texture_array((t, t, capacity), 4, dtype="f1")
        self.tex.repeat_x = False
        self.tex.repeat_y = False
        self.tex.build_mipmaps()
        self.tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        # Anisotropic filtering (TREND §4.1.2); a software rasteriser pays for it per fragment
        # (llvmpipe: +40 ms at 800x600), so it is off there.
        renderer = str(ctx.info.get("GL_RENDERER", "")).lower()
        self.tex.anisotropy = 1.0 if "llvmpipe" in renderer or "softpipe" in renderer else 8.0
        # Which (pool generation, imagery version) each slot holds.
        self._gen = np.full(capacity, -1, np.int64)
        self._ver = np.full(capacity, -1, np.int64)
        self.uploaded_last = 0

    def update(self, pool, slots: np.ndarray, keys: np.ndarray) -> int:
        """Write the imagery of drawn tiles whose slot content is stale; returns how many."""
        slots = np.asarray(slots, np.int64)
        if len(slots) == 0:
            return 0
        stale = (self._gen[slots] != pool.generation[slots]) | (
            self._ver[slots] != self.stack.version
        )
        todo = np.nonzero(stale)[0]
        t = self.stack.tex_size
        for i in todo:  # per newly loaded tile, not per frame in steady state
            rgba = self.stack.tile(tuple(int(v) for v in keys[i]))
            self.tex.write(rgba.tobytes(), viewport=(0, 0, int(slots[i]), t, t, 1))
        if len(todo):
            self._gen[slots[todo]] = pool.generation[slots[todo]]
            self._ver[slots[todo]] = self.stack.version
            self.tex.build_mipmaps()
        self.uploaded_last = len(todo)
        return len(todo)

    def release(self) -> None:
        self.tex.release()


class OverlaySet:
    """Overlays of one renderer: the imagery drape and the vector / point layers.

    The renderer calls `prepare` before its terrain pass (uploads stale imagery slots, binds
    the array to ``unit`` and sets ``u_imagery*`` uniforms) and `draw` after it (vectors,
    then point objects, depth-tested against the terrain).
    """

    IMAGERY_UNIT = 3

    def __init__(self, ctx: moderngl.Context, capacity: int) -> None:
        self.ctx = ctx
        self.capacity = capacity
        self.imagery = ImageryStack()
        self._drape: ImageryDrape | None = None
        self.vectors: list = []  # VectorOverlay objects (overlay_vectors.py)
        self.points: list = []  # PointOverlay objects (overlay_points.py)
        self.opacity = 1.0
        # GPU twins of the model's overlay layers (`sync`): id(layer) -> (layer, its
        # style_version when built, twin). Twins live in ``vectors``/``points`` in the
        # model's order, after any overlay added to those lists directly.
        self._twins: dict[int, tuple[Any, int, Any]] = {}
        self._imagery_sig: tuple = ()

    def sync(self, layers: Sequence[Any]) -> list[tuple[Any, str]]:
        """Bring the GPU side in line with the model's overlay layers (bottom first), at
        frame time with the context current: the imagery stack takes the drapes' layers,
        and vector and point layers get GPU twins, made when first drawn, rebuilt when
        their ``style_version`` changes, released when the layer is gone. Layers are
        duck-typed models (`globeview.model.overlay_layers`): ``gpu_kind`` 'imagery',
        'vectors' or 'points', their data, style and ``visible``; ``parts`` for a group.
        Returns (layer part, one-line reason) for each part the GL refused (its twin is
        not kept); the caller drops those layers from the model."""
        parts = list(_flatten(layers))
        failures: list[tuple[Any, str]] = []
        drapes = []
        for p in parts:
            if getattr(p, "gpu_kind", None) != "imagery":
                continue
            size = getattr(p.layer.source, "tex_size", self.imagery.tex_size)
            if size != self.imagery.tex_size:
                failures.append((p, f"texture size {size} != {self.imagery.tex_size}"))
            else:
                drapes.append(p.layer)
        sig = tuple((id(ly), bool(ly.visible), float(ly.opacity)) for ly in drapes)
        if sig != self._imagery_sig:
            self.imagery.layers = drapes
            self.imagery.changed()
            self._imagery_sig = sig
        wanted = [p for p in parts if getattr(p, "gpu_kind", None) in ("vectors", "points")]
        owned = {id(entry[2]) for entry in self._twins.values()}
        keep: set[int] = set()
        for p in wanted:
            entry = self._twins.get(id(p))
            version = int(getattr(p, "style_version", 0))
            if entry is None or entry[0] is not p or entry[1] != version:
                if entry is not None:
                    entry[2].release()
                    del self._twins[id(p)]
                try:
                    twin = _make_twin(self.ctx, p)
                except (moderngl.Error, ValueError) as exc:  # data the GL still refuses
                    first = (str(exc).splitlines() or [type(exc).__name__])[0]
                    failures.append((p, f"{first:.160}"))
                    continue
                self._twins[id(p)] = entry = (p, version, twin)
            entry[2].visible = bool(p.visible)
            keep.add(id(p))
        for key in [k for k in self._twins if k not in keep]:
            self._twins.pop(key)[2].release()
        drawn = [(p, self._twins[id(p)][2]) for p in wanted if id(p) in self._twins]
        # Overlays put in the lists directly (not twins) stay, below the model's.
        self.vectors = [o for o in self.vectors if id(o) not in owned]
        self.vectors += [t for p, t in drawn if p.gpu_kind == "vectors"]
        self.points = [o for o in self.points if id(o) not in owned]
        self.points += [t for p, t in drawn if p.gpu_kind == "points"]
        return failures

    def set_imagery(self, stack: ImageryStack) -> None:
        if self._drape is not None:
            self._drape.release()
            self._drape = None
        self.imagery = stack

    def prepare(self, program: moderngl.Program, pool, slots, keys) -> None:
        active = self.imagery.active
        if active:
            if self._drape is None or self._drape.stack.tex_size != self.imagery.tex_size:
                if self._drape is not None:
                    self._drape.release()
                self._drape = ImageryDrape(self.ctx, self.capacity, self.imagery)
            self._drape.stack = self.imagery
            self._drape.update(pool, slots, keys)
            self._drape.tex.use(self.IMAGERY_UNIT)
        uni = {
            "u_imagery": self.IMAGERY_UNIT,
            "u_imagery_on": 1.0 if active else 0.0,
            "u_imagery_opacity": float(self.opacity),
            "u_imagery_size": float(self.imagery.tex_size),
            "u_tile_nodes": float(pool.size),
        }
        for name, value in uni.items():
            if name in program:
                program[name].value = value

    def draw(self, view, render_set, terrain, settings, displace=None) -> dict:
        """Draw the vector then point overlays; returns per-kind counts for the stats."""
        out: dict[str, int] = {}
        for ov in self.vectors:
            out["vector_segments"] = out.get("vector_segments", 0) + ov.draw(
                view, render_set, terrain, settings.exaggeration
            )
        for ov in self.points:
            out["objects"] = out.get("objects", 0) + ov.draw(
                view, render_set, terrain, settings.exaggeration
            )
        return out

    def release(self) -> None:
        if self._drape is not None:
            self._drape.release()
        for ov in (*self.vectors, *self.points):
            ov.release()
        self.vectors, self.points, self._twins = [], [], {}


def _flatten(layers: Sequence[Any]) -> Iterator[Any]:
    """The drawable parts of overlay layers (a group's ``parts``), in order."""
    for layer in layers:
        parts = getattr(layer, "parts", None)
        if isinstance(parts, list):
            yield from _flatten(parts)
        else:
            yield layer


def _make_twin(ctx: moderngl.Context, layer: Any) -> Any:
    """The GPU object drawing a vector or point layer model (its data and style)."""
    if layer.gpu_kind == "vectors":
        from globeview.render.overlay_vectors import LineStyle, VectorOverlay

        style = LineStyle(layer.color, layer.width_px, layer.dash_px)
        return VectorOverlay(ctx, layer.lines, style, layer.name, coarser=layer.coarser)
    from globeview.render.overlay_points import PointOverlay, PointStyle

    style = PointStyle(
        layer.object_kind,
        layer.size_px,
        layer.scale_m,
        layer.color,
        labels=layer.labels,
        label_color=layer.label_color,
    )
    # Per-point sizes (plugin API 1.2) as scale factors of the style's size for the kind:
    # pixels for placemarks, metres for 3-D objects.
    placemark = layer.object_kind == "placemark"
    sizes = getattr(layer, "point_sizes_px" if placemark else "point_scales_m", None)
    base = layer.size_px if placemark else layer.scale_m
    scale = None if sizes is None else np.asarray(sizes, np.float64) / float(base)
    colors = getattr(layer, "point_colors", None)
    return PointOverlay(
        ctx, layer.lon, layer.lat, layer.names, style, scale=scale, colors=colors, name=layer.name
    )
