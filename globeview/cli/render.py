"""`globeview render`: draw the globe headless (EGL) into a PNG, optionally with frame stats."""

from __future__ import annotations

import argparse
import sys

from globeview.cli.dem_options import add_dem_options, check_dem_options
from globeview.cli.view_options import (
    add_scene_options,
    add_view_options,
    check_plugin_options,
    checked,
    parse_camera,
    parse_floats,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "sources",
        nargs="*",
        metavar="STORE|URL|DEM",
        help="tile store folders, store URLs (https://HOST/path/store, read over HTTP with "
        "a local disk cache) or DEM files (DEMs are ingested into the cache once); "
        "none: the embedded data; or one project file (PROJECT.toml, saved by the window or "
        "Globe.save_project), drawn as it was saved",
    )
    parser.add_argument("--out", "-o", required=True, help="PNG file to write")
    parser.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT in pixels")
    # --camera, --lod, --tool, --set: shared with `globeview gui` (cli/view_options.py).
    add_view_options(parser)
    # --fov, --tau, --exaggeration, display flags, --layer: shared with `globeview movie`.
    add_scene_options(parser)
    parser.add_argument("--wireframe", action="store_true", help="overlay the triangle edges")
    parser.add_argument("--stats", help="write the frame's figures as JSON to this file")
    add_dem_options(parser)
    parser.add_argument(
        "--points",
        metavar="LON,LAT[;LON,LAT...]",
        help="the points (degrees) the --tool gets, in order, as a user would click them",
    )
    parser.add_argument(
        "--point",
        action="append",
        default=[],
        metavar="LON,LAT",
        help="one point for the --tool (degrees); repeatable, after those of --points",
    )
    parser.add_argument(
        "--tool-csv",
        metavar="FILE",
        help="write the plot the --tool publishes (e.g. the measure tool's terrain profile) "
        "as CSV to FILE, with the PNG, all or nothing",
    )
    parser.add_argument(
        "--strict",
        action="store_true",
        help="exit 3 and write nothing when a plugin fails (the LOD provider falls back, the "
        "tool or a layer type fails); without it the picture is drawn by the fallback and the "
        "'wrote' line says so (exit 0), except where nothing stands in for the plugin (a "
        "layer type that cannot open a --layer file, the --tool-csv tool): exit 3 either way",
    )
    parser.add_argument(
        "--collapse",
        metavar="LONA,LATA,LONB,LATB[,RATIO]",
        help="fold away the terrain between A and B (degrees) to RATIO (default: the "
        "collapse.ratio setting, 0.2) of its length: a spelling of --tool collapse "
        "--points LONA,LATA;LONB,LATB --set collapse.ratio=RATIO",
    )


def parse_size(text: str) -> tuple[int, int]:
    from globeview.errors import GlobeviewError

    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise GlobeviewError(f"--size must look like 1280x720, not {text!r}") from None
    if not (16 <= w <= 16384 and 16 <= h <= 16384):
        raise GlobeviewError(f"--size {text} is out of range (16..16384 pixels a side)")
    return w, h


def parse_background(text: str) -> tuple[float, float, float]:
    """--background R,G,B, each a finite number in 0..1."""
    from globeview.validate import check_number

    vals = parse_floats(text, "--background", (3,))
    return tuple(  # type: ignore[return-value]
        checked("--background", check_number, name, v, 0.0, 1.0)
        for name, v in zip(("red", "green", "blue"), vals, strict=True)
    )


def parse_collapse(text: str) -> tuple[float, float, float, float, float | None]:
    """--collapse LONA,LATA,LONB,LATB[,RATIO]: finite longitudes, latitudes in -90..90 and a
    ratio in 0.001..1 (the tool itself refuses near-antipodal pairs)."""
    from globeview.validate import check_finite, check_number

    vals = parse_floats(text, "--collapse", (4, 5))
    lon_a = checked("--collapse", check_finite, "longitude of A", vals[0])
    lat_a = checked("--collapse", check_number, "latitude of A", vals[1], -90.0, 90.0, " deg")
    lon_b = checked("--collapse", check_finite, "longitude of B", vals[2])
    lat_b = checked("--collapse", check_number, "latitude of B", vals[3], -90.0, 90.0, " deg")
    ratio = None
    if len(vals) == 5:
        ratio = checked("--collapse", check_number, "ratio", vals[4], 0.001, 1.0)
    return lon_a, lat_a, lon_b, lat_b, ratio


