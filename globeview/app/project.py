"""Projects on a live globe: capture a globe into a `Project`, write it atomically, and apply
a project to a globe (issue #26 item 4). The file format is `globeview.model.project`.

The same functions serve the Python API (`globeview.Globe.save_project`, ``open_project``),
the window (File > Save Project..., Open Project...) and ``globeview render PROJECT.toml``,
so all three see the same globe from one file. No Qt here.

Applying a project checks every plugin name and setting first (`check_plugins`: one
`GlobeviewError` line, the globe unchanged); then each DEM and overlay is opened on its own:
one that is missing, absolute, of the wrong kind or unreadable is reported in one line
(`apply_project` returns the lines) while the rest opens.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from globeview.app.overlay_host import OverlayHost
from globeview.errors import GlobeviewError
from globeview.fileio import atomic_write_text, check_output_file
from globeview.model.bookmarks import Bookmark
from globeview.model.camera import Camera
from globeview.model.globe import Globe as GlobeModel
from globeview.model.project import (
    PROJECT_SUFFIX,
    CameraSpec,
    DemSpec,
    OverlaySpec,
    Project,
    ToolSpec,
    project_text,
    relative_path,
    resolve_path,
)
from globeview.model.tour import TOUR_FORMAT, TOUR_VERSION, Tour, tour_from_dict, tour_to_dict
from globeview.paths import cache_dir
from globeview.plugins.api import PluginKind
from globeview.plugins.registry import PluginRegistry
from globeview.terrain.compose.stack import TerrainLayer
from globeview.terrain.dem.data import EMBEDDED_DATA_DIR
from globeview.terrain.sources import open_source, opened_as
from globeview.terrain.store.tile_store import TileStore

__all__ = [
    "GlobeParts",
    "OpenedDems",
    "apply_project",
    "capture_project",
    "check_plugins",
    "open_dems",
    "project_tour",
    "save_project",
]

#: The layer types whose open options a project keeps (``[overlays.open]``): those that check
#: every option themselves, in one line (`globeview.model.vector_files.read_vector_file`).
OPEN_TYPES = ("gis",)
#: The display settings a project holds.
DISPLAY_FIELDS = ("exaggeration", "wireframe", "hillshade", "fog", "background")


@dataclass(frozen=True)
class GlobeParts:
    """What a project is captured from and applied to: the evented model, the overlay host
    that opens its overlays and the plugin registry that serves its LOD provider and tool,
    and the tour (the API globe's `tour` or the Tour dock's): saved into the project's
    ``[[tours]]`` and replaced in place by an opened project's (None: no tour kept)."""

    model: GlobeModel
    overlays: OverlayHost
    registry: PluginRegistry
    tour: Tour | None = None


# -- capture and save --------------------------------------------------------------------------
def capture_project(parts: GlobeParts, base: Path) -> tuple[Project, list[str]]:
    """The project of the globe now, paths relative to the folder ``base``, and one line per
    layer that a project cannot name (a DEM made from an in-memory array, an overlay a
    plugin drew without a file): those are left out."""
    model = parts.model
    skipped: list[str] = []
    dems = []
    for layer in model.terrain.layers:
        spec = _dem_spec(layer, base)
        if spec is None:
            skipped.append(f"DEM layer {layer.name!r:.60} has no file a project can name")
        else:
            dems.append(spec)
    overlays = []
    for ov in model.overlays:
        ospec = _overlay_spec(parts.overlays, ov, base)
        if ospec is None:
            name = getattr(ov, "name", "?")
            skipped.append(f"overlay {name!r:.60} has no file a project can name")
        else:
            overlays.append(ospec)
    camera = CameraSpec(*_tidy_pose(model.camera.lonlat_hpr()), fov=model.camera.fovy_deg)
    project = Project(
        camera=camera,
        lod=model.lod,
        tau_px=model.tau_px,
        lod_settings=_values(parts.registry.find(PluginKind.LOD, model.lod)),
        display={k: getattr(model.display, k) for k in DISPLAY_FIELDS},
        tool=_tool_spec(parts.registry, model.tool),
        dems=dems,
        overlays=overlays,
        bookmarks=[Bookmark(b.name, _tidy_pose(b.pose)) for b in model.bookmarks],
        tours=_tours(parts.tour),
    )
    return project, skipped


