"""`OverlayHost`: opening files as overlay layers through the layer types plugins provide.

The host side of a layer type's ``open()``: dispatch picks the type (an explicit one, the
declared extensions, then content sniffing), its result is checked (drawables become the
host's GL-free layer models, `globeview.model.overlay_layers`; an API 1.0 object with
``attach``/``detach`` is wrapped so each call into it is isolated), and the layer is added to
the `Globe` (an event). Garbage or a crash fails that layer type (one line, reported by the
registry); a bad file is the user's error (one line, the plugin stays enabled).

Opening needs no renderer and no GL: a window opens overlays before its GL context exists,
and opening, showing, restyling or removing one never makes a context current.
`prepare_gpu` (each frame, the context current) brings the renderer's GPU twins in line with
the globe's overlays and drops a layer the GPU side refuses, with one line in `errors`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import weakref
from pathlib import Path
from typing import Any

from psygnal import Signal

from globeview.app.host_checks import has_method
from globeview.app.layer_dispatch import (
    choose_layer_type,
    layer_type_infos,
    overlay_file_filter,
    parse_layer_spec,
    split_sublayer,
)
from globeview.errors import GlobeviewError, PluginFailed
from globeview.model.globe import Globe
from globeview.model.overlay_layers import (
    DrawnLayer,
    ImageryOverlayLayer,
    PointsLayer,
    VectorLayer,
    as_drawables,
    host_layer,
)
from globeview.plugins.api import PluginKind
from globeview.plugins.registry import PluginRegistry
from globeview.render.renderer import GlobeRenderer
from globeview.terrain.dem.data import EMBEDDED_DATA_DIR
from globeview.terrain.imagery import DEFAULT_TEX_SIZE, ImageryError

__all__ = ["OverlayHost"]

log = logging.getLogger("globeview.session")

#: The layer objects the host builds from drawables (GL-free models).
_HOST_LAYERS = (DrawnLayer, ImageryOverlayLayer, PointsLayer, VectorLayer)


class OverlayHost:
    """Opens overlays onto ``globe`` with the layer types of ``registry``."""

    def __init__(self, globe: Globe, registry: PluginRegistry) -> None:
        self.globe = globe
        self.registry = registry
        #: One line per overlay dropped at a frame because the GPU side refused it.
        self.errors: list[str] = []
        self._detach: list[_PluginLayer] = []  # removed API 1.0 layers, detached next frame
        #: The layer types that opened a file this session (`open`), e.g. to tell the user a
        #: setting of another type changed nothing.
        self.types_used: set[str] = set()
        #: Each host layer opened here -> (file, layer type, style) it was opened with
        #: (`restyle` reopens it so).
        self._sources: weakref.WeakKeyDictionary[Any, tuple[str, str, dict[str, Any]]] = (
            weakref.WeakKeyDictionary()
        )
        #: Layer -> (absolute path of its file, the layer type that opened it), for project
        #: files (`globeview.app.project`). Weak: a layer dropped is forgotten.
        self.origins: weakref.WeakKeyDictionary[Any, tuple[str, str]] = weakref.WeakKeyDictionary()

    # -- layer types ---------------------------------------------------------------------------
    def layer_types(self) -> list:
        """The enabled layer types in dispatch order (`layer_dispatch.LayerTypeInfo`: name,
        plugin, label, extensions), for menus and the Open Overlay filter."""
        return layer_type_infos(self.registry)

    def file_filter(self) -> str:
        """The Open Overlay dialog's filter: every enabled layer type's patterns."""
        return overlay_file_filter(self.registry)

    def layer_type_for(self, path: str, layer_type: str | None = None) -> str:
        """The name of the layer type that opens ``path`` (`layer_dispatch.choose_layer_type`:
        an explicit ``layer_type``, then declared extensions, then content sniffing).
        Raises a one-line `GlobeviewError` naming the installed types when none does."""
        return choose_layer_type(self.registry, path, layer_type)

    # -- opening and removing --------------------------------------------------------------------
    def open(self, path: str, layer_type: str | None = None, **style: Any) -> Any:
        """Open a file as an overlay layer with the layer type dispatch picks (``path`` may
        be ``"TYPE:FILE"``) and show it on top of the globe's overlays.

        The type's ``open()`` may return drawables (`globeview.model.drawables`), which
        the host checks and turns into layer models, or an API 1.0 object with
        ``attach``/``detach`` (attached at the next frame: its methods take the GL
        renderer). Bad files raise a one-line `GlobeviewError` and leave the plugin
        enabled; garbage returned, or a crash, fails that layer type (reported) and raises
        a one-line `PluginFailed` (a `GlobeviewError`: exit 3 on the command line)."""
        path, name, obj, style = self._resolve(str(path), layer_type, style)
        failed = object()
        result = self.registry.invoke(obj, "open", path, default=failed, user_errors=True, **style)
        layer: Any = failed
        own_drawables = result is not failed and as_drawables(result) is None
        if own_drawables and has_method(result, "drawables"):
            # An object returning drawables: its drawables() is the plugin's code.
            got = self.registry.call_for(obj, result.drawables, default=failed)
            result = failed if got is failed else _Named(got, result, path)
        if result is not failed:
            try:
                built, problem = host_layer(result, Path(path).name)
            except GlobeviewError:  # e.g. a RasterFile GDAL cannot read: the user's file
                raise
            except Exception as exc:  # noqa: BLE001  e.g. a drawable subclass whose property raises
                first = str(exc).splitlines()[0] if str(exc) else ""
                built, problem = (
                    None,
                    f"open() returned drawables the host cannot read "
                    f"({f'{type(exc).__name__}: {first}'[:120]})",
                )
            if problem is not None:
                self.registry.fail(obj, TypeError(problem))
            else:
                layer = built
        if layer is not failed and not isinstance(layer, _HOST_LAYERS):
            # An API 1.0 layer object: every call into it is plugin code, isolated, and
            # made at frame time (it takes the GL renderer): attached at the next frame.
            layer = _PluginLayer(layer, self.registry, obj, Path(path).name)
        elif layer is not failed:
            # A host layer is a model: no GL here. Its GPU twin is made at the next frame
            # (`prepare_gpu`), where a GL refusal drops the layer with a one-line message.
            _check_drape_size(layer, Path(path).name)
        if layer is failed:
            # The plugin's fault, not the file's: no other type stands in for it.
            raise PluginFailed(
                f"layer type {name} could not open {Path(path).name}: {self._why(obj)}"
            )
        self.globe.add_overlay(layer)
        self.types_used.add(name)
        if isinstance(layer, _HOST_LAYERS):
            self._sources[layer] = (path, name, dict(style))
        with contextlib.suppress(TypeError):  # a layer object that cannot be weakly keyed
            self.origins[layer] = (os.path.abspath(path), name)
        return layer

    def _resolve(
        self, path: str, layer_type: str | None, style: dict[str, Any]
    ) -> tuple[str, str, Any, dict[str, Any]]:
        """(file, layer type name, its object, style) for what `open` was given: ``TYPE:``
        and ``::LAYER`` taken off the path (the layer joins the style as ``layer=``)."""
        if layer_type is None:
            layer_type, path = parse_layer_spec(path)
        path, sublayer = split_sublayer(path)
        name = self.layer_type_for(path, layer_type)
        obj = self.registry.find(PluginKind.LAYER, name)
        if obj is None:
            raise GlobeviewError(f"layer type {name} is not available ({path})")
        if sublayer is not None:  # FILE::LAYER: the layer inside the file, for types taking one
            _check_takes_layer(obj, name, Path(path).name, sublayer)
            style = {**style, "layer": sublayer}
        return path, name, obj, style

    # -- styling by attribute (GIS vector files) ------------------------------------------------
    def vector_fields(self, layer: Any) -> list[str] | None:
        """The attribute fields of a layer the ``gis`` layer type opened (what it can be
        coloured or labelled by), or None for another layer. One line (`GlobeviewError`)
        when its file can no longer be read."""
        src = self._sources.get(layer)
        if src is None or src[1] != "gis":
            return None
        from globeview.terrain.ogr_vectors import layer_fields

        return layer_fields(src[0], src[2].get("layer"))

    def opened_style(self, layer: Any) -> dict[str, Any] | None:
        """The style ``layer`` was opened with (a copy; None: not opened from a file here)."""
        src = self._sources.get(layer)
        return None if src is None else dict(src[2])

    def restyle(self, layer: Any, **style: Any) -> Any:
        """Reopen ``layer`` from its file with ``style`` over the style it was opened with
        (e.g. ``color_by="kind"``, ``label=None``), in its place among the overlays and
        with its visibility; returns the new layer. Raises `GlobeviewError` (one line, the
        old layer kept) for a layer not opened from a file here or a style its type refuses."""
        src = self._sources.get(layer)
        if src is None:
            raise GlobeviewError(f"{getattr(layer, 'name', 'overlay')}: not opened from a file")
        path, type_name, old = src
        new = self.open(path, type_name, **{**old, **style})
        order = [ly for ly in self.globe.overlays if ly is not new]
        at = next(i for i, ly in enumerate(order) if ly is layer)
        order[at] = new
        order.append(layer)  # on top for a moment, then removed: one row changes in place
        self.globe.set_overlay_order(order)
        if not getattr(layer, "visible", True):
            new.set_visible(False)
        self.remove(layer)
        return new

    def open_embedded(self, imagery: bool = False) -> list:
        """The embedded default overlays: Natural Earth borders and coastlines (and the Blue
        Marble imagery with ``imagery``), opened through the enabled built-in layer types
        like any file (none when those types are disabled)."""
        wanted: list[tuple[str, Path, dict]] = []
        if imagery:
            wanted.append(("imagery", EMBEDDED_DATA_DIR / "bluemarble_2048x1024.tif", {}))
        wanted.append(
            (
                "vector",
                EMBEDDED_DATA_DIR / "ne_110m_countries.geojson",
                {"color": (1.0, 0.92, 0.35, 1.0), "width_px": 1.5},
            )
        )
        layers = []
        for kind, path, style in wanted:
            # offers(): from the manifests, so no other layer plugin is imported for this.
            if self.registry.offers(PluginKind.LAYER, kind):
                layers.append(self.open(str(path), kind, **style))
        return layers

    def remove(self, layer: Any) -> None:
        """Take ``layer`` off the globe; no GL: a host layer's GPU twin is released and an
        API 1.0 layer object detached at the next frame."""
        self.globe.remove_overlay(layer)
        if isinstance(layer, _PluginLayer) and layer.attached:
            self._detach.append(layer)

    # -- the GPU side (at frame time) ------------------------------------------------------------
    def prepare_gpu(self, renderer: GlobeRenderer) -> None:
        """Bring ``renderer``'s overlay twins in line with the globe's overlays; a layer the
        GPU side refuses (its limits) is dropped from the globe with one line in
        ``errors`` (and the log)."""
        while self._detach:
            self._detach.pop().gpu_detach(renderer)
        for layer in list(self.globe.overlays):
            if not isinstance(layer, _PluginLayer):
                continue
            if not layer.attached and not layer.gpu_attach(renderer):
                self._drop(layer, f"could not attach: {self._why(layer._owner)}")
            else:
                layer.gpu_show(renderer)
        for part, why in renderer.overlays.sync(self.globe.overlays):
            top = next((ly for ly in self.globe.overlays if _contains(ly, part)), part)
            self._drop(top, why)

    def _drop(self, layer: Any, why: str) -> None:
        """Take a layer the frame could not draw off the globe, with one line."""
        message = f"cannot draw {getattr(layer, 'name', 'overlay')}: {why}"[:300]
        log.warning("%s", message)
        self.errors.append(message)
        if any(ly is layer for ly in self.globe.overlays):
            self.globe.remove_overlay(layer)

    def _why(self, contribution: object) -> str:
        """The recorded reason a contribution (or its plugin) failed, one line."""
        try:
            plugin, cname = self.registry.contribution_of(contribution)
        except (KeyError, AttributeError):
            return "failed"
        rec = self.registry.records.get(plugin)
        if rec is None:
            return "failed"
        failure = getattr(rec, "failures", {}).get(cname)
        if failure is not None and getattr(failure, "error", None):
            return str(failure.error)
        return rec.error or "failed"


class _PluginLayer:
    """An API 1.0 layer object (``attach``/``detach``, optional ``set_visible``) behind the
    host's isolation, listed with kind 'plugin' and the object's ``name`` (default: the
    file's). Its methods take the GL renderer, so the host calls them only at frame time
    (`OverlayHost.prepare_gpu`, the context current): ``set_visible`` here only records the
    wish. A method that raises fails its layer type (one line) instead of the window."""

    kind = "plugin"
    #: Emitted when the wanted visibility changed (the globe re-emits it as ``overlays``).
    changed = Signal()

    def __init__(self, layer: object, registry: PluginRegistry, owner: object, path_name: str):
        self.layer_object = layer
        self._registry = registry
        self._owner = owner  # the layer type that opened it: failures are its own
        self.visible = True
        self.attached = False  # attach() ran (at a frame) and detach() has not
        self.shown = True  # the visibility the object was last told
        try:
            name = getattr(layer, "name", "")
        except Exception:  # noqa: BLE001  a plugin object's attribute may raise anything
            name = ""
        self.name = (name if isinstance(name, str) and name else path_name)[:200]

    def _call(self, method: str, *args: object) -> bool:
        if not has_method(self.layer_object, method):
            return False
        failed = object()
        fn = getattr(self.layer_object, method)
        return self._registry.call_for(self._owner, fn, *args, default=failed) is not failed

    # -- the model side (no plugin call, no GL) ---------------------------------------------
    def set_visible(self, visible: bool) -> bool:
        """Record the visibility wanted (told to the object, as API 1.0's
        ``set_visible(renderer, visible)``, at the next frame); True (and ``changed``) if it
        changed."""
        if bool(visible) == self.visible:
            return False
        self.visible = bool(visible)
        self.changed.emit()
        return True

    # -- the GPU side (OverlayHost.prepare_gpu, the context current) -------------------------
    def gpu_attach(self, renderer: GlobeRenderer) -> bool:
        """Attach the object; False when it failed (its layer type is reported)."""
        self.attached = self._call("attach", renderer)
        self.shown = True
        return self.attached

    def gpu_detach(self, renderer: GlobeRenderer) -> None:
        if self.attached:
            self._call("detach", renderer)
            self.attached = False

    def gpu_show(self, renderer: GlobeRenderer) -> None:
        """Tell the object the visibility the model wants, once per change."""
        if self.attached and self.shown != self.visible:
            self.shown = self.visible
            self._call("set_visible", renderer, self.visible)


class _Named:
    """A layer object's drawables with its ``name`` (the default: the file's)."""

    def __init__(self, items: object, owner: object, path: str) -> None:
        self.items = items
        self.name = str(getattr(owner, "name", "") or Path(path).name)[:200]

    def drawables(self) -> object:
        return self.items


def _check_takes_layer(obj: object, type_name: str, file_name: str, sublayer: str) -> None:
    """One line when a ``FILE::LAYER`` goes to a layer type whose ``open`` has no ``layer``
    parameter (the plugin would fail on an argument the user added, not on its own fault)."""
    import inspect

    try:
        params = inspect.signature(obj.open).parameters  # type: ignore[attr-defined]
    except (TypeError, ValueError, AttributeError):
        return
    if "layer" not in params:
        raise GlobeviewError(
            f"{file_name}::{sublayer:.60}: layer type {type_name} opens whole files (no ::LAYER)"
        )


def _contains(layer: object, part: object) -> bool:
    """Whether ``part`` is ``layer`` or one of its parts (a `DrawnLayer`'s)."""
    return layer is part or any(p is part for p in getattr(layer, "parts", ()) or ())


def _check_drape_size(layer: object, name: str) -> None:
    """Refuse (one line) a drape whose texture size the renderer's imagery stack cannot
    compose with (all drapes of a globe share one texture array, of the imagery's
    `DEFAULT_TEX_SIZE`: the renderer's `OverlaySet.sync` refuses another size at the frame
    too, this says so when the file is opened)."""
    for part in getattr(layer, "parts", None) or [layer]:
        if getattr(part, "gpu_kind", None) != "imagery":
            continue
        size = getattr(part.layer.source, "tex_size", DEFAULT_TEX_SIZE)
        if size != DEFAULT_TEX_SIZE:
            raise ImageryError(f"{name}: texture size {size} != {DEFAULT_TEX_SIZE}")
