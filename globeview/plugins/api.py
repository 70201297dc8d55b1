"""The plugin API, version ``API_VERSION``: what a globeview plugin implements and receives.

Three kinds of contribution (`PluginKind`):

- ``lod``: a `LodProvider` turns a `ViewState` and the terrain into a `RenderSet` each frame.
- ``tool``: a `Tool` handles pointer and key events, draws overlay primitives, and may displace
  the terrain's vertices in the vertex shader (`Tool.displacement_glsl`).
- ``layer``: a `LayerType` opens files of some formats as new scene layers.

A contribution's manifest target (``"module:attribute"``) names a *factory*: a class or
callable that takes one `PluginContext` and returns the contribution object. The base classes
here accept the context in ``__init__`` (and ``None``, so tests can build them bare).

Nothing here imports Qt: events are plain dataclasses the UI translates Qt events into.
Frames and units: ECEF metres (float64), geodetic degrees, heights in metres above WGS84,
pixel coordinates with the origin at the top-left of the view.

Versioning: ``API_VERSION`` is ``MAJOR.MINOR``. A minor bump only adds (new optional hooks,
new fields with defaults); a major bump may break plugins. A plugin's manifest declares the
version it targets; it loads when the majors match and its minor is not newer than the host's.

This module is the whole public surface: a plugin (and every built-in one, which the import
contracts in pyproject.toml hold to it) imports from ``globeview.plugins.api`` only, besides
numpy, the standard library and its own package. Besides the contribution bases and events
defined here it re-exports, under the same names, what a provider, tool or layer builds with:

- frames and results: `ViewState`, `RenderSet` (+ `InvalidRenderSet`, `MAX_TILES`,
  `MAX_KEY_LEVEL`), `IndexVariant`;
- the terrain: `TerrainStack` (``metadata``, ``heights``, ``height_at``, ``max_level``,
  ``tile_size``, ``version``, ``layers``), `N_STRIDES`, and the quadtree's tile keys
  `TileKey`, `level_shape`, `tile_bounds_arrays`, `node_lonlat`;
- culling and error helpers the built-in providers use (`tile_bounding_points`,
  `frustum_visible`, `horizon_visible`, `bounding_distance`, `cull_level`, `chord_sag`, ...);
- the shared quadtree traversal an LOD provider steers with a policy (`traverse`,
  `LodPolicy`, `ScreenSpaceErrorPolicy`, `TileCandidates`, `render_set_from_tiles`, ...),
  and `triangle_count` (the triangles a render set or selection would draw);
- geodesy on WGS84 (`WGS84`, `lonlat_to_ecef`, `ecef_to_lonlat`, `ecef_foot_points`,
  `enu_basis`, geodesics);
- errors: `GlobeviewError`, the base of every one-line user error.

The renderer and terrain re-exports are imported on first use (PEP 562 ``__getattr__``), so
reading a manifest, which imports this module for `API_VERSION`, does not load them.
Delegating to another provider (e.g. wrapping chunked-sse): `PluginContext.lod_provider`.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import math
import weakref
from collections.abc import Callable, MutableMapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import numpy as np

from globeview.errors import GlobeviewError
from globeview.model.drawables import (
    Lines,
    Points,
    RasterDrape,
    RasterFile,
    RasterInfo,
    raster_info,
)
from globeview.model.plot import Plot, PlotSeries, read_csv_columns
from globeview.plugins.geo import (
    TerrainSample,
    ecef_to_lonlat,
    geodesic_direct,
    geodesic_inverse,
    geodesic_samples,
    lonlat_to_ecef,
    sample_terrain,
)

if TYPE_CHECKING:  # the lazy re-exports (`_REEXPORTS`), spelled out for type checkers
    from globeview.geodesy import WGS84, ecef_foot_points, enu_basis
    from globeview.lod.candidates import MAX_LEVEL, Selection, TileCandidates, TreeRows
    from globeview.lod.culling import (
        LATTICE,
        bounding_distance,
        box_angular_distance_pre,
        chord_sag,
        cull_level,
        displacement_bend_m,
        displacement_chord_error_m,
        frustum_visible,
        horizon_cap,
        horizon_peak_angle,
        horizon_visible,
        tile_bounding_points,
    )
    from globeview.lod.flat_walk import SelectionState
    from globeview.lod.policy import LodPolicy, coarsest_stride_within
    from globeview.lod.render_set import MAX_KEY_LEVEL, MAX_TILES, InvalidRenderSet, RenderSet
    from globeview.lod.sse_policy import ScreenSpaceErrorPolicy
    from globeview.lod.stitching import neighbour_edge_strides, render_set_from_tiles
    from globeview.lod.tile_indices import IndexVariant, node_lonlat
    from globeview.lod.traversal import displacement_key, traverse
    from globeview.lod.triangle_count import triangle_count
    from globeview.lod.view_state import ViewState
    from globeview.model.vector_files import read_vector_file, vector_file_layers
    from globeview.terrain.compose.metadata import N_STRIDES
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.quadtree import TileKey, level_shape, tile_bounds_arrays

__all__ = [
    "API_VERSION",
    "LATTICE",
    "MAX_KEY_LEVEL",
    "MAX_LEVEL",
    "MAX_TILES",
    "N_STRIDES",
    "TAU_OVERRIDE",
    "TEXEL_SIZE",
    "TILE_BUDGET",
    "WGS84",
    "DelegateProvider",
    "GlobeviewError",
    "IndexVariant",
    "InvalidRenderSet",
    "KeyEvent",
    "LayerType",
    "Lines",
    "LodPolicy",
    "LodProvider",
    "Marker",
    "Overlay",
    "Plot",
    "PlotSeries",
    "PluginContext",
    "PluginKind",
    "PointerEvent",
    "Points",
    "PolicyProvider",
    "Polyline",
    "ProviderUnavailable",
    "RasterDrape",
    "RasterFile",
    "RasterInfo",
    "RenderSet",
    "RendererHooks",
    "ScreenSpaceErrorPolicy",
    "Selection",
    "SelectionState",
    "Setting",
    "TerrainSample",
    "TerrainStack",
    "TileCandidates",
    "TileKey",
    "Tool",
    "TreeRows",
    "TwoPointPick",
    "ViewState",
    "bounding_distance",
    "box_angular_distance_pre",
    "chord_sag",
    "coarsest_stride_within",
    "cull_level",
    "displacement_bend_m",
    "displacement_chord_error_m",
    "displacement_key",
    "ecef_foot_points",
    "ecef_to_lonlat",
    "enu_basis",
    "frustum_visible",
    "geodesic_direct",
    "geodesic_inverse",
    "geodesic_samples",
    "horizon_cap",
    "horizon_peak_angle",
    "horizon_visible",
    "level_shape",
    "lonlat_to_ecef",
    "neighbour_edge_strides",
    "node_lonlat",
    "raster_info",
    "read_csv_columns",
    "read_vector_file",
    "render_set_from_tiles",
    "sample_terrain",
    "tile_bounding_points",
    "tile_bounds_arrays",
    "traverse",
    "triangle_count",
    "vector_file_layers",
]

#: Public name -> the host module defining it. These names are the supported surface (the
#: modules behind them are internals a plugin must not import; an import contract checks the
#: built-ins and the example). Imported on first access, see the module docstring.
_REEXPORTS: dict[str, str] = {
    "WGS84": "globeview.geodesy",
    "ecef_foot_points": "globeview.geodesy",
    "enu_basis": "globeview.geodesy",
    "LATTICE": "globeview.lod.culling",
    "bounding_distance": "globeview.lod.culling",
    "box_angular_distance_pre": "globeview.lod.culling",
    "chord_sag": "globeview.lod.culling",
    "cull_level": "globeview.lod.culling",
    "displacement_bend_m": "globeview.lod.culling",
    "displacement_chord_error_m": "globeview.lod.culling",
    "frustum_visible": "globeview.lod.culling",
    "horizon_cap": "globeview.lod.culling",
    "horizon_peak_angle": "globeview.lod.culling",
    "horizon_visible": "globeview.lod.culling",
    "tile_bounding_points": "globeview.lod.culling",
    "MAX_KEY_LEVEL": "globeview.lod.render_set",
    "MAX_TILES": "globeview.lod.render_set",
    "InvalidRenderSet": "globeview.lod.render_set",
    "RenderSet": "globeview.lod.render_set",
    "IndexVariant": "globeview.lod.tile_indices",
    "LodPolicy": "globeview.lod.policy",
    "ScreenSpaceErrorPolicy": "globeview.lod.sse_policy",
    "coarsest_stride_within": "globeview.lod.policy",
    "neighbour_edge_strides": "globeview.lod.stitching",
    "render_set_from_tiles": "globeview.lod.stitching",
    "MAX_LEVEL": "globeview.lod.candidates",
    "Selection": "globeview.lod.candidates",
    "TileCandidates": "globeview.lod.candidates",
    "TreeRows": "globeview.lod.candidates",
    "SelectionState": "globeview.lod.flat_walk",
    "traverse": "globeview.lod.traversal",
    "displacement_key": "globeview.lod.traversal",
    "triangle_count": "globeview.lod.triangle_count",
    "node_lonlat": "globeview.lod.tile_indices",
    "ViewState": "globeview.lod.view_state",
    "TileKey": "globeview.terrain.quadtree",
    "level_shape": "globeview.terrain.quadtree",
    "tile_bounds_arrays": "globeview.terrain.quadtree",
    "N_STRIDES": "globeview.terrain.compose.metadata",
    "TerrainStack": "globeview.terrain.compose.stack",
    "read_vector_file": "globeview.model.vector_files",
    "vector_file_layers": "globeview.model.vector_files",
}


def __getattr__(name: str) -> Any:
    """A re-exported host name (`_REEXPORTS`), imported on first access and then kept in
    this module's namespace."""
    module = _REEXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_REEXPORTS))