def parse_point(text: str, option: str) -> tuple[float, float]:
    """One ``LON,LAT`` (degrees): a finite longitude, reduced to -180..180 as --camera's is,
    and a latitude in -90..90."""
    from globeview.validate import check_finite, check_number

    lon, lat = parse_floats(text, option, (2,))
    lon = checked(option, check_finite, "longitude", lon)
    lat = checked(option, check_number, "latitude", lat, -90.0, 90.0, " deg")
    return wrap_lon(lon), lat


def wrap_lon(lon: float) -> float:
    """A finite longitude (degrees) in -180..180 (1e308 degrees is some place, not garbage)."""
    return (lon + 180.0) % 360.0 - 180.0


def parse_tool_args(args: argparse.Namespace) -> tuple[str | None, list, list[tuple[str, str]]]:
    """(tool name or None, its points, the ``--set`` texts with the option each came from),
    with ``--collapse A,B[,R]`` read as ``--tool collapse --points A;B --set
    collapse.ratio=R``. Only the syntax is checked here; names and values are checked against
    the plugins in `check_plugin_options`."""
    from globeview.errors import GlobeviewError

    points: list[tuple[float, float]] = []
    if args.points is not None:
        parts = [p for p in args.points.split(";") if p.strip()]
        if not parts:
            raise GlobeviewError("--points takes LON,LAT[;LON,LAT...]")
        points += [parse_point(p, "--points") for p in parts]
    points += [parse_point(p, "--point") for p in args.point]
    if len(points) > MAX_TOOL_POINTS:
        raise GlobeviewError(f"--points/--point: {len(points)} points (at most {MAX_TOOL_POINTS})")
    tool = args.tool
    sets = [(text, "--set") for text in args.set_values]
    if args.collapse:
        if tool not in (None, "collapse") or points:
            raise GlobeviewError(
                "--collapse is --tool collapse with two --points; give one or the other"
            )
        *ab, ratio = parse_collapse(args.collapse)
        tool, points = "collapse", [(wrap_lon(ab[0]), ab[1]), (wrap_lon(ab[2]), ab[3])]
        if ratio is not None:
            sets.append((f"collapse.ratio={ratio!r}", "--collapse"))
    if points and tool is None:
        raise GlobeviewError("--points/--point need a --tool to give them to")
    return tool, points, sets


#: Most points `--points`/`--point` may give a tool.
MAX_TOOL_POINTS = 10_000


def check_view_args(args: argparse.Namespace) -> dict:
    """Every view argument validated before anything is loaded or drawn: a bad one is a
    one-line `GlobeviewError` stating the valid range (not a traceback from deep in the
    LOD selection). Returns the parsed values."""
    from globeview.model.camera import FOV_RANGE_DEG
    from globeview.validate import check_exaggeration, check_number, check_tau

    return {
        "size": parse_size(args.size),
        "fov": checked("--fov", check_number, "field of view", args.fov, *FOV_RANGE_DEG, " deg"),
        "tau": checked("--tau", check_tau, args.tau),
        "exaggeration": checked("--exaggeration", check_exaggeration, args.exaggeration),
        "camera": parse_camera(args.camera) if args.camera else None,
        "background": parse_background(args.background) if args.background else None,
        "tool": parse_tool_args(args),
    }


def check_outputs(args: argparse.Namespace):
    """(png, stats or None) paths, checked before any work (see `fileio.check_output_file`)."""
    import os

    from globeview.errors import GlobeviewError
    from globeview.fileio import check_output_file

    out = check_output_file(args.out, "--out", (".png",))
    stats = check_output_file(args.stats, "--stats") if args.stats is not None else None
    if stats is not None and os.path.abspath(stats) == os.path.abspath(out):
        raise GlobeviewError("--stats and --out name the same file")
    return out, stats


def check_tool_csv(args: argparse.Namespace, tool: str | None, others: list):
    """The --tool-csv path (or None), checked before any work: a .csv file that none of
    the other outputs names, and a --tool to publish it."""
    import os

    from globeview.errors import GlobeviewError
    from globeview.fileio import check_output_file

    if args.tool_csv is None:
        return None
    if tool is None:
        raise GlobeviewError("--tool-csv needs a --tool whose plot it writes")
    path = check_output_file(args.tool_csv, "--tool-csv", (".csv",))
    if any(o is not None and os.path.abspath(o) == os.path.abspath(path) for o in others):
        raise GlobeviewError("--tool-csv names the same file as --out or --stats")
    return path