#: The name a tour without one is saved under in a project.
DEFAULT_TOUR_NAME = "Tour"


def _tours(tour: Tour | None) -> list[dict[str, Any]]:
    """The project's ``[[tours]]``: the tour (named) if it has keyframes."""
    if tour is None or not tour.keyframes:
        return []
    return [tour_to_dict(Tour(list(tour.keyframes), tour.name or DEFAULT_TOUR_NAME))]


def save_project(parts: GlobeParts, path: str | os.PathLike[str]) -> list[str]:
    """Write the globe's project to ``path`` (a ``.toml`` file), atomically: a temporary
    file in the same folder replaced into place, so a read-only folder, a full disk or
    Ctrl-C leaves no partial file (one `OutputError` line). Returns the lines of the
    layers left out (`capture_project`)."""
    from globeview import __version__

    out = check_output_file(path, "project", (PROJECT_SUFFIX,))
    project, skipped = capture_project(parts, Path(out).resolve().parent)
    atomic_write_text(out, project_text(project, generator=f"globeview {__version__}"))
    return skipped


def _tidy_pose(pose: tuple[float, ...]) -> tuple[float, float, float, float, float, float]:
    """A camera pose read back from ECEF, without the last bits of rounding noise (angles
    to 1e-10 degree, about 10 micrometres on the ground; heights to a micrometre), so the
    file says 40.0 where the camera was placed at 40 degrees."""
    lon, lat, height, heading, pitch, roll = pose
    heading, roll = round(heading, 10) % 360.0, round(roll, 10) % 360.0
    return round(lon, 10), round(lat, 10), round(height, 6), heading, round(pitch, 10), roll


def _values(contribution: Any) -> dict[str, Any]:
    """A plugin contribution's setting values that TOML can hold (finite numbers, text,
    true/false)."""
    values = dict(getattr(contribution, "values", {}) or {})
    return {
        k: v
        for k, v in values.items()
        if isinstance(v, (bool, int, str)) or (isinstance(v, float) and math.isfinite(v))
    }


def _tool_spec(registry: PluginRegistry, name: str | None) -> ToolSpec | None:
    """The active tool's settings and its points A and B where it exposes them (``a``,
    ``b``: (lon, lat) degrees, as the collapse and measure tools do)."""
    if name is None:
        return None
    tool = registry.find(PluginKind.TOOL, name)
    points: tuple[tuple[float, float], ...] = ()
    a, b = getattr(tool, "a", None), getattr(tool, "b", None)
    if a is not None and b is not None:
        points = ((float(a[0]), float(a[1])), (float(b[0]), float(b[1])))
    return ToolSpec(name, _values(tool), points)


def _embedded_name(path: str) -> str | None:
    """The file name of a path inside globeview's shipped data, else None."""
    p = Path(path).resolve()
    return p.name if p.parent == EMBEDDED_DATA_DIR.resolve() else None


def _dem_spec(layer: TerrainLayer, base: Path) -> DemSpec | None:
    origin = opened_as(layer.store)
    if origin is None:
        return None
    vis, crs, vdatum = layer.visible, origin.crs, origin.vdatum
    if origin.kind == "store" and "://" in origin.text:
        return DemSpec(layer.name, "url", origin.text, vis)
    embedded = _embedded_name(origin.text)
    if embedded is not None:
        return DemSpec(layer.name, "embedded", embedded, vis, crs, vdatum)
    if Path(origin.text).resolve().is_relative_to(cache_dir().resolve()):
        return None  # an array's file in the cache: nothing the project's reader may open
    return DemSpec(layer.name, "path", relative_path(base, origin.text), vis, crs, vdatum)