#: The plugin API version this host implements ("MAJOR.MINOR"). 1.2 added, all optional:
#: `PlotSeries` (plots of several curves), per-point sizes and colours of `Points`,
#: `triangle_count`, and the ``sniff`` contract written down (docs/plugins.md). 1.3 added:
#: `Tool.animate` and `Tool.plot` declared on `Tool` (the host called them before), the
#: two-point picking helper `TwoPointPick`, and shared setting declarations (`TILE_BUDGET`,
#: `TEXEL_SIZE`, `TAU_OVERRIDE`). 1.4 added the flat selection (issue #27): `traverse`'s
#: ``state`` (`SelectionState`, which `PolicyProvider` keeps), `LodPolicy.per_tile` and
#: `LodPolicy.stop_level` (`TreeRows`), `TileCandidates.flat`, ``levels_past_data`` and
#: ``pole``, and `Selection.tree`. 1.5 added GIS vector files (issue #26):
#: `read_vector_file` (any OGR source as drawables, coloured and labelled by attribute),
#: `vector_file_layers`, and the ``legend`` text of `Lines` and `Points`.
API_VERSION = "1.5"


class PluginKind(StrEnum):
    """What a contribution is: an LOD provider, an interactive tool, or a layer type."""

    LOD = "lod"
    TOOL = "tool"
    LAYER = "layer"


