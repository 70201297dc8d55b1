"""A globeview project file: the schema, its reader (checked) and its writer (issue #26).

A project is a TOML file a person can read and edit::

    schema = 1                       # this reader refuses a newer one in one line
    [camera]                         # lon/lat degrees (WGS84), height m above the ellipsoid,
    lon = -71.3                      # heading/pitch/roll degrees, fov the vertical field of
    lat = 44.27                      # view in degrees
    height = 12000.0
    [lod]                            # the LOD provider, tau (pixels) and its settings
    provider = "chunked-sse"
    tau_px = 2.0
    [lod.settings]
    [display]                        # exaggeration, wireframe, hillshade, fog, background
    [tool]                           # optional: the active tool, its settings and points
    [[dems]]                         # bottom first: name, path | url | embedded, visible,
    path = "data/N44W072.hgt"        # crs and vdatum as the DEM was opened with
    [[overlays]]                     # bottom first: name, path | embedded, type, visible,
    path = "roads.geojson"           # opacity (drapes), [overlays.style], and optional
                                     # [overlays.open]: what the layer type opened the file
                                     # with (a GIS file's layer, color_by, label, width_px)
    [[bookmarks]]                    # name + camera
    [[tours]]                        # optional: name + [[tours.keyframes]] (model/tour.py's
                                     # form; checked when a globe opens it, app/project.py)

Paths are relative to the project file (``/`` separated; ``..`` allowed); an absolute path,
one that is missing or of the wrong kind is a problem of that layer only (`resolve_path`),
reported while the rest opens. Everything else is checked when read: one `ProjectError`
line naming the key for a file that is not a project, a newer schema, an unknown key or a
bad value (NaN camera, an opacity outside 0..1...). Plugin names and settings are checked
against the installed plugins by the application (`globeview.app.project`). Nothing here
knows Qt, GL or the plugins.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from globeview.errors import GlobeviewError
from globeview.model.bookmarks import Bookmark
from globeview.model.camera import FOV_RANGE_DEG, check_lonlat_hpr
from globeview.model.overlay_layers import style_problem
from globeview.validate import check_exaggeration, check_tau

__all__ = [
    "PROJECT_SUFFIX",
    "SCHEMA",
    "CameraSpec",
    "DemSpec",
    "OverlaySpec",
    "Project",
    "ProjectError",
    "ToolSpec",
    "is_project_path",
    "parse_project",
    "project_text",
    "read_project",
    "resolve_path",
]

#: The suffix a project file has (``globeview PROJECT.toml`` tells projects apart by it).
PROJECT_SUFFIX = ".toml"
#: The schema version this globeview writes and the newest it reads.
SCHEMA = 1
#: The schema versions this reader reads.
SCHEMAS_READ = (1,)
#: Largest project file read (bytes): a project is a page of text, not a data set.
MAX_BYTES = 8 << 20
#: Most layers, bookmarks and tool points a project may hold.
MAX_ITEMS = 10_000
#: Sources a DEM layer may name (one of them), and an overlay.
DEM_SOURCES = ("path", "url", "embedded")
OVERLAY_SOURCES = ("path", "embedded")


def is_project_path(text: str | os.PathLike[str]) -> bool:
    """Whether a command-line argument names a project file (by its ``.toml`` suffix)."""
    return Path(text).suffix.lower() == PROJECT_SUFFIX


class ProjectError(GlobeviewError):
    """A project file that cannot be read: one line naming the file and the key."""


@dataclass(frozen=True)
class CameraSpec:
    """A camera: lon/lat degrees (WGS84), height metres above the ellipsoid, heading (from
    north, clockwise), pitch (-90: straight down) and roll in degrees, vertical fov degrees."""

    lon: float
    lat: float
    height: float
    heading: float = 0.0
    pitch: float = -90.0
    roll: float = 0.0
    fov: float = 45.0

    @property
    def pose(self) -> tuple[float, float, float, float, float, float]:
        return (self.lon, self.lat, self.height, self.heading, self.pitch, self.roll)


@dataclass(frozen=True)
class DemSpec:
    """A DEM layer: ``kind`` "path" (a DEM file or store folder, relative to the project),
    "url" (a store URL) or "embedded" (a DEM globeview ships, by file name), with the
    ``crs`` and ``vdatum`` it was opened with (None: the file's own)."""

    name: str
    kind: str
    source: str
    visible: bool = True
    crs: str | None = None
    vdatum: str | None = None


@dataclass(frozen=True)
class OverlaySpec:
    """An overlay layer: ``kind`` "path" (relative to the project) or "embedded", the layer
    type that opened it, visibility, opacity 0..1 (drapes; None: the layer's own), style
    (the layer's style fields: colour RGBA 0..1, widths in pixels...) and ``open``: the
    options its layer type opened the file with (the ``gis`` type's ``layer``, ``color_by``,
    ``label``, ``width_px``...; checked by the layer type when the project is opened, so a
    bad one is a problem of that layer only)."""

    name: str
    kind: str
    source: str
    layer_type: str | None = None
    visible: bool = True
    opacity: float | None = None
    style: dict[str, Any] = field(default_factory=dict)
    open: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class ToolSpec:
    """The active tool: its name, its setting values and the points (lon, lat degrees) it
    was given (the collapse and measure tools' A and B)."""

    name: str
    settings: dict[str, Any] = field(default_factory=dict)
    points: tuple[tuple[float, float], ...] = ()


@dataclass
class Project:
    """Everything a project file holds, checked (see the module docstring)."""

    camera: CameraSpec
    lod: str = "chunked-sse"
    tau_px: float = 2.0
    lod_settings: dict[str, Any] = field(default_factory=dict)
    display: dict[str, Any] = field(default_factory=dict)
    tool: ToolSpec | None = None
    dems: list[DemSpec] = field(default_factory=list)
    overlays: list[OverlaySpec] = field(default_factory=list)
    bookmarks: list[Bookmark] = field(default_factory=list)
    #: Tours (issue #26 item 5) in `globeview.model.tour.tour_to_dict`'s form, kept as read
    #: here and checked per tour when a globe opens them (`globeview.app.project`).
    tours: list[dict[str, Any]] = field(default_factory=list)


# -- reading -----------------------------------------------------------------------------------
def read_project(path: str | os.PathLike[str]) -> Project:
    """The project in the file ``path``; one `ProjectError` line if it is not one."""
    p = Path(path)
    try:
        if p.is_dir():
            raise ProjectError(f"{p} is a directory, not a project file")
        if p.exists() and not p.is_file():  # a FIFO or a device would block or never end
            raise ProjectError(f"{p} is not a regular file, not a project file")
        size = p.stat().st_size
        if size > MAX_BYTES:
            raise ProjectError(f"{p} is {size} bytes: not a project file (at most {MAX_BYTES})")
        data = p.read_bytes()
    except OSError as exc:
        raise ProjectError(f"cannot read project {p}: {exc.strerror or exc}") from None
    return parse_project(data, str(p))


def parse_project(data: bytes | str, label: str = "project") -> Project:
    """A checked `Project` from a file's bytes (``label`` names it in errors)."""
    try:
        text = data.decode("utf-8") if isinstance(data, bytes) else data
        raw = tomllib.loads(text)
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ProjectError(f"{label} is not a globeview project (not TOML: {first})") from None
    if "schema" not in raw:
        raise ProjectError(f"{label} is not a globeview project (no `schema = 1` line)")
    schema = raw["schema"]
    if isinstance(schema, bool) or not isinstance(schema, int):
        raise ProjectError(f"{label}: schema must be a whole number, not {schema!r:.40}")
    if schema not in SCHEMAS_READ:
        newer = "a newer globeview" if schema > SCHEMA else "an unknown version"
        raise ProjectError(
            f"{label} has project schema {schema}, from {newer}; this globeview reads "
            f"schema {', '.join(map(str, SCHEMAS_READ))}"
        )
    try:
        return _project(raw)
    except ValueError as exc:
        raise ProjectError(f"{label}: {exc}") from None


def _project(raw: dict[str, Any]) -> Project:
    keys = ("schema", "generator", "camera", "lod", "display", "tool")
    _keys(raw, "", (*keys, "dems", "overlays", "bookmarks", "tours"))
    lod = _table(raw, "lod")
    _keys(lod, "lod.", ("provider", "tau_px", "settings"))
    return Project(
        camera=_camera(_table(raw, "camera", required=True), "camera."),
        lod=_text(lod.get("provider", "chunked-sse"), "lod.provider"),
        tau_px=_checked("lod.tau_px", check_tau, lod.get("tau_px", 2.0)),
        lod_settings=_settings(lod.get("settings", {}), "lod.settings"),
        display=_display(_table(raw, "display")),
        tool=_tool(raw["tool"]) if "tool" in raw else None,
        dems=[_dem(t, f"dems[{i}].") for i, t in enumerate(_array(raw, "dems"))],
        overlays=[_overlay(t, f"overlays[{i}].") for i, t in enumerate(_array(raw, "overlays"))],
        bookmarks=_bookmarks(_array(raw, "bookmarks")),
        tours=[dict(t) for t in _array(raw, "tours")],
    )


def _keys(table: dict[str, Any], where: str, allowed: tuple[str, ...]) -> None:
    unknown = [k for k in table if k not in allowed]
    if unknown:
        raise ValueError(f"unknown key {where}{unknown[0]} (known: {', '.join(allowed)})")


def _table(raw: dict[str, Any], key: str, required: bool = False) -> dict[str, Any]:
    value = raw.get(key)
    if value is None:
        if required:
            raise ValueError(f"no [{key}] table")
        return {}
    if not isinstance(value, dict):
        raise ValueError(f"{key} must be a table, not {type(value).__name__}")
    return value


def _array(raw: dict[str, Any], key: str) -> list[dict[str, Any]]:
    value = raw.get(key, [])
    if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
        raise ValueError(f"{key} must be an array of tables ([[{key}]])")
    if len(value) > MAX_ITEMS:
        raise ValueError(f"{key} holds {len(value)} entries (at most {MAX_ITEMS})")
    return value


def _checked(key: str, check: Callable[[Any], Any], value: Any) -> Any:
    try:
        return check(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{key}: {exc}") from None


def _number(value: Any, key: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{key} must be a number, not {value!r:.40}")
    v = float(value)
    if not math.isfinite(v) or not lo <= v <= hi:
        span = f" in {lo:g}..{hi:g}" if math.isfinite(lo) or math.isfinite(hi) else ""
        raise ValueError(f"{key} = {v!r} must be a finite number{span}")
    return v


def _bool(value: Any, key: str) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{key} must be true or false, not {value!r:.40}")
    return value


def _text(value: Any, key: str, limit: int = 4096) -> str:
    if not isinstance(value, str) or not value.strip() or len(value) > limit:
        raise ValueError(f"{key} must be non-empty text of at most {limit} characters")
    if any(c in value for c in "\r\n\0"):
        raise ValueError(f"{key} must be one line")
    return value


def _camera(t: dict[str, Any], where: str) -> CameraSpec:
    names = ("lon", "lat", "height", "heading", "pitch", "roll")
    _keys(t, where, (*names, "fov"))
    defaults = {"heading": 0.0, "pitch": -90.0, "roll": 0.0}
    missing = [k for k in ("lon", "lat", "height") if k not in t]
    if missing:
        raise ValueError(f"no {where}{missing[0]}")
    values = [_number(t.get(k, defaults.get(k)), f"{where}{k}") for k in names]
    pose = _checked(where.rstrip("."), lambda v: check_lonlat_hpr(*v), values)
    fov = _number(t.get("fov", 45.0), f"{where}fov", *FOV_RANGE_DEG)
    lon, lat, height, heading, pitch, roll = pose
    return CameraSpec(lon, lat, height, heading, pitch, roll, fov)


def _settings(value: Any, key: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ValueError(f"{key} must be a table")
    for k, v in value.items():
        if isinstance(v, (dict, list)) or (isinstance(v, float) and not math.isfinite(v)):
            raise ValueError(f"{key}.{k} must be a finite number, true/false or text")
    return dict(value)


def _display(t: dict[str, Any]) -> dict[str, Any]:
    _keys(t, "display.", ("exaggeration", "wireframe", "hillshade", "fog", "background"))
    out: dict[str, Any] = {}
    if "exaggeration" in t:
        value = t["exaggeration"]
        out["exaggeration"] = _checked("display.exaggeration", check_exaggeration, value)
    for k in ("wireframe", "hillshade", "fog"):
        if k in t:
            out[k] = _bool(t[k], f"display.{k}")
    if "background" in t:
        bg = t["background"]
        if not isinstance(bg, list) or len(bg) != 3:
            raise ValueError("display.background must be [R, G, B] in 0..1")
        out["background"] = tuple(_number(c, "display.background", 0.0, 1.0) for c in bg)
    return out


def _points(value: Any, key: str) -> tuple[tuple[float, float], ...]:
    if not isinstance(value, list) or len(value) > MAX_ITEMS:
        raise ValueError(f"{key} must be a list of [lon, lat] pairs")
    out = []
    for p in value:
        if not isinstance(p, list) or len(p) != 2:
            raise ValueError(f"{key} must be a list of [lon, lat] pairs")
        out.append((_number(p[0], f"{key} lon"), _number(p[1], f"{key} lat", -90.0, 90.0)))
    return tuple(out)


def _tool(value: Any) -> ToolSpec:
    if not isinstance(value, dict):
        raise ValueError("tool must be a table")
    _keys(value, "tool.", ("name", "settings", "points"))
    return ToolSpec(
        name=_text(value.get("name"), "tool.name", 200),
        settings=_settings(value.get("settings", {}), "tool.settings"),
        points=_points(value.get("points", []), "tool.points"),
    )


def _source(t: dict[str, Any], where: str, kinds: tuple[str, ...]) -> tuple[str, str]:
    given = [k for k in kinds if k in t]
    if len(given) != 1:
        raise ValueError(f"{where.rstrip('.')} needs exactly one of {', '.join(kinds)}")
    kind = given[0]
    return kind, _text(t[kind], f"{where}{kind}")


def _dem(t: dict[str, Any], where: str) -> DemSpec:
    _keys(t, where, ("name", *DEM_SOURCES, "visible", "crs", "vdatum"))
    kind, source = _source(t, where, DEM_SOURCES)
    return DemSpec(
        name=_text(t.get("name", Path(source).stem or "dem"), f"{where}name", 200),
        kind=kind,
        source=source,
        visible=_bool(t.get("visible", True), f"{where}visible"),
        crs=_text(t["crs"], f"{where}crs") if "crs" in t else None,
        vdatum=_text(t["vdatum"], f"{where}vdatum", 40) if "vdatum" in t else None,
    )


def _overlay(t: dict[str, Any], where: str) -> OverlaySpec:
    _keys(t, where, ("name", *OVERLAY_SOURCES, "type", "visible", "opacity", "style", "open"))
    kind, source = _source(t, where, OVERLAY_SOURCES)
    style = t.get("style", {})
    if not isinstance(style, dict):
        raise ValueError(f"{where}style must be a table")
    for k, v in style.items():
        problem = style_problem(k, tuple(v) if isinstance(v, list) else v)
        if problem is not None:
            raise ValueError(f"{where}style: {problem}")
    return OverlaySpec(
        name=_text(t.get("name", Path(source).name), f"{where}name", 200),
        kind=kind,
        source=source,
        layer_type=_text(t["type"], f"{where}type", 200) if "type" in t else None,
        visible=_bool(t.get("visible", True), f"{where}visible"),
        opacity=_number(t["opacity"], f"{where}opacity", 0.0, 1.0) if "opacity" in t else None,
        style={k: tuple(v) if isinstance(v, list) else v for k, v in style.items()},
        open=_open_options(t.get("open", {}), f"{where}open"),
    )


#: Most options an overlay's ``open`` table holds.
MAX_OPEN_OPTIONS = 32


def _open_options(value: Any, key: str) -> dict[str, Any]:
    """An overlay's ``open`` table: option names to text, true/false, numbers or lists of
    numbers. Only the shape is checked here; the values (a field the file lacks, a NaN
    width) are the layer type's to refuse, as a problem of that layer
    (`globeview.app.project`)."""
    if not isinstance(value, dict) or len(value) > MAX_OPEN_OPTIONS:
        raise ValueError(f"{key} must be a table of at most {MAX_OPEN_OPTIONS} options")
    out: dict[str, Any] = {}
    for k, v in value.items():
        scalar = (bool, int, float, str)
        if isinstance(v, list) and len(v) <= 16 and all(isinstance(x, scalar) for x in v):
            out[k] = tuple(v)
        elif isinstance(v, scalar) and (not isinstance(v, str) or len(v) <= 4096):
            out[k] = v
        else:
            raise ValueError(f"{key}.{k} must be text, true/false, a number or a list of those")
    return out


def _bookmarks(tables: list[dict[str, Any]]) -> list[Bookmark]:
    marks: list[Bookmark] = []
    for i, t in enumerate(tables):
        where = f"bookmarks[{i}]."
        _keys(t, where, ("name", "lon", "lat", "height", "heading", "pitch", "roll"))
        name = _text(t.get("name"), f"{where}name", 200)
        if any(b.name == name for b in marks):
            raise ValueError(f"{where}name {name!r:.60} is used twice")
        cam = _camera({k: v for k, v in t.items() if k != "name"}, where)
        marks.append(Bookmark(name.strip(), cam.pose))
    return marks


# -- paths -------------------------------------------------------------------------------------
def resolve_path(base: Path, text: str, want: str = "file") -> Path:
    """The file a project's relative ``text`` names, from the project's folder ``base``.
    ValueError (one line, for that layer) for an absolute path, one that does not exist,
    and one of the wrong kind (``want``: "file", or "any" for a DEM file or a store
    folder)."""
    rel = Path(text)
    if rel.is_absolute() or text.startswith("~"):
        raise ValueError(f"{text!r:.80} is an absolute path; a project names files relative to it")
    path = base / rel
    if not path.exists():
        raise ValueError(f"{text!r:.80}: no such file (looked in {base})")
    if want == "file" and not path.is_file():
        raise ValueError(f"{text!r:.80} is not a file")
    return path


def relative_path(base: Path, path: str | os.PathLike[str]) -> str:
    """``path`` relative to the folder ``base`` (``..`` where needed), ``/`` separated."""
    rel = os.path.relpath(Path(path).resolve(), base.resolve())
    return Path(rel).as_posix()


# -- writing -----------------------------------------------------------------------------------
def project_text(project: Project, generator: str = "") -> str:
    """The TOML text of ``project`` (paths as they are in it: relative)."""
    import tomli_w

    c = project.camera
    doc: dict[str, Any] = {"schema": SCHEMA}
    if generator:
        doc["generator"] = generator
    doc["camera"] = _pose_table(c.pose) | {"fov": c.fov}
    doc["lod"] = {"provider": project.lod, "tau_px": project.tau_px}
    doc["lod"]["settings"] = dict(project.lod_settings)
    doc["display"] = {k: list(v) if isinstance(v, tuple) else v for k, v in project.display.items()}
    if project.tool is not None:
        t = project.tool
        doc["tool"] = {"name": t.name, "points": [list(p) for p in t.points]}
        doc["tool"]["settings"] = dict(t.settings)
    doc["dems"] = [_dem_table(d) for d in project.dems]
    doc["overlays"] = [_overlay_table(o) for o in project.overlays]
    doc["bookmarks"] = [{"name": b.name} | _pose_table(b.pose) for b in project.bookmarks]
    if project.tours:
        doc["tours"] = project.tours
    header = (
        "# A globeview project (docs/projects.md): paths are relative to this\n"
        "# file; lon/lat in degrees (WGS84), heights in metres above the ellipsoid.\n"
    )
    return header + tomli_w.dumps(doc, multiline_strings=False)


def _pose_table(pose: tuple[float, ...]) -> dict[str, float]:
    names = ("lon", "lat", "height", "heading", "pitch", "roll")
    return {k: float(v) for k, v in zip(names, pose, strict=True)}


def _dem_table(d: DemSpec) -> dict[str, Any]:
    t: dict[str, Any] = {"name": d.name, d.kind: d.source, "visible": d.visible}
    if d.crs is not None:
        t["crs"] = d.crs
    if d.vdatum is not None:
        t["vdatum"] = d.vdatum
    return t


def _overlay_table(o: OverlaySpec) -> dict[str, Any]:
    t: dict[str, Any] = {"name": o.name, o.kind: o.source, "visible": o.visible}
    if o.layer_type is not None:
        t["type"] = o.layer_type
    if o.opacity is not None:
        t["opacity"] = float(o.opacity)
    t["style"] = {k: list(v) if isinstance(v, tuple) else v for k, v in o.style.items()}
    if o.open:
        t["open"] = {k: list(v) if isinstance(v, tuple) else v for k, v in o.open.items()}
    return t