def _overlay_spec(host: OverlayHost, layer: Any, base: Path) -> OverlaySpec | None:
    origin = host.origins.get(layer)
    if origin is None:
        return None
    path, layer_type = origin
    embedded = _embedded_name(path)
    kind, source = ("embedded", embedded) if embedded else ("path", relative_path(base, path))
    opacity = _opacity(layer)
    fields = getattr(layer, "style_fields", ())
    style = {k: _plain(getattr(layer, k)) for k in fields if hasattr(layer, k)}
    visible = bool(getattr(layer, "visible", True))
    given = host.opened_style(layer) if layer_type in OPEN_TYPES else None
    opened = {k: _plain(v) for k, v in (given or {}).items()}
    return OverlaySpec(
        str(getattr(layer, "name", Path(path).name)),
        kind,
        source,
        layer_type,
        visible,
        opacity,
        {k: v for k, v in style.items() if v is not None},
        {k: tuple(v) if isinstance(v, list) else v for k, v in opened.items() if v is not None},
    )


def _opacity(layer: Any) -> float | None:
    """A drape's opacity 0..1 (a drawn layer's: its first drape part's), else None."""
    inner = getattr(layer, "layer", None)
    if inner is not None and hasattr(inner, "opacity"):
        return float(inner.opacity)
    for part in getattr(layer, "parts", ()):
        if hasattr(part, "set_opacity"):
            return _opacity(part)
    return None


def _plain(value: Any) -> Any:
    """A style value as TOML holds it (tuples as lists of floats), or None if it cannot."""
    if isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)):
        return float(value) if math.isfinite(float(value)) else None
    if isinstance(value, (tuple, list)):
        return [float(v) for v in value]
    return None


# -- apply -------------------------------------------------------------------------------------
def check_plugins(project: Project, registry: PluginRegistry) -> None:
    """The project's LOD provider and tool are enabled and their settings are theirs and
    in range: one `GlobeviewError` line otherwise (checked before anything changes)."""
    from globeview.app.globe import checked_settings
    from globeview.app.lod_host import check_lod_name

    check_lod_name(registry, project.lod)
    provider = registry.find(PluginKind.LOD, project.lod)
    if provider is None:
        why = registry.failure_of(project.lod) or "it did not load"
        raise GlobeviewError(f"LOD provider {project.lod} is not available: {why}")
    checked_settings(project.lod, provider, project.lod_settings)
    if project.tool is not None:
        tool = registry.find(PluginKind.TOOL, project.tool.name)
        if tool is None:
            raise GlobeviewError(f"no enabled tool named {project.tool.name!r:.80}")
        checked_settings(project.tool.name, tool, project.tool.settings)


#: Opens a DEM source as `open_source` does: (text, crs, vdatum) -> TileStore.
OpenDem = Callable[[str, str | None, str | None], TileStore]


def _open_dem(text: str, crs: str | None, vdatum: str | None) -> TileStore:
    return open_source(text, crs=crs, vdatum=vdatum)


@dataclass
class OpenedDems:
    """A project's DEM layers opened (`open_dems`): each spec with its store, and one line
    per layer that could not be opened."""

    stores: list[tuple[DemSpec, TileStore]]
    problems: list[str]


def open_dems(project: Project, base: Path, open_dem: OpenDem = _open_dem) -> OpenedDems:
    """Open (ingest if needed) the project's DEMs, touching no globe: the slow part of
    `apply_project`, which a window runs off its UI thread."""
    problems: list[str] = []
    stores = _open_dems(project.dems, base, open_dem, problems)
    return OpenedDems(stores, problems)