# -- settings --------------------------------------------------------------------------------
SettingType = Literal["float", "int", "bool", "choice"]


@dataclass(frozen=True)
class Setting:
    """One user-adjustable parameter of a contribution (the UI builds a widget from it).

    Attributes:
        name: key in the values dict passed to ``configure`` (identifier-like).
        type: 'float', 'int', 'bool' or 'choice'.
        default: value used when the user set none.
        min, max: inclusive bounds for 'float' and 'int' (None: unbounded).
        choices: the allowed values of a 'choice' setting (strings).
        label: short text for the UI (defaults to ``name``).
        help: one sentence for a tooltip, stating the unit.
    """

    name: str
    type: SettingType
    default: Any
    min: float | None = None
    max: float | None = None
    choices: tuple[str, ...] = ()
    label: str = ""
    help: str = ""

    def coerce(self, value: Any) -> Any:
        """``value`` converted to this setting's type and clamped to its bounds.

        Raises ValueError for a value that cannot be converted (also NaN, infinity, a bool
        for a number) or a choice not offered.
        """
        if self.type == "bool":
            if isinstance(value, str):
                low = value.strip().lower()
                if low in ("1", "true", "yes", "on"):
                    return True
                if low in ("0", "false", "no", "off"):
                    return False
                raise ValueError(f"setting {self.name!r}: {value!r} is not a boolean")
            return bool(value)
        if self.type == "choice":
            v = str(value)
            if v not in self.choices:
                raise ValueError(f"setting {self.name!r}: {v!r} is not one of {self.choices}")
            return v
        if self.type not in ("int", "float"):
            raise ValueError(f"setting {self.name!r}: unknown type {self.type!r}")
        if isinstance(value, bool):  # True is not the number 1 to a user
            raise ValueError(f"setting {self.name!r}: {value!r} is not a number")
        try:
            num: float | int = float(value)
            if not math.isfinite(num):
                raise ValueError(f"setting {self.name!r}: {value!r} is not a finite number")
            if self.type == "int":
                num = int(value) if isinstance(value, int) else int(num)
        except (OverflowError, TypeError) as exc:
            raise ValueError(f"setting {self.name!r}: {value!r:.40} is not a number") from exc
        if self.min is not None and num < self.min:
            num = type(num)(self.min)
        if self.max is not None and num > self.max:
            num = type(num)(self.max)
        return num


def resolve_settings(settings: Sequence[Setting], values: dict[str, Any]) -> dict[str, Any]:
    """Defaults overlaid with ``values``, each coerced; unknown or invalid values are dropped
    (the default stays), so stale stored settings never break a plugin."""
    out: dict[str, Any] = {}
    for s in settings:
        out[s.name] = s.default
        if isinstance(values, dict) and s.name in values:
            with contextlib.suppress(TypeError, ValueError, OverflowError):
                out[s.name] = s.coerce(values[s.name])
    return out


# Declarations several contributions share (API 1.3): use them as they are, or with another
# default or range through ``dataclasses.replace(TILE_BUDGET, default=1500, max=MAX_TILES)``;
# the name stays, so the stored values, ``--set NAME.max_tiles=...`` and the window's
# controls are the same for every provider that declares one.

#: An LOD provider's tile budget: at most this many tiles drawn in a frame (a count).
TILE_BUDGET = Setting(
    "max_tiles",
    "int",
    600,
    min=16,
    max=2000,
    label="tile budget",
    help="most tiles drawn in a frame (count); past it the tiles with the largest error refine "
    "first",
)
#: Refine tiles while one texel of their textures covers more than this many pixels.
TEXEL_SIZE = Setting(
    "texel_px",
    "float",
    1.5,
    min=0.5,
    max=8.0,
    label="texel size (pixels)",
    help="refine tiles while a texel of the tile textures covers more pixels than this",
)
#: A provider's own screen-space error threshold in pixels; 0 uses the view's tau.
TAU_OVERRIDE = Setting(
    "tau_px",
    "float",
    0.0,
    min=0.0,
    max=64.0,
    label="tau override (pixels)",
    help="screen-space error threshold in pixels for this provider; 0 uses the view's tau",
)


# -- context ---------------------------------------------------------------------------------
@runtime_checkable
class RendererHooks(Protocol):
    """What the renderer lets plugins do. The host passes an object with these methods."""

    def request_redraw(self) -> None:
        """Ask for a new frame (e.g. a tool's overlay changed)."""

    def set_status(self, text: str) -> None:
        """Show a one-line message in the status bar (or log it, headless)."""


class NullRendererHooks:
    """Renderer hooks for headless use: redraw requests are counted, status text is kept."""

    def __init__(self) -> None:
        self.redraws = 0
        self.status = ""

    def request_redraw(self) -> None:
        self.redraws += 1

    def set_status(self, text: str) -> None:
        self.status = text


