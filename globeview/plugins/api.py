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
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import MutableMapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import numpy as np

from globeview.errors import GlobeviewError
from globeview.plugins.geo import (
    TerrainSample,
    ecef_to_lonlat,
    geodesic_direct,
    geodesic_inverse,
    geodesic_samples,
    lonlat_to_ecef,
    sample_terrain,
)
from globeview.plugins.tool_output import Plot, read_csv_columns

if TYPE_CHECKING:
    from globeview.render.render_set import RenderSet
    from globeview.render.view_state import ViewState

__all__ = [
    "API_VERSION",
    "GlobeviewError",
    "KeyEvent",
    "LayerType",
    "LodProvider",
    "Marker",
    "Overlay",
    "Plot",
    "PluginContext",
    "PluginKind",
    "PointerEvent",
    "Polyline",
    "RendererHooks",
    "Setting",
    "TerrainSample",
    "Tool",
    "ecef_to_lonlat",
    "geodesic_direct",
    "geodesic_inverse",
    "geodesic_samples",
    "lonlat_to_ecef",
    "read_csv_columns",
    "sample_terrain",
]

#: The plugin API version this host implements ("MAJOR.MINOR").
API_VERSION = "1.0"


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
            (`globeview.terrain.stack.TerrainStack`), or None.
        camera: the `globeview.render.camera.Camera` (ECEF, float64), or None.
        renderer: `RendererHooks`.
        settings: this plugin's persisted settings, a mutable mapping of JSON-able values
            (writes persist at once).
        logger: ``logging.getLogger("globeview.plugins.<name>")``.

    The host may replace ``scene``, ``terrain`` and ``camera`` when the user opens data; a
    plugin should read them from the context when it needs them rather than keep copies.
    """

    name: str
    scene: Any = None
    terrain: Any = None
    camera: Any = None
    renderer: RendererHooks = field(default_factory=NullRendererHooks)
    settings: MutableMapping[str, Any] = field(default_factory=dict)
    logger: logging.Logger = field(default_factory=lambda: logging.getLogger("globeview.plugins"))


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
    (``plugins/budget_ms``, 250 ms): a malformed render set, or too many overruns in a row
    in the window, disables the provider's plugin and the frame falls back to chunked-sse.
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
    """An overlay point: ``position`` ECEF (m), drawn as a screen-aligned dot.

    ``color`` is RGBA in 0..1; ``size_px`` the dot diameter in pixels; ``label`` optional text.
    """

    position: tuple[float, float, float]
    color: tuple[float, float, float, float] = (1.0, 0.2, 0.1, 1.0)
    size_px: float = 8.0
    label: str = ""


@dataclass(frozen=True)
class Polyline:
    """An overlay line through ``points`` (N, 3) ECEF (m); ``width_px`` in pixels."""

    points: np.ndarray
    color: tuple[float, float, float, float] = (1.0, 0.9, 0.1, 1.0)
    width_px: float = 2.0
    closed: bool = False


Overlay = Marker | Polyline


class Tool(_Contribution):
    """An interactive tool: the active tool sees pointer and key events before navigation.

    Event handlers return True when they consumed the event (navigation then ignores it).
    ``overlay`` is asked for its primitives each frame.

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

    def on_mouse(self, event: PointerEvent) -> bool:
        """Handle a pointer event; True when consumed."""
        return False

    def on_key(self, event: KeyEvent) -> bool:
        """Handle a key event; True when consumed."""
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

    def deactivate(self) -> None:
        """Called when the tool stops being the active tool (drop transient state)."""


# -- layer types -----------------------------------------------------------------------------
@runtime_checkable
class LayerType(Protocol):
    """A kind of layer the user can open from a file.

    Attributes:
        name: unique among layer types.
        label: text for the open dialog's filter.
        extensions: lower-case file suffixes it opens, with the dot (e.g. ``(".gpx",)``).
    """

    name: str
    label: str
    extensions: tuple[str, ...]

    def open(self, path: str) -> Any:
        """Open ``path`` and return the layer object for the scene.

        Raise `globeview.errors.GlobeviewError` with a one-line message for bad input.
        """
        ...