def tool_plot_csv(scene, tool_name: str, strict: bool = False) -> str:
    """The CSV text of the plot the active tool publishes, as the session's tool host gives
    it (`GlobeSession.tool_plot_csv`). A tool that failed (before or in ``plot()``; garbage
    returned fails it too) is a one-line `PluginFailed` naming it and its error (exit 3:
    nothing stands in for it); one that works but publishes none (no ``plot()``, or its
    points gave none) is the user's one-line `GlobeviewError` (exit 2)."""
    from globeview.errors import GlobeviewError, PluginFailed
    from globeview.plugins.api import PluginKind

    text = scene.tool_plot_csv()
    if text is not None:
        return text
    why = scene.registry.failure_of(tool_name, PluginKind.TOOL)
    if why is not None:  # the plugin's fault, not a tool without a plot: say so (exit 3)
        suffix = " (--strict)" if strict else ""
        raise PluginFailed(f"--tool-csv: tool {tool_name} failed: {why}; nothing written{suffix}")
    raise GlobeviewError(f"--tool-csv: the tool {tool_name} published no plot; nothing written")


def check_inputs(args: argparse.Namespace) -> None:
    """Sources and --layer files exist, checked before the first (slow) ingest."""
    from pathlib import Path

    from globeview.errors import GlobeviewError
    from globeview.terrain.sources import check_source

    for src in args.sources:
        check_source(src)  # a URL's form (the server is asked when it is opened), a DEM file
    from globeview.app.layer_dispatch import parse_layer_spec, split_sublayer

    for layer in args.layer:
        p = Path(split_sublayer(parse_layer_spec(layer)[1])[0])  # [TYPE:]FILE[::LAYER]
        if p.is_dir():
            raise GlobeviewError(f"--layer {layer} is a directory, not a layer file")
        if not p.is_file():
            raise GlobeviewError(f"--layer {layer}: no such file")


def check_cache_writable(
    sources: list[str], crs: str | None = None, vdatum: str | None = None
) -> None:
    """Refuse in one line, before rendering, when DEMs must be ingested into a cache folder
    that cannot be written (a read-only mount, no permission). Stores already in the cache
    (current ones, of the same --crs/--vdatum) are read, so a read-only cache that holds them
    all is fine."""
    from pathlib import Path

    from globeview.errors import GlobeviewError
    from globeview.fileio import writable_folder_problem
    from globeview.paths import cache_dir
    from globeview.terrain.embedded import embedded_stores_ready
    from globeview.terrain.sources import cache_message, source_kind, store_path_for
    from globeview.terrain.store.identify import identify

    dems = [Path(s) for s in sources if source_kind(s) == "dem"]
    if sources:
        needed = any(
            not identify(store_path_for(p, crs=crs, vdatum=vdatum)).is_current for p in dems
        )
    else:
        needed = not embedded_stores_ready()
    if not needed:
        return
    problem = writable_folder_problem(cache_dir())
    if problem is not None:
        raise GlobeviewError(cache_message(problem))


def open_sources(sources: list[str], crs: str | None, vdatum: str | None = None):
    """Tile stores for the given sources, each opened by `open_source` (stores as they are,
    DEM files ingested into the cache; ``crs`` and ``vdatum`` apply to the DEM files); the
    embedded DEMs when there are none."""
    from globeview.terrain.embedded import embedded_stores
    from globeview.terrain.sources import open_source

    if not sources:
        return embedded_stores()
    return [open_source(src, crs=crs, vdatum=vdatum) for src in sources]


#: How the warning of `warn_unused_settings` says to use a contribution, by kind.
_USE_HINT = {"lod": "--lod {}", "tool": "--tool {}", "layer": "--layer {}:FILE"}