def apply_project(
    project: Project,
    base: Path,
    parts: GlobeParts,
    open_dem: OpenDem = _open_dem,
    opened: OpenedDems | None = None,
) -> list[str]:
    """Make the globe ``parts`` show ``project`` (paths relative to the folder ``base``):
    its DEMs and overlays replace the globe's, then the camera, LOD provider and settings,
    display, tool and bookmarks. Plugin names and settings are checked first
    (`check_plugins`: one line, nothing changes). The DEMs are opened here with
    ``open_dem``, or were opened already (``opened``, from `open_dems`). Returns one line
    per layer that could not be opened (missing, absolute path, not a DEM...); the rest
    opens."""
    registry, model = parts.registry, parts.model
    check_plugins(project, registry)
    if opened is None:
        opened = open_dems(project, base, open_dem)
    problems, stores = list(opened.problems), opened.stores
    for name in dict.fromkeys(ly.name for ly in model.terrain.layers):
        model.terrain.remove(name)
    for spec, store in stores:
        name = _unique(spec.name, [ly.name for ly in model.terrain.layers])
        try:
            model.terrain.add(store, name)
        except GlobeviewError as exc:  # e.g. another tile size than the layers below
            problems.append(f"DEM layer {spec.name!r:.60}: {exc}")
            continue
        if not spec.visible:
            model.terrain.set_visible(name, False)
    for layer in list(model.overlays):
        parts.overlays.remove(layer)
    for ospec in project.overlays:
        problem = _open_overlay(parts.overlays, ospec, base)
        if problem is not None:
            problems.append(f"overlay {ospec.name!r:.60}: {problem}")
    _apply_view(project, parts)
    problem = _apply_tool(project.tool, parts)
    if problem is not None:
        problems.append(problem)
    model.bookmarks.set(project.bookmarks)
    if parts.tour is not None:
        found, lines = project_tour(project)
        parts.tour.keyframes[:] = found.keyframes
        parts.tour.name = found.name
        problems += lines
    return problems


def project_tour(project: Project) -> tuple[Tour, list[str]]:
    """The project's tour (its first ``[[tours]]`` entry that reads; an empty `Tour` if
    none) and one line per ``[[tours]]`` entry that is not opened: a bad keyframe or value
    (`tour_from_dict`'s line), or a tour after the one shown (a globe has one tour)."""
    tours: list[Tour] = []
    problems: list[str] = []
    for i, table in enumerate(project.tours, 1):
        name = table.get("name")
        where = f"tour {name!r:.60}" if isinstance(name, str) and name else f"tour {i}"
        data = {"format": TOUR_FORMAT, "version": TOUR_VERSION} | table
        try:
            tours.append(tour_from_dict(data, where))
        except GlobeviewError as exc:
            problems.append(str(exc))
    for extra in tours[1:]:
        problems.append(f"tour {extra.name!r:.60}: a globe shows one tour; left out")
    return (tours[0] if tours else Tour()), problems


def _unique(name: str, taken: list[str]) -> str:
    """``name``, or ``name (2)``, ``name (3)``... if a layer has it (as File > Open names
    layers), so showing or hiding one layer never touches another."""
    unique, n = name, 2
    while unique in taken:
        unique, n = f"{name} ({n})", n + 1
    return unique


def _open_dems(
    specs: list[DemSpec], base: Path, open_dem: OpenDem, problems: list[str]
) -> list[tuple[DemSpec, TileStore]]:
    """Each DEM layer's store; a layer that cannot be opened is one line in ``problems``."""
    out = []
    for spec in specs:
        try:
            text = _dem_text(spec, base)
            out.append((spec, open_dem(text, spec.crs, spec.vdatum)))
        except (GlobeviewError, ValueError) as exc:
            problems.append(f"DEM layer {spec.name!r:.60}: {exc}")
        except OSError as exc:  # e.g. a file that cannot be read (permissions, I/O)
            problems.append(f"DEM layer {spec.name!r:.60}: {exc.strerror or exc}")
    return out


def _dem_text(spec: DemSpec, base: Path) -> str:
    """What `open_source` is given for a DEM layer (ValueError: the layer's problem)."""
    if spec.kind == "url":
        return spec.source
    if spec.kind == "embedded":
        return str(_embedded_file(spec.source))
    return str(resolve_path(base, spec.source, want="any"))


def _embedded_file(name: str) -> Path:
    """A file globeview ships, by its bare name (ValueError for anything else)."""
    path = EMBEDDED_DATA_DIR / name
    if Path(name).name != name or not path.is_file():
        raise ValueError(f"{name!r:.80} is not a file globeview ships")
    return path


