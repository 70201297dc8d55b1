"""Project files on the command line (issue #26 item 4): ``globeview PROJECT.toml`` opens
the window on a project, ``globeview render PROJECT.toml -o out.png`` draws it headless.

A project is told apart by its ``.toml`` suffix (`globeview.model.project.is_project_path`).
It is read and checked, plugins included, before any window or GL exists: a file that is not
a project, of a newer schema, or with a bad value, an unknown LOD provider or setting is one
``globeview: error:`` line (exit 2). ``render`` draws through the Python API's
`globeview.Globe` (`Globe.open_project`, then `Globe.save`), so its picture is the API's.
A layer whose file is missing is one ``globeview: warning:`` line and the rest is drawn;
``--strict`` refuses instead (exit 2, nothing written).

Like the subcommand modules, this imports only argparse at top level.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

#: ``render`` options a project sets itself (its file says them), and their defaults: given
#: with a project they are refused, not silently overridden.
_RENDER_DEFAULTS: dict[str, object] = {
    "camera": None,
    "lod": "chunked-sse",
    "tool": None,
    "set_values": [],
    "layer": [],
    "points": None,
    "point": [],
    "collapse": None,
    "tool_csv": None,
    "stats": None,
    "fov": 45.0,
    "tau": 2.0,
    "exaggeration": 1.0,
    "wireframe": False,
    "hillshade": False,
    "no_fog": False,
    "background": None,
    "imagery": False,
    "no_borders": False,
    "crs": None,
    "vdatum": None,
}

#: The window's options that a project sets itself.
_GUI_DEFAULTS: dict[str, object] = {"camera": None, "lod": None, "tool": None, "set_values": []}


def project_argument(files: Sequence[str]) -> str | None:
    """The project file among command-line ``files`` (None when there is none); one
    `GlobeviewError` line when a project is given with other files."""
    from globeview.errors import GlobeviewError
    from globeview.model.project import is_project_path

    projects = [f for f in files if is_project_path(f)]
    if not projects:
        return None
    if len(files) > 1:
        raise GlobeviewError(
            f"a project opens alone: {projects[0]} was given with {len(files) - 1} other "
            "file(s); add them to the project in the window, or open them without it"
        )
    return projects[0]


def refuse_options(args: argparse.Namespace, defaults: dict[str, object]) -> None:
    """One `GlobeviewError` line for an option the project file sets itself."""
    from globeview.errors import GlobeviewError

    for name, default in defaults.items():
        if getattr(args, name, default) != default:
            option = "--set" if name == "set_values" else "--" + name.replace("_", "-")
            raise GlobeviewError(
                f"{option} does not apply to a project (the project file sets it); "
                "edit the project, or save another one from the window"
            )


def check_project(path: str) -> None:
    """Read ``path`` and check its plugins against the installed ones (one line if bad)."""
    from globeview.app.project import check_plugins
    from globeview.model.project import read_project
    from globeview.plugins.registry import PluginRegistry

    check_plugins(read_project(path), PluginRegistry().discover())


def check_gui_project(args: argparse.Namespace) -> str | None:
    """``globeview PROJECT.toml``: the project to open in the window, checked (None if
    the files hold none)."""
    path = project_argument(args.files)
    if path is not None:
        refuse_options(args, _GUI_DEFAULTS)
        check_project(path)
    return path


def left_out(problems: list[str]) -> str:
    """The render summary's words for `Globe.project_problems`: layers, tours and a tool
    that were not opened are counted apart (``1 layer(s) missing, 1 tour left out``); a
    tour or tool line starts with ``tour `` or ``tool `` (`globeview.app.project`)."""
    tours = sum(line.startswith("tour ") for line in problems)
    tools = sum(line.startswith("tool ") for line in problems)
    layers = len(problems) - tours - tools
    said = [f"{layers} layer(s) missing"] if layers else []
    said += [f"{tours} tour{'s' if tours > 1 else ''} left out"] if tours else []
    said += ["the tool left out"] if tools else []
    return ", ".join(said)


def render_project(args: argparse.Namespace, path: str) -> int:
    """``globeview render PROJECT.toml -o out.png [--size WxH] [--strict]``."""
    from globeview.app.globe import Globe
    from globeview.cli.render import parse_size
    from globeview.errors import GlobeviewError
    from globeview.fileio import check_output_file
    from globeview.plugins.registry import PluginRegistry

    refuse_options(args, _RENDER_DEFAULTS)
    size = parse_size(args.size)
    out = check_output_file(args.out, "--out", (".png",))
    from globeview.model.project import read_project

    read_project(path)  # a file that is not a project: one line before plugins are found
    globe = Globe.open_project(path, registry=PluginRegistry().discover())
    try:
        missing = globe.project_problems
        if missing and args.strict:
            raise GlobeviewError(f"{path}: {left_out(missing)}; nothing written (--strict)")
        globe.save(out, size)
        stats = globe.session.last.stats if globe.session and globe.session.last else None
    finally:
        globe.close()
    said = f"{len(globe.dems)} DEM(s), {len(globe.overlays)} overlay(s)"
    if missing:
        said += f", {left_out(missing)}"
    drawn = f": {stats.triangles} triangles, {stats.tiles_drawn} tiles" if stats else ""
    print(f"wrote {out} ({size[0]}x{size[1]}; project {path}: {said}){drawn}")
    return 0