def warn_unused_settings(registry, assignments: list, used: dict[str, set]) -> None:
    """One warning line per --set of a contribution this render does not use (the user
    likely meant it to change the picture), for the kinds in ``used`` (kind -> the names
    used): LOD providers and tools are known before any work, layer types once the --layer
    files (and the embedded overlays) are open, since the files decide which types open
    them."""
    import logging

    for target, _ in assignments:
        kind = target.kind(registry)
        if kind in used and target.contribution not in used[kind]:
            logging.getLogger("globeview.cli").warning(
                "--set %s: %s is not used by this render (%s)",
                target.label,
                target.contribution,
                _USE_HINT[kind].format(target.contribution),
            )


def run(args: argparse.Namespace) -> int:
    from PIL import Image

    from globeview.app.headless import place_points
    from globeview.app.session import GlobeSession
    from globeview.cli.project import project_argument, render_project
    from globeview.model.camera import Camera, camera_for_bounds
    from globeview.plugins.api import PluginKind
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import apply_overrides
    from globeview.render.offscreen import OffscreenTarget, create_headless_context
    from globeview.terrain.compose.stack import TerrainStack

    project = project_argument(args.sources)  # `render PROJECT.toml`: cli/project.py
    if project is not None:
        return render_project(args, project)
    # Everything the user typed is checked before the first tile is read: a bad value or an
    # unwritable output fails at once, in one line, and nothing is written.
    v = check_view_args(args)
    size = v["size"]
    tool_name, points, sets = v["tool"]
    out, stats_path = check_outputs(args)
    csv_path = check_tool_csv(args, tool_name, [out, stats_path])
    check_inputs(args)
    check_cache_writable(args.sources, args.crs, args.vdatum)
    check_dem_options(args)  # "egm2008" or a typo: one line before any work
    registry = PluginRegistry().discover()
    assignments = check_plugin_options(registry, args.lod, tool_name, sets)
    warn_unused_settings(registry, assignments, {"lod": {args.lod}, "tool": {tool_name}})
    apply_overrides(registry, assignments)  # this render only: nothing is stored
    stores = open_sources(args.sources, args.crs, args.vdatum)
    terrain = TerrainStack.from_stores(stores)
    if v["camera"] is not None:
        camera = Camera.from_lonlat(*v["camera"], fovy_deg=v["fov"])
    elif args.sources:
        camera = camera_for_bounds(*stores[-1].bounds, fovy_deg=v["fov"])
    else:
        camera = Camera.from_lonlat(0.0, 20.0, 2.0e7, 0.0, -90.0, fovy_deg=v["fov"])

    ctx = create_headless_context()
    target = OffscreenTarget(ctx, size)
    scene = GlobeSession(ctx, terrain, camera, registry=registry, lod=args.lod)
    scene.tau_px = v["tau"]
    s = scene.settings
    s.exaggeration = v["exaggeration"]
    s.wireframe = args.wireframe
    s.hillshade = args.hillshade
    s.fog = not args.no_fog
    if v["background"] is not None:
        s.background = v["background"]
    if not args.no_borders or args.imagery:
        if args.no_borders:
            scene.add_embedded_overlays(imagery=True)
            scene.remove_overlay(scene.overlay_layers[-1])  # keep the imagery only
        else:
            scene.add_embedded_overlays(imagery=args.imagery)
    open_layers(scene, args.layer, args.strict)
    warn_unused_settings(registry, assignments, {"layer": scene.overlay_host.types_used})
    if tool_name is not None:
        tool = scene.find_tool(tool_name)  # imports that tool's plugin only
        if tool is not None:
            scene.activate_tool(tool_name)
            if points and scene.tool() is not None:
                place_points(scene, tool, points, size)
    # The first frame uploads tiles; the second one is the steady-state frame we report.
    remote = any(bool(getattr(st, "is_remote", False)) for st in stores)
    first = stream_tiles(scene, target.fbo, size) if remote else scene.render(target.fbo, size)
    if scene.overlay_errors:  # a layer the GPU side refused (its limits): the user's, one line
        from globeview.errors import GlobeviewError

        raise GlobeviewError(f"{scene.overlay_errors[0]}; nothing written")
    scene.reset_lod()  # measure a full selection, not a cache hit
    result = scene.render(target.fbo, size)
    result.stats.tiles_uploaded = first.stats.tiles_uploaded
    # render() drew the tool's overlay too (e.g. the collapse's fold lines), as the window's.

    st = result.stats
    failures = plugin_failures(scene, args.lod, tool_name)
    # The plot is asked for before --strict judges: a tool failing in plot() is a failure.
    extra = {csv_path: tool_plot_csv(scene, tool_name, args.strict)} if csv_path else {}
    tiles_failed = int(st.extra.get("tiles_failed", 0))
    dead = [x for x in stores if getattr(x, "is_remote", False) and x.blocks_read == 0]
    if tiles_failed and dead:
        # Not one block of a remote store arrived (its server is down, or refuses every
        # chunk): a globe without it written with exit 0 would pass for a render of it.
        from globeview.errors import StoreError

        raise StoreError(
            f"no tile of {dead[0].location} could be read ({first_tile_failure(scene)}); "
            "nothing written"
        )
    if tiles_failed:
        failures["tiles"] = f"{tiles_failed} tiles could not be read (drawn from coarser ones)"
    status = tool_status(scene) if tool_name is not None else ""
    stats = stats_json(
        st, args.lod, (tool_name, points, status), assignments, failures, result.overlay_drawn
    )
    if failures and args.strict:
        print(
            f"globeview: error: {'; '.join(failure_texts(args.lod, tool_name, failures))}; "
            "nothing written (--strict)",
            file=sys.stderr,
        )
        return STRICT_EXIT
    write_outputs(Image.fromarray(target.read_rgb()), stats, out, stats_path, extra)
    drew = st.lod_provider
    if not drew or not registry.offers(PluginKind.LOD, drew):
        drew = "none, no terrain drawn"  # the fallback failed too: an empty frame
    said = [f"provider: {drew}", *failure_texts(args.lod, tool_name, failures)]
    degraded = st.extra.get("degraded")
    print(
        f"wrote {out} ({size[0]}x{size[1]}; {', '.join(said)}): {st.triangles} triangles, "
        f"{st.tiles_drawn} tiles, {st.frame_ms:.1f} ms/frame, max screen-space error "
        f"{st.max_sse_px:.2f} px" + (f"; degraded: {degraded}" if degraded else "")
    )
    if status:  # what the tool would say in the window's status bar (e.g. a distance)
        print(status if status.startswith(f"{tool_name}:") else f"{tool_name}: {status}")
    return 0