@dataclass
class PluginContext:
    """What a plugin receives when one of its contributions is created.

    Attributes:
        name: the plugin's name (from its manifest).
        scene: the host's scene model (layers); None headless without a scene.
        terrain: the composed terrain of the visible DEM layers
            (`globeview.terrain.compose.stack.TerrainStack`), or None.
        camera: the `globeview.model.camera.Camera` (ECEF, float64), or None.
        renderer: `RendererHooks`.
        settings: this plugin's persisted settings, a mutable mapping of JSON-able values
            (writes persist at once).
        logger: ``logging.getLogger("globeview.plugins.<name>")``.

    The host may replace ``scene``, ``terrain`` and ``camera`` when the user opens data; a
    plugin should read them from the context when it needs them rather than keep copies.

    ``host`` is the host's plugin registry (None in a bare context); plugins reach other
    contributions through `lod_provider`, never through it directly.
    """

    name: str
    scene: Any = None
    terrain: Any = None
    camera: Any = None
    renderer: RendererHooks = field(default_factory=NullRendererHooks)
    settings: MutableMapping[str, Any] = field(default_factory=dict)
    logger: logging.Logger = field(default_factory=lambda: logging.getLogger("globeview.plugins"))
    host: Any = field(default=None, repr=False, compare=False)

    def lod_provider(self, name: str) -> DelegateProvider:
        """The enabled LOD provider ``name`` (e.g. ``"chunked-sse"``), to delegate to.

        Returns a `DelegateProvider`: its ``select`` runs the other provider through the
        host, with the same isolation, time budget and type check as the host's own calls,
        so a bug there fails *that* provider's plugin, and it is named as the cause. Your
        ``select`` then gets `ProviderUnavailable`; left uncaught, it fails your provider
        for the session with that one-line reason (the user re-enables your plugin, which
        clears its failures, once the delegate is back). The provider is looked up at every
        call: a plugin disabled or failed later is noticed. Raises `ProviderUnavailable`
        (one line naming the enabled providers) when no enabled plugin declares ``name``, and
        without a host.
        """
        host = self.host
        shown = _short_repr(name)
        if host is None:
            raise ProviderUnavailable(f"no host to find LOD provider {shown} in (bare context)")
        if not isinstance(name, str) or not host.offers(PluginKind.LOD, name):
            enabled = ", ".join(host.declared(PluginKind.LOD)) or "none"
            raise ProviderUnavailable(f"no enabled LOD provider {shown} (enabled: {enabled})")
        return DelegateProvider(host, name)