def _open_overlay(host: OverlayHost, spec: OverlaySpec, base: Path) -> str | None:
    """Open one overlay with its visibility, opacity and style; its problem, or None."""
    try:
        if spec.kind == "embedded":
            path = _embedded_file(spec.source)
        else:
            path = resolve_path(base, spec.source)
        if spec.open:
            _check_open_options(spec.open, host.layer_type_for(str(path), spec.layer_type))
        layer = host.open(str(path), spec.layer_type, **spec.open)
    except (GlobeviewError, ValueError) as exc:
        return str(exc)
    except OSError as exc:
        return str(exc.strerror or exc)
    try:
        _style(layer, spec)
    except (TypeError, ValueError) as exc:
        host.remove(layer)
        return str(exc)
    return None


def _check_open_options(options: dict[str, Any], layer_type: str) -> None:
    """An overlay's ``open`` options are for a layer type that checks them itself (the
    ``gis`` type: an unknown option or field is its one line) and within the host's limits
    on style values (a NaN or huge ``width_px``, a colour that is not 3 or 4 numbers):
    ValueError, that layer's problem, before the layer type sees them, so a hostile project
    never fails a layer type."""
    from globeview.model.overlay_layers import style_problem

    if layer_type not in OPEN_TYPES:
        raise ValueError(
            f"open options are for the {', '.join(OPEN_TYPES)} layer type; "
            f"this file opens as {layer_type}"
        )
    for k, v in options.items():
        problem = style_problem(k, v)
        if problem is not None:
            raise ValueError(problem)


def _style(layer: Any, spec: OverlaySpec) -> None:
    """Set the overlay's saved style (only what differs from the file's own, so per-point
    colours and sizes a file gives stay), opacity and visibility."""
    changed = {k: v for k, v in spec.style.items() if getattr(layer, k, None) != v}
    if changed:
        if not hasattr(layer, "set_style"):
            raise ValueError(f"the layer has no style {next(iter(changed))!r}")
        layer.set_style(**changed)
    if spec.opacity is not None and hasattr(layer, "set_opacity"):
        layer.set_opacity(spec.opacity)
    if not spec.visible:
        layer.set_visible(False)


def _apply_view(project: Project, parts: GlobeParts) -> None:
    """Camera, LOD provider with its settings, tau and display settings (all checked)."""
    model, registry = parts.model, parts.registry
    c = project.camera
    camera = Camera.from_lonlat(*c.pose, fovy_deg=c.fov)
    model.camera = camera
    registry.attach(camera=camera)
    provider = registry.find(PluginKind.LOD, project.lod)
    if project.lod_settings:
        from globeview.app.globe import checked_settings

        values = checked_settings(project.lod, provider, project.lod_settings)
        registry.invoke(provider, "configure", values)
    model.lod = project.lod
    model.tau_px = project.tau_px
    for key, value in project.display.items():
        setattr(model.display, key, value)


def _apply_tool(spec: ToolSpec | None, parts: GlobeParts) -> str | None:
    """Activate the project's tool with its settings and give it its points; a line if the
    tool refused them (the rest of the project stands)."""
    model, registry = parts.model, parts.registry
    model.tool = None if spec is None else spec.name
    if spec is None:
        return None
    from globeview.app.globe import checked_settings

    tool = registry.find(PluginKind.TOOL, spec.name)
    if spec.settings:
        registry.invoke(tool, "configure", checked_settings(spec.name, tool, spec.settings))
    if spec.points and callable(getattr(tool, "place_points", None)):
        failed = object()
        try:
            got = registry.invoke(
                tool, "place_points", list(spec.points), default=failed, user_errors=True
            )
        except GlobeviewError as exc:
            return f"tool {spec.name}: {exc}"
        if got is failed:
            why = registry.failure_of(spec.name, PluginKind.TOOL) or "it failed"
            return f"tool {spec.name}: its points were not taken ({why})"
    return None
