"""`globeview render`: draw the globe headless (EGL) into a PNG, optionally with frame stats."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "sources",
        nargs="*",
        metavar="STORE|DEM",
        help="tile stores or DEM files (DEMs are ingested into the cache once); "
        "none: the embedded data",
    )
    parser.add_argument("--out", "-o", required=True, help="PNG file to write")
    parser.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT in pixels")
    parser.add_argument(
        "--camera",
        help="LON,LAT,HEIGHT[,HEADING,PITCH[,ROLL]] in degrees and metres "
        "(heading 0 = north, pitch -90 = straight down); default: the whole globe, or the "
        "last source's footprint",
    )
    parser.add_argument("--fov", type=float, default=45.0, help="vertical field of view, deg")
    parser.add_argument("--tau", type=float, default=2.0, help="screen-space error, pixels")
    parser.add_argument("--exaggeration", type=float, default=1.0, help="vertical exaggeration")
    parser.add_argument("--wireframe", action="store_true", help="overlay the triangle edges")
    parser.add_argument("--hillshade", action="store_true", help="light from the north-west")
    parser.add_argument("--no-fog", action="store_true", help="no haze toward the horizon")
    parser.add_argument("--background", help="R,G,B background colour in 0..1")
    parser.add_argument("--stats", help="write the frame's figures as JSON to this file")
    parser.add_argument("--crs", help="CRS for DEM sources that lack one (e.g. EPSG:32610)")
    parser.add_argument(
        "--lod", default="chunked-sse", help="LOD provider plugin (see `globeview plugins list`)"
    )
    parser.add_argument(
        "--layer",
        action="append",
        default=[],
        metavar="FILE",
        help="overlay a raster (imagery, thematic) or vector (GeoJSON lines, points) file; "
        "repeatable",
    )
    parser.add_argument(
        "--imagery", action="store_true", help="drape the embedded Blue Marble imagery"
    )
    parser.add_argument(
        "--no-borders", action="store_true", help="hide the embedded country borders"
    )
    parser.add_argument(
        "--collapse",
        metavar="LONA,LATA,LONB,LATB[,RATIO]",
        help="fold away the terrain between A and B (degrees) to RATIO (default 0.2) of its "
        "length with the terrain-collapse tool",
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


def parse_floats(text: str, name: str, lengths: tuple[int, ...]) -> list[float]:
    from globeview.errors import GlobeviewError

    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise GlobeviewError(f"{name} must be comma-separated numbers, not {text!r}") from None
    if len(vals) not in lengths:
        raise GlobeviewError(f"{name} takes {' or '.join(map(str, lengths))} numbers")
    return vals


def open_sources(sources: list[str], crs: str | None):
    """Tile stores for the given stores/DEMs (DEMs ingested into the cache)."""
    from pathlib import Path

    from globeview.errors import GlobeviewError
    from globeview.terrain.embedded import embedded_stores, open_or_ingest
    from globeview.terrain.store import TileStore

    if not sources:
        return embedded_stores()
    stores = []
    for src in sources:
        p = Path(src)
        if p.is_dir() and (p / "manifest.json").exists():
            stores.append(TileStore.open(p))
        elif p.is_dir():
            raise GlobeviewError(f"{p} is a directory but not a globeview tile store")
        else:
            if crs:
                from globeview.terrain.embedded import store_path_for
                from globeview.terrain.ingest import ingest

                out = store_path_for(p)
                out.parent.mkdir(parents=True, exist_ok=True)
                ingest([p], out, crs=crs)
                stores.append(TileStore.open(out))
            else:
                stores.append(open_or_ingest(p))
    return stores


def run(args: argparse.Namespace) -> int:
    import json
    import os
    from pathlib import Path

    from PIL import Image

    from globeview.errors import GlobeviewError
    from globeview.plugins.session import GlobeSession
    from globeview.render.camera import Camera, camera_for_bounds
    from globeview.render.offscreen import OffscreenTarget, create_headless_context
    from globeview.terrain.stack import TerrainStack

    size = parse_size(args.size)
    stores = open_sources(args.sources, args.crs)
    terrain = TerrainStack.from_stores(stores)
    if args.camera:
        cam_vals = parse_floats(args.camera, "--camera", (3, 5, 6))
        camera = Camera.from_lonlat(*cam_vals, fovy_deg=args.fov)
    elif args.sources:
        camera = camera_for_bounds(*stores[-1].bounds, fovy_deg=args.fov)
    else:
        camera = Camera.from_lonlat(0.0, 20.0, 2.0e7, 0.0, -90.0, fovy_deg=args.fov)

    ctx = create_headless_context()
    target = OffscreenTarget(ctx, size)
    scene = GlobeSession(ctx, terrain, camera, lod=args.lod)
    scene.tau_px = args.tau
    s = scene.settings
    s.exaggeration = args.exaggeration
    s.wireframe = args.wireframe
    s.hillshade = args.hillshade
    s.fog = not args.no_fog
    if args.background:
        s.background = tuple(parse_floats(args.background, "--background", (3,)))
    if not args.no_borders or args.imagery:
        if args.no_borders:
            scene.add_embedded_overlays(imagery=True)
            scene.remove_overlay(scene.overlay_layers[-1])  # keep the imagery only
        else:
            scene.add_embedded_overlays(imagery=args.imagery)
    for path in args.layer:
        scene.add_overlay(path)
    if args.collapse:
        vals = parse_floats(args.collapse, "--collapse", (4, 5))
        tool = scene.tools().get("collapse")
        if tool is None:
            raise GlobeviewError("the collapse tool plugin is not enabled")
        try:
            tool.set_points(*vals[:4], vals[4] if len(vals) == 5 else None)
        except ValueError as exc:
            raise GlobeviewError(f"--collapse: {exc}") from None
        scene.activate_tool("collapse")
    # The first frame uploads tiles; the second one is the steady-state frame we report.
    first = scene.render(target.fbo, size)
    scene.reset_lod()  # measure a full selection, not a cache hit
    result = scene.render(target.fbo, size)
    result.stats.tiles_uploaded = first.stats.tiles_uploaded
    scene.draw_tool_overlay(target.fbo, result.view)  # e.g. the collapse's fold lines

    out = Path(args.out)
    tmp = out.with_name(out.name + ".tmp")
    Image.fromarray(target.read_rgb()).save(tmp, format="PNG")
    os.replace(tmp, out)
    if args.stats:
        Path(args.stats).write_text(json.dumps(result.stats.as_dict(), indent=2) + "\n")
    st = result.stats
    print(
        f"wrote {out} ({size[0]}x{size[1]}): {st.triangles} triangles, {st.tiles_drawn} tiles, "
        f"{st.frame_ms:.1f} ms/frame, max screen-space error {st.max_sse_px:.2f} px"
    )
    return 0