def first_tile_failure(scene) -> str:
    """The first failed tile's error, one line (what the tile loader kept), or a generic
    phrase when there is none to show."""
    loader = getattr(scene.renderer, "loader", None)
    failed = dict(loader.failed) if loader is not None else {}
    for exc in failed.values():
        text = " ".join(str(exc).split())
        if text:
            return text if len(text) <= 300 else text[:297] + "..."
    return "every tile failed"


def stream_tiles(scene, fbo, size: tuple[int, int]):
    """Draw frames until every tile of the view has arrived or failed, as the window does:
    for stores read over HTTP the tile loader's worker fetches the tiles while coarser ones
    stand in, and a tile that cannot be fetched (a server's 500, a timeout) stays stood in
    and is counted (``tiles_failed`` in the stats, and in the 'wrote' line) instead of
    failing the render. Each wait is bounded by the remote reader's timeouts and retries;
    Ctrl-C ends it. Returns the last frame, with every upload counted."""
    import time

    scene.renderer.async_loading = True
    uploaded = 0
    while True:
        result = scene.render(fbo, size)
        uploaded += result.stats.tiles_uploaded
        if result.stats.tiles_loading == 0:
            break
        time.sleep(0.02)  # the loader's worker holds the network wait, not this thread
    result.stats.tiles_uploaded = uploaded
    return result


def stats_json(
    st,
    lod: str,
    tool: tuple,
    assignments: list,
    failures: dict[str, str],
    overlay_drawn: int = 0,
) -> dict:
    """What ``--stats`` writes: the frame's figures (`FrameStats.as_dict`: host figures,
    ``levels``, ``provider`` with its own stats) plus what was asked and what failed:
    ``provider.requested`` and ``provider.fell_back_from``; ``tool`` (name, points, status,
    error, ``overlay_drawn``: the tool overlay instances the frame drew) when ``tool`` =
    (name, points, status text) names one; ``settings`` from --set."""
    name, points, status = tool
    stats = st.as_dict()
    stats["provider"]["requested"] = lod
    if "provider" in failures:
        stats["provider"]["fell_back_from"] = {"name": lod, "error": failures["provider"]}
    if name is not None:
        stats["tool"] = {"name": name, "points": [list(p) for p in points]}
        stats["tool"]["overlay_drawn"] = int(overlay_drawn)
        if status:
            stats["tool"]["status"] = status
        if "tool" in failures:
            stats["tool"]["error"] = failures["tool"]
    if assignments:
        stats["settings"] = {t.label: value for t, value in assignments}
    return stats