def _short_repr(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters (for one-line messages)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class _Contribution:
    """Common part of LOD providers and tools: name, label, settings, ``configure``."""

    #: Unique name among contributions of its kind (defaults to the manifest's name).
    name: str = ""
    #: Text for menus.
    label: str = ""
    #: The adjustable parameters; ``configure`` receives their values.
    settings: Sequence[Setting] = ()

    def __init__(self, context: PluginContext | None = None) -> None:
        self.context = context
        self.values: dict[str, Any] = resolve_settings(self.settings, {})

    def configure(self, values: dict[str, Any]) -> None:
        """Apply setting values (missing ones take their defaults). The host calls this after
        creating the contribution and whenever the user changes a setting."""
        self.values = resolve_settings(self.settings, values)


# -- LOD providers ---------------------------------------------------------------------------
class LodProvider(_Contribution):
    """Chooses the tiles to draw each frame.

    ``select`` runs once per frame on the UI thread; keep it vectorised (numpy over arrays of
    tiles) and within a few milliseconds. It must not draw or touch GL. The host checks every
    result (`RenderSet.validate`) and times every call against the frame budget
    (``plugins/budget_ms``, default 1000 ms a call): a malformed render set, or 5 overruns in
    a row in the window, disables the provider's plugin and the frame falls back to
    chunked-sse.
    """

    def select(self, view: ViewState, terrain: Any) -> RenderSet:
        """The render set for one frame.

        Args:
            view: the frame's `ViewState` (ECEF eye, frustum, viewport, tau_px, ...);
                ``view.in_local_frames(origins, bases)`` expresses the eye and frustum in
                each tile's ENU frame.
            terrain: the composed terrain (`TerrainStack`) or None when no DEM is open.
        """
        raise NotImplementedError

    def reset(self) -> None:
        """Forget anything cached between frames (the next ``select`` computes afresh).
        The host calls it before measured frames; the default does nothing."""


class PolicyProvider(LodProvider):
    """An LOD provider that is one `LodPolicy` on the shared traversal: ``select`` builds
    ``policy(**self.values)`` (the policy takes the provider's settings as keyword arguments,
    one per `Setting`) and returns ``traverse(view, terrain, that policy, state=...)``. Adding
    an LOD provider is then a policy class, this subclass naming it, and a manifest::

        class CoarseProvider(PolicyProvider):
            policy = CoarsePolicy
            settings = (Setting("factor", "float", 4.0, min=1.0, max=64.0),)

    A repaint with an unchanged view (window expose, overlay redraw) reuses the last render
    set (its stats then say ``lod_ms`` 0 and ``lod_cached`` 1); any change of the camera,
    viewport, field of view, tau, exaggeration, navigation speed or frame rate, of a setting
    or of the terrain (its ``version``) selects afresh, and so does a frame whose tool
    displacement (``view.displace``) changed: its `displacement_key` (the tool's key and
    where the displacement moves fixed probe points) differs from the last frame's. A
    displacement without the tool's key (``view.displacement_key`` None) selects every frame.
    A policy that reads anything else of the view must not be wrapped this way.

    The provider keeps a `SelectionState` (API 1.4): with a `LodPolicy.per_tile` policy a
    moving camera's selection starts from last frame's candidate tree (the flat walk), with
    the same result as a walk from scratch; `reset` forgets it.
    """

    #: The policy class, called with the setting values as keyword arguments each frame.
    policy: type[LodPolicy]
    # The last selection and what it was selected for (`_reuse_key`); class defaults so that
    # a subclass's __init__ need not call ours.
    _reuse_key: tuple[object, ...] | None = None
    _reuse: RenderSet | None = None
    # The terrain it was for, weakly: an id alone could be a new terrain's after the old one
    # was freed, and a strong reference would keep a closed terrain alive.
    _reuse_terrain: weakref.ref[Any] | None = None
    # The flat walk's state (made on first use: this module must not import the LOD engine).
    _selection_state: SelectionState | None = None
    # Under a tool displacement: the view selected for and where its displacement moves the
    # probe points (`displacement_key`, computed only once a still frame asks).
    _reuse_view: ViewState | None = None
    _reuse_moved: object | None = None

    def reset(self) -> None:
        self._reuse_key = self._reuse = self._reuse_terrain = None
        self._reuse_view = self._reuse_moved = None
        if self._selection_state is not None:
            self._selection_state.reset()

    def _state(self) -> SelectionState:
        from globeview.lod.flat_walk import SelectionState

        if self._selection_state is None:
            self._selection_state = SelectionState()
        return self._selection_state

    def select(self, view: ViewState, terrain: Any) -> RenderSet:
        # Deferred (heavy): reading a manifest imports this module, and must not load the
        # LOD engine and the terrain (tests/plugins/test_plugin_facade.py).
        from globeview.lod.traversal import displacement_key, traverse

        # A displacement without the tool's key could change where no probe point sees it.
        if terrain is None or (view.displace is not None and view.displacement_key is None):
            self._reuse_key = self._reuse = self._reuse_terrain = None
            return traverse(view, terrain, self.policy(**self.values), state=self._state())
        key = (
            view.eye.tobytes(),
            view.rotation.tobytes(),
            view.proj.tobytes(),  # near and far too
            view.viewport,
            view.fovy_deg,
            view.tau_px,
            view.exaggeration,
            view.speed_mps,
            view.frame_rate_hz,
            terrain.version,
            tuple(sorted(self.values.items())),
            # A still collapse selects once; an animating one (its key changes) every frame.
            view.displacement_key,
            view.displacement_bend is not None,
        )
        old = self._reuse_terrain
        if (
            self._reuse is not None
            and key == self._reuse_key
            and old is not None
            and old() is terrain
            and self._same_displacement(view, displacement_key)
        ):
            rs = self._reuse
            rs.stats["lod_ms"] = 0.0
            rs.stats["lod_cached"] = 1.0
            return rs
        rs = traverse(view, terrain, self.policy(**self.values), state=self._state())
        self._reuse_key, self._reuse, self._reuse_terrain = key, rs, weakref.ref(terrain)
        self._reuse_view = view if view.displace is not None else None
        self._reuse_moved = None
        return rs

    def _same_displacement(self, view: ViewState, moved: Callable[[ViewState], object]) -> bool:
        """Whether ``view``'s displacement moves the probe points exactly as the one last
        selected for did (``moved``: `displacement_key`); True without a displacement. Only
        a frame otherwise equal to the last pays for the probes (a moving one never)."""
        if view.displace is None or self._reuse_view is None:
            return view.displace is None and self._reuse_view is None
        if self._reuse_moved is None:
            self._reuse_moved = moved(self._reuse_view)
        return bool(moved(view) == self._reuse_moved)


class ProviderUnavailable(Exception):
    """The LOD provider a plugin delegates to is not there: disabled, failed, or never
    installed (`PluginContext.lod_provider`). One-line message naming it and why."""


class DelegateProvider:
    """Another plugin's LOD provider as seen by a plugin that wraps it
    (`PluginContext.lod_provider`).

    ``select`` goes through the host's registry (`PluginRegistry.select`): isolated, timed
    against the frame budget, and checked to return a `RenderSet`. The render set it returns
    is read-only (its arrays are read-only views, its containers copies): the delegate may
    hand the same set out again next frame, so build a new `RenderSet` from copies of what
    you change. Writing into it raises ValueError, which fails your provider, not the
    delegate.
    """

    def __init__(self, host: Any, name: str) -> None:
        self._host = host
        #: The delegate's contribution name (e.g. "chunked-sse").
        self.name = name
        self._busy = False

    def _instance(self) -> Any:
        inner = self._host.find(PluginKind.LOD, self.name)
        if inner is None:
            raise ProviderUnavailable(f"LOD provider {self.name!r} is disabled or has failed")
        return inner

    @property
    def values(self) -> dict[str, Any]:
        """A copy of the delegate's current setting values."""
        return dict(getattr(self._instance(), "values", {}))

    def select(self, view: ViewState, terrain: Any) -> RenderSet:
        """The delegate's render set for this frame. Raises `ProviderUnavailable` when it is
        disabled, when it fails now (the message says why) and on a delegation cycle."""
        if self._busy:  # A wraps B wraps A: fail this frame instead of recursing
            raise ProviderUnavailable(f"delegation cycle through LOD provider {self.name!r}")
        _check_frame_args(view, terrain)  # the caller's garbage must not fail the delegate
        inner = self._instance()
        self._busy = True
        try:
            rs = self._host.select(inner, view, terrain)
        finally:
            self._busy = False
        if rs is None:
            raise ProviderUnavailable(
                f"LOD provider {self.name!r} failed: {_failure_reason(self._host, inner)}"
            )
        return _read_only(rs)

    def reset(self) -> None:
        """Ask the delegate to forget what it cached between frames (isolated)."""
        inner = self._host.find(PluginKind.LOD, self.name)
        if inner is not None:
            self._host.invoke(inner, "reset")


def _check_frame_args(view: Any, terrain: Any) -> None:
    """TypeError unless ``view`` is a `ViewState` and ``terrain`` a `TerrainStack` or None
    (what the host passes a provider's ``select``)."""
    # Deferred (heavy): the terrain is not loaded by reading a manifest (see `select`).
    from globeview.lod.view_state import ViewState
    from globeview.terrain.compose.stack import TerrainStack

    if not isinstance(view, ViewState):
        raise TypeError(f"select() needs a ViewState, not {type(view).__name__}")
    if terrain is not None and not isinstance(terrain, TerrainStack):
        raise TypeError(f"select() needs a TerrainStack or None, not {type(terrain).__name__}")


def _frozen(a: Any) -> Any:
    """A read-only view of array ``a`` (the original stays writable for its owner)."""
    if isinstance(a, np.ndarray):
        a = a.view()
        a.flags.writeable = False
    return a


def _read_only(rs: RenderSet) -> RenderSet:
    """A plain `RenderSet` sharing ``rs``'s data through read-only views (microseconds)."""
    from globeview.lod.render_set import RenderSet  # deferred (heavy), as in `select`

    return RenderSet(
        keys=_frozen(rs.keys),
        variant_ids=_frozen(rs.variant_ids),
        variants=list(rs.variants),
        custom_indices={r: _frozen(i) for r, i in rs.custom_indices.items()},
        error_px=_frozen(rs.error_px),
        stats=dict(rs.stats),
        block_strides=_frozen(rs.block_strides),
        block_tau_px=rs.block_tau_px,
    )


def _failure_reason(host: Any, instance: Any) -> str:
    """The error the host recorded for contribution ``instance`` (its own failure, else its
    plugin's), for the one-line `ProviderUnavailable` message."""
    try:
        plugin, name = host.contribution_of(instance)
        rec = host.get(plugin)
        failure = rec.failures.get(name)
        return (failure.error if failure is not None else rec.error) or "unknown"
    except Exception:  # noqa: BLE001  a host without records: the reason is in the log
        return "unknown (see the log)"


# -- tools -----------------------------------------------------------------------------------
PointerKind = Literal["press", "move", "release", "wheel"]


@dataclass(frozen=True)
class PointerEvent:
    """A mouse/pen event over the globe (the UI translates Qt's events into these).

    Attributes:
        x, y: cursor position in pixels, origin at the top-left of the view.
        kind: 'press', 'move', 'release' or 'wheel'.
        button: the button that changed ('left', 'middle', 'right') for press/release.
        buttons: the buttons held down after the event.
        modifiers: held modifier keys among 'shift', 'ctrl', 'alt', 'meta'.
        wheel_delta: wheel steps (positive away from the user), for 'wheel'.
        picked: ECEF point (m) of the terrain under the cursor, or None (sky).
        lonlat: (lon, lat, height) in degrees and metres of ``picked``, or None. Both are true
            coordinates: the host inverts any active displacement hook.
    """

    x: float
    y: float
    kind: PointerKind
    button: str | None = None
    buttons: frozenset[str] = frozenset()
    modifiers: frozenset[str] = frozenset()
    wheel_delta: float = 0.0
    picked: tuple[float, float, float] | None = None
    lonlat: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class KeyEvent:
    """A key press or release. ``key`` is a name like 'a', 'Escape', 'Left', 'F1'."""

    key: str
    modifiers: frozenset[str] = frozenset()
    kind: Literal["press", "release"] = "press"


@dataclass(frozen=True)
class Marker:
    """An overlay point: ``position`` ECEF (m), drawn as a screen-aligned dot, always on top
    of the terrain (points beyond the horizon are left out).

    ``color`` is RGBA in 0..1; ``size_px`` the dot diameter in pixels; ``label`` optional text
    drawn to the right of the dot (white with a dark shadow, Pillow's bitmap font; at most 80
    characters are shown).
    """

    position: tuple[float, float, float]
    color: tuple[float, float, float, float] = (1.0, 0.2, 0.1, 1.0)
    size_px: float = 8.0
    label: str = ""


@dataclass(frozen=True)
class Polyline:
    """An overlay line through ``points`` (N, 3) ECEF (m) joined by straight segments;
    ``width_px`` in pixels.

    ``depth_test`` (default True): the terrain in front of the line hides it (a straight chord
    between two cities goes behind the globe), with a small pull toward the eye so a line lying
    on the surface stays visible. False: drawn on top of everything (interaction feedback that
    must show through the relief); then only what lies beyond the horizon is left out.
    """

    points: np.ndarray
    color: tuple[float, float, float, float] = (1.0, 0.9, 0.1, 1.0)
    width_px: float = 2.0
    closed: bool = False
    depth_test: bool = True


Overlay = Marker | Polyline


PickStep = Literal["a", "b"]


class TwoPointPick:
    """Picking two points A and B, as a "from A to B" tool does (API 1.3): a left press on
    the terrain sets A, the next one sets B, a third starts a new pair (A again, B dropped);
    Escape clears both. A tool keeps one and forwards its events to it (the built-in measure
    and collapse tools do)::

        class Ruler(Tool):
            def __init__(self, context=None):
                super().__init__(context)
                self.pick = TwoPointPick()

            def on_mouse(self, event):
                step = self.pick.on_mouse(event)  # "a", "b" or None (not consumed)
                if step == "b":
                    km = geodesic_inverse(*self.pick.a, *self.pick.b)[2] / 1000.0
                    self.set_status(f"{km:.1f} km")
                if step is not None:
                    self.request_redraw()
                return step is not None

            def on_key(self, event):
                return self.pick.on_key(event)  # Escape clears A and B

    Attributes:
        a, b: the points picked, (lon, lat) in degrees (the events' ``lonlat``: true
            coordinates, any displacement inverted), or None; a tool may set them itself
            (headless input, `Tool.place_points`).
    """

    def __init__(self) -> None:
        self.a: tuple[float, float] | None = None
        self.b: tuple[float, float] | None = None

    @property
    def state(self) -> Literal["idle", "a_set", "complete"]:
        """'idle' (no point), 'a_set' (A picked, B not yet) or 'complete' (A and B)."""
        if self.a is None:
            return "idle"
        return "a_set" if self.b is None else "complete"

    def clear(self) -> None:
        """Forget both points."""
        self.a = self.b = None

    def on_mouse(
        self,
        event: PointerEvent,
        check: Callable[[tuple[float, float], tuple[float, float]], object] | None = None,
    ) -> PickStep | None:
        """Take a pointer event: a left press with a terrain point (``event.lonlat``) sets A
        when no point or both are set (a new pair: B is dropped) and returns ``"a"``, or sets
        B when only A is and returns ``"b"``. Anything else (a move, a release, another
        button, a press on the sky) changes nothing and returns None: the event is not the
        pick's (return False from ``on_mouse``, navigation gets it).

        ``check(a, b)``, optional, vets a pair before B is set: a ValueError it raises
        propagates, A kept and B unset (the collapse tool refuses near-antipodal points so
        and shows the message)."""
        if event.kind != "press" or event.button != "left" or event.lonlat is None:
            return None
        point = (float(event.lonlat[0]), float(event.lonlat[1]))
        if self.a is None or self.b is not None:
            self.a, self.b = point, None
            return "a"
        if check is not None:
            check(self.a, point)
        self.b = point
        return "b"

    def on_key(self, event: KeyEvent) -> bool:
        """Escape (pressed) clears the points; True when it did, False when there were none
        or it is another key (then the host's Escape leaves the tool)."""
        if event.kind == "press" and event.key == "Escape" and self.a is not None:
            self.clear()
            return True
        return False


class Tool(_Contribution):
    """An interactive tool: the active tool sees pointer and key events before navigation.

    Event handlers return True when they consumed the event (navigation then ignores it).
    ``overlay`` is asked for its primitives each frame, ``animate`` for its animation step
    before it, and ``plot`` for the data it publishes after it. A tool picking two points
    keeps a `TwoPointPick`.

    Displacement hook: a tool may move the terrain's vertices on the GPU. It returns GLSL
    source from ``displacement_glsl`` defining exactly this function::

        vec3 gv_displace(vec3 rel_to_eye, vec3 up, float h, vec3 tile_center_rel);

    - ``rel_to_eye``: the vertex position relative to the eye, ECEF axes, metres (float32;
      relative-to-eye keeps precision at globe scale).
    - ``up``: unit ellipsoid normal at the vertex (ECEF axes).
    - ``h``: the vertex's height above the ellipsoid, metres, after exaggeration.
    - ``tile_center_rel``: the tile's ENU origin relative to the eye (ECEF axes, m).
    - returns the displaced position, relative to the eye (same frame and units).

    The source may declare its own ``uniform`` variables; their names must start with
    ``gv_u_`` and their values come from ``displacement_uniforms(view)`` each frame (floats or
    tuples of 2-4 floats; positions should be given relative to ``view.eye`` so they fit
    float32). ``displacement_numpy`` applies the same mapping on the CPU to ECEF points; the
    host uses it for picking (inverting by fixed-point iteration) and overlays. A source
    that fails to compile disables the tool's plugin (reported, not fatal).

    LOD providers refine tiles where the displacement bends straight triangle edges (a kink
    would open cracks between tiles drawn at different strides). By default the host measures
    that bend exactly (`culling.displacement_chord_error_m`: three displacements of every
    candidate tile's bounding lattice, every frame); a tool that knows where its map is
    (nearly) rigid overrides ``displacement_bend_m`` with a cheap conservative bound.
    """

    def request_redraw(self) -> None:
        """Ask the host for a new frame (the overlay or displacement changed). A no-op when
        the tool was made without a context or the host's hooks lack the method."""
        hook = getattr(getattr(self.context, "renderer", None), "request_redraw", None)
        if callable(hook):
            hook()

    def set_status(self, text: str) -> None:
        """Show one line in the host's status bar (headless: kept by `NullRendererHooks`);
        a no-op without a context, as `request_redraw`."""
        hook = getattr(getattr(self.context, "renderer", None), "set_status", None)
        if callable(hook):
            hook(text)

    def on_mouse(self, event: PointerEvent) -> bool:
        """Handle a pointer event; True when consumed."""
        return False

    def on_key(self, event: KeyEvent) -> bool:
        """Handle a key event; True when consumed."""
        return False

    def place_points(self, points: Sequence[tuple[float, float]]) -> bool:
        """Headless input (``globeview render --tool NAME --points ...``): the points
        (lon, lat) in degrees a user would click, in order. Return True when the tool took
        them (e.g. set its state at once, with no animation: a headless frame has no time);
        False (the default) and the host clicks them instead: a left press and release
        `PointerEvent` at each point's pixel, ``lonlat`` and ``picked`` on the terrain.
        Raise `globeview.errors.GlobeviewError` (one line) for points the tool refuses."""
        return False

    def overlay(self, view: ViewState) -> list[Overlay]:
        """Overlay primitives (ECEF) to draw over the terrain this frame."""
        return []

    def displacement_glsl(self) -> str | None:
        """GLSL source defining ``gv_displace`` (see the class docstring), or None."""
        return None

    def displacement_uniforms(self, view: ViewState) -> dict[str, float | tuple[float, ...]]:
        """Values of the ``gv_u_*`` uniforms the GLSL source declares, for this frame."""
        return {}

    def displacement_numpy(self, points_ecef: np.ndarray) -> np.ndarray:
        """The displacement applied to (N, 3) ECEF points (m) on the CPU; identity by default."""
        return np.asarray(points_ecef, dtype=np.float64)

    def displacement_inverse_numpy(self, points_ecef: np.ndarray) -> np.ndarray:
        """The inverse of ``displacement_numpy``: maps drawn (displaced) ECEF points back to
        the true ones, so picks report real coordinates. Identity by default."""
        return np.asarray(points_ecef, dtype=np.float64)

    def displacement_key(self) -> object | None:
        """Optional: a hashable summary of the current displacement (e.g. the collapse's
        points and ratio); equal keys promise the same ``displacement_numpy``, so LOD
        providers may cache displaced tile data across frames under it (``ViewState.
        displacement_key``). None (the default): providers fingerprint the displacement."""
        return None

    def displacement_bend_m(
        self, points_ecef: np.ndarray, displaced: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Optional: an upper bound (m) of how far ``displacement_numpy`` bends straight edges
        over tile bounding lattices ``points_ecef`` (N, K, 3) true ECEF (2 heights x L x L,
        `culling.tile_bounding_points`), per tile (N,): it must be >=
        ``culling.displacement_chord_error_m(displacement_numpy, points_ecef)``, and should be
        (near) zero where the map is (nearly) rigid. ``displaced`` is
        ``displacement_numpy(points_ecef)`` when the provider already has it. The host uses
        it only if a tool overrides this method; returning None falls back to the exact
        measure."""
        return None

    def animate(self, now_s: float) -> bool:
        """Advance the tool's animation to time ``now_s`` (API 1.3 declares it; the host
        called it before). Returns True while it moves (another frame is wanted), False
        (the default) when nothing does.

        Called by the host once per frame drawn while the tool is active, before the frame's
        view is built, so the frame's displacement, uniforms and overlay all see the state
        at ``now_s``: seconds on a steady clock, of which only differences mean anything
        (the first call after an animation starts may fix its origin). In the window, True
        keeps frames coming about every 16 ms; the host draws a frame only when asked, so
        call `request_redraw` when an animation starts. A headless frame (``render``) has no
        time: `place_points` should set the final state at once. Raising, or returning
        something that is not a truth value, fails the tool (one line)."""
        return False

    def plot(self) -> Plot | None:
        """The `Plot` this tool publishes now (curves, and the table its CSV export
        writes), or None (the default): nothing to show (API 1.3 declares it; a tool could
        define it since 1.1).

        The host asks the active tool after every frame and when the tool changes
        (`globeview.app.tool_host.ToolHost.plot`): the window shows it in its Plot dock with
        Export CSV..., ``render --tool-csv FILE`` writes its table, a script reads
        ``session.tool_plot()``. Return the *same* object while nothing changed (the dock
        redraws only for a new one) and None to clear the dock. Units are the tool's, named
        in the axis labels. Anything but a `Plot` or None fails the tool (one line)."""
        return None

    def deactivate(self) -> None:
        """Called when the tool stops being the active tool (drop transient state)."""


# -- layer types -----------------------------------------------------------------------------
class LayerType(_Contribution):
    """A kind of layer the user can open from a file.

    Like every contribution it has ``name``, ``label`` (the open dialog's filter text),
    ``settings`` and ``configure(values)`` (values in ``self.values``: e.g. a default line
    width for the layers it opens; the host applies the stored values when it creates the
    layer type and persists changes). Subclassing is optional: any object with ``open`` is
    accepted (``configure`` is then called only if it has one).

    Attributes:
        extensions: lower-case file suffixes it opens, with the dot (e.g. ``(".gpx",)``).

    Optional ``sniff(path) -> bool``: whether a file is this type's, by content. File dispatch
    (`globeview.app.layer_dispatch`) asks it when several types claim a file's extension,
    and asks every type that has one when none claims it; a type without ``sniff`` takes every
    file with its extensions. Raise `GlobeviewError` for a file of your format that is broken.
    """

    extensions: tuple[str, ...] = ()

    def open(self, path: str) -> Any:
        """Open ``path`` and return the layer object for the scene.

        Raise `globeview.errors.GlobeviewError` with a one-line message for bad input.
        """
        raise NotImplementedError