def tool_status(scene) -> str:
    """The last status text the tool gave the host (`RendererHooks.set_status`), one line of
    at most 300 characters ('' when none)."""
    text = getattr(scene.hooks, "status", "")
    text = " ".join(text.split()) if isinstance(text, str) else ""
    return text if len(text) <= 300 else text[:297] + "..."


#: Exit status of `render --strict` when a plugin failed (2 is bad input, 1 a bug); the
#: status of every `PluginFailed`.
STRICT_EXIT = 3


def plugin_failures(scene, lod: str, tool: str | None) -> dict[str, str]:
    """What failed during the render: ``{"provider": reason}`` when the requested LOD
    provider did not draw the frame (the session fell back), ``{"tool": reason}`` when the
    tool's plugin failed (its overlay and displacement were dropped), ``{"layers": text}``
    when layer types failed (a ``sniff`` that crashed while another type took the file)."""
    out: dict[str, str] = {}
    drew = scene.last.stats.lod_provider if scene.last is not None else ""
    failure_of = scene.registry.failure_of
    if drew != lod or failure_of(lod) is not None:
        out["provider"] = failure_of(lod) or "it did not draw"
    if tool is not None and scene.tool() is None:
        out["tool"] = failure_of(tool) or "it was not active"
    layers = layer_type_failures(scene.registry)
    if layers:
        out["layers"] = "; ".join(f"layer type {n} failed: {why}" for n, why in layers.items())
    return out


def layer_type_failures(registry) -> dict[str, str]:
    """Layer type name -> ``"ExcType: message"`` of each layer type that failed in this
    process (failures are per session: a render's are its own)."""
    from globeview.plugins.api import PluginKind

    return {
        name: failure.error
        for rec in registry
        for name, failure in rec.failures.items()
        if failure.kind == PluginKind.LAYER
    }


def open_layers(scene, layers: list[str], strict: bool) -> None:
    """Open each ``--layer`` file (`GlobeSession.add_overlay`). A layer type that fails on
    one is a `PluginFailed` line (exit 3, nothing written); under ``strict`` so is the user's
    error met after a layer type failed on the way (a ``sniff`` that crashed), since a
    plugin failed."""
    from globeview.errors import GlobeviewError, PluginFailed

    suffix = "; nothing written" + (" (--strict)" if strict else "")
    for path in layers:
        try:
            scene.add_overlay(path)
        except PluginFailed as exc:
            raise PluginFailed(f"{exc}{suffix}") from None
        except GlobeviewError as exc:
            if strict and layer_type_failures(scene.registry):
                raise PluginFailed(f"{exc}{suffix}") from None
            raise


def failure_texts(lod: str, tool: str | None, failures: dict[str, str]) -> list[str]:
    """The failures as phrases for the 'wrote' line and the --strict error."""
    said = []
    if "provider" in failures:
        said.append(f"fell back from {lod}: {failures['provider']}")
    if "tool" in failures:
        said.append(f"tool {tool} failed: {failures['tool']}")
    if "layers" in failures:
        said.append(failures["layers"])
    if "tiles" in failures:
        said.append(failures["tiles"])
    return said


def write_outputs(image, stats: dict, out, stats_path, texts: dict | None = None) -> None:
    """The PNG, the stats JSON and any further text files (``texts``: path -> text, e.g.
    the tool's CSV), all-or-nothing (`fileio.atomic_outputs`): all are written to
    temporaries first and only then moved into place, so a full disk or Ctrl-C leaves
    neither a half PNG nor a PNG without its stats."""
    import json

    from globeview.fileio import atomic_outputs

    texts = dict(texts or {})
    if stats_path is not None:
        texts = {stats_path: json.dumps(stats, indent=2) + "\n", **texts}
    with atomic_outputs([out, *texts]) as temps:
        image.save(temps[0], format="PNG")
        for tmp, text in zip(temps[1:], texts.values(), strict=True):
            tmp.write_text(text, encoding="utf-8")
