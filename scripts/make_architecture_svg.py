"""Write docs/img/architecture.svg: globeview's layers (left) and one frame (right).

The picture is data below, laid out by this script, so keeping it in step with the code is an
edit of a table, not of coordinates. LAYERS follows docs/architecture.md's layers table (and the
layers contract in pyproject.toml, top to bottom; "|" rows hold siblings that never import each
other); TERRAIN_ROOMS follows the terrain contract; STEPS follows FramePipeline.run
(render/frame_pipeline.py). Run it from the repository root after changing any of them:

    .venv/bin/python scripts/make_architecture_svg.py
    convert docs/img/architecture.svg /tmp/architecture.png   # look at it
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

OUT = Path(__file__).resolve().parent.parent / "docs" / "img" / "architecture.svg"


@dataclass(frozen=True)
class Box:
    """One layer's box: its package, what it holds (one line) and its main modules."""

    name: str
    css: str
    what: str
    mods: str


# Top to bottom; a row with two boxes holds siblings ("ui | bench").
LAYERS: list[list[Box]] = [
    [Box("cli", "cli", "the globeview command", "gui · render · ingest · height · info · bench")],
    [
        Box("ui", "ui", "Qt shell over the model", "main_window · globe_widget · panels"),
        Box("bench", "bench", "headless flights, soak", "harness · flight · soak · check"),
    ],
    [
        Box(
            "app",
            "app",
            "the application without a window: the session and its hosts (no Qt)",
            "session · lod_host · tool_host · overlay_host · layer_dispatch · testing",
        )
    ],
    [
        Box(
            "render",
            "render",
            "moderngl adapter: the frame pipeline, tile pool, GPU objects",
            "frame_pipeline · renderer · tile_pool · tile_loader · overlay_* · shaders/",
        )
    ],
    [
        Box(
            "plugins",
            "plugins",
            "the API facade, manifests, registry (isolation), built-ins",
            "api · manifest · registry · settings · builtin/<name>/",
        )
    ],
    [
        Box(
            "model",
            "model",
            "the globe as evented plain objects (psygnal; no Qt, no GL)",
            "globe · camera · display · overlay_layers · drawables · plot",
        )
    ],
    [
        Box(
            "lod",
            "lod",
            "ViewState, one traversal steered by policies (numpy)",
            "view_state · traversal · policy · tile_cache · render_set",
        )
    ],
    [Box("terrain", "terrain", "rooms with one purpose, imports pointing down:", "")],
    [
        Box(
            "geodesy",
            "geodesy",
            "ellipsoid, geoid, geodetic/ECEF, ENU, rays, geodesics",
            "transforms · enu · rays · geodesic · geoid",
        )
    ],
    [
        Box(
            "shared",
            "shared",
            "fileio (atomic outputs), then the small bottom modules",
            "fileio → errors · interrupts · paths · validate",
        )
    ],
]

# Inside terrain, top to bottom (the "terrain's parts" contract); "|": side by side.
TERRAIN_ROOMS: list[list[str]] = [
    ["embedded → sources (open_source: the one opener)"],
    ["compose/", "ingest/", "imagery", "vectors"],
    ["store/ (backends: local, http, entry points)"],
    ["dem/ (reader, vdatum, edge)"],
    ["levels → quadtree · interpolate · zhang_index"],
]

# One frame, FramePipeline.run's steps: (title, the layer whose code does the work, note).
STEPS: list[tuple[str, str, str]] = [
    ("1 GPU objects", "app", "the hosts ready the tool's shader hook and overlay twins"),
    ("2 view", "lod", "camera speed from its history, tool step, the ViewState once"),
    ("3 LOD", "lod", "the provider's policy steers the traversal: a RenderSet"),
    ("4 load + upload", "render", "missing tiles built from terrain (threads in the window)"),
    ("5 draw", "render", "terrain in one multi-draw-indirect call, imagery drape"),
    ("6 overlays", "render", "vectors, points and labels, depth-tested"),
    ("7 tool overlay", "app", "the tool's markers and lines, checked and draped by the host"),
    ("8 stats", "lod", "FrameStats in a FrameResult: status bar, --stats, bench"),
]

FILLS = {
    "cli": "#f3f3f3",
    "ui": "#d6e6fb",
    "bench": "#d6f0f0",
    "app": "#f9d9e6",
    "render": "#fde3c8",
    "plugins": "#dcf2d8",
    "model": "#eadcf6",
    "lod": "#fff1b8",
    "terrain": "#eadfd0",
    "geodesy": "#e4e4e4",
    "shared": "#ffffff",
}

WIDTH = 1040
LEFT_X, LEFT_W = 60, 460
RIGHT_X, RIGHT_W = 570, 440
TOP = 56
ROW_H, GAP = 62, 16
ROOM_H, ROOM_GAP = 22, 8


def _text(x: float, y: float, css: str, text: str, extra: str = "") -> str:
    return f'  <text x="{x}" y="{y}" class="{css}"{extra}>{escape(text)}</text>'


def _rect(x: float, y: float, w: float, h: float, css: str, rx: int = 8) -> str:
    return f'  <rect x="{x}" y="{y}" width="{w}" height="{h}" rx="{rx}" class="{css}"/>'


def _arrow(x: float, y1: float, y2: float) -> str:
    return f'    <line x1="{x}" y1="{y1}" x2="{x}" y2="{y2}"/>'


def _terrain_rooms(x: float, y: float, w: float) -> tuple[list[str], float]:
    """The terrain box's inner rooms from y down (px); returns the elements and their bottom."""
    out: list[str] = []
    for row in TERRAIN_ROOMS:
        cell_w = (w - ROOM_GAP * (len(row) - 1)) / len(row)
        for i, room in enumerate(row):
            cx = x + i * (cell_w + ROOM_GAP)
            out.append(_rect(cx, y, cell_w, ROOM_H, "room", rx=4))
            out.append(_text(cx + cell_w / 2, y + 15, "mods", room, ' text-anchor="middle"'))
        y += ROOM_H + ROOM_GAP
    return out, y - ROOM_GAP


def _layers() -> tuple[list[str], float]:
    """The left column: each layer row, the arrows between rows; returns them and its bottom."""
    out = [_text(LEFT_X, 34, "title", "Layers: imports point downwards only")]
    arrows: list[str] = []
    y = TOP
    model_y = ui_y = 0.0
    for row in LAYERS:
        height = float(ROW_H)
        box_w = (LEFT_W - GAP * (len(row) - 1)) / len(row)
        for i, box in enumerate(row):
            x = LEFT_X + i * (box_w + GAP)
            rooms: list[str] = []
            if box.name == "terrain":
                rooms, bottom = _terrain_rooms(x + 14, y + 50, box_w - 28)
                height = bottom - y + 12
            out.append(_rect(x, y, box_w, height, f"box {box.css}"))
            label = box.name if box.name == "shared" else f"globeview/{box.name}"
            out.append(_text(x + 14, y + 20, "name", label))
            out.append(_text(x + 14, y + 38, "what", box.what))
            if box.mods:
                out.append(_text(x + 14, y + 55, "mods", box.mods))
            out.extend(rooms)
            if box.name == "model":
                model_y = y + height / 2
            if box.name == "ui":
                ui_y = y + height / 2
        if y > TOP:
            arrows.append(_arrow(LEFT_X + LEFT_W / 2, y - GAP, y - 2))
        y += height + GAP
    out.append('  <g stroke="#333" stroke-width="1.6" marker-end="url(#arrow)">')
    out.extend(arrows)
    out.append("  </g>")
    out.append(_text(LEFT_X + LEFT_W / 2 + 10, TOP + ROW_H + 12, "note", "imports"))
    # Model events go up to whoever subscribes (the window's widgets, the tool host).
    out.append(
        f'  <path d="M {LEFT_X} {model_y} L 34 {model_y} L 34 {ui_y} L {LEFT_X - 2} {ui_y}" '
        'fill="none" stroke="#7a3fa0" stroke-width="1.6" stroke-dasharray="6 4" '
        'marker-end="url(#arrow-event)"/>'
    )
    mid = (model_y + ui_y) / 2
    out.append(
        _text(
            26,
            mid,
            "note",
            "model events (psygnal)",
            f' fill="#7a3fa0" transform="rotate(-90 26 {mid})" text-anchor="middle"',
        )
    )
    return out, y - GAP


def _frame() -> tuple[list[str], float]:
    """The right column: the callers, then FramePipeline.run's steps; returns them, bottom."""
    out = [_text(RIGHT_X, 34, "title", "One frame, top to bottom")]
    out.append(_rect(RIGHT_X, TOP, RIGHT_W, 56, "box shared side"))
    out.append(_text(RIGHT_X + 14, TOP + 22, "step", "Callers: one path for all"))
    out.append(
        _text(RIGHT_X + 14, TOP + 43, "mods", "window paintGL · render CLI · bench · rendered")
    )
    frame_top = TOP + 72
    step_x, step_w, step_h, pitch = RIGHT_X + 12, RIGHT_W - 24, 54, 68
    steps_top = frame_top + 32
    frame_h = 32 + pitch * len(STEPS) + 2
    out.append(
        f'  <rect x="{RIGHT_X - 12}" y="{frame_top}" width="{RIGHT_W + 24}" height="{frame_h}" '
        'rx="10" fill="none" stroke="#555" stroke-width="1.2"/>'
    )
    out.append(_text(RIGHT_X, frame_top + 20, "mods", "FramePipeline.run"))
    out.append(
        _text(
            RIGHT_X + RIGHT_W,
            frame_top + 20,
            "mods",
            "render/frame_pipeline.py",
            ' text-anchor="end"',
        )
    )
    cx = RIGHT_X + RIGHT_W / 2
    arrows = [_arrow(cx, TOP + 56, steps_top - 2)]
    for i, (title, css, note) in enumerate(STEPS):
        y = steps_top + i * pitch
        out.append(_rect(step_x, y, step_w, step_h, f"box {css}", rx=6))
        out.append(_text(step_x + 14, y + 22, "step", title))
        out.append(_text(step_x + 14, y + 42, "note", note))
        if i:
            arrows.append(_arrow(cx, y - (pitch - step_h), y - 2))
    out.append('  <g stroke="#333" stroke-width="1.6" marker-end="url(#arrow)">')
    out.extend(arrows)
    out.append("  </g>")
    y = frame_top + frame_h + 24
    for line in (
        "Step colour = the layer whose code does the work (legend: the",
        "boxes on the left). The provider in step 3 and the tool in steps 2",
        "and 7 are plugins, called by the app's hosts through the registry.",
    ):
        out.append(_text(RIGHT_X, y, "note", line))
        y += 16
    return out, y


def svg() -> str:
    """The whole picture as SVG text."""
    left, left_bottom = _layers()
    right, right_bottom = _frame()
    height = int(max(left_bottom, right_bottom) + 24)
    fills = " ".join(f".{k} {{ fill: {v}; }}" for k, v in FILLS.items())
    head = f"""<?xml version="1.0" encoding="UTF-8"?>
<!-- globeview's architecture, written by scripts/make_architecture_svg.py (edit its tables and
     rerun it; docs/architecture.md explains the picture).
     Left: the layers, imports point downwards only; model events go up to whoever subscribes.
     Right: one frame, top to bottom, as FramePipeline.run runs it; each step is coloured
     like the layer whose code does the work. -->
<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{height}" \
viewBox="0 0 {WIDTH} {height}"
     font-family="DejaVu Sans, Helvetica, Arial, sans-serif" font-size="13">
  <defs>
    <marker id="arrow" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="8" markerHeight="8"
            orient="auto-start-reverse">
      <path d="M 0 0 L 10 5 L 0 10 z" fill="#333"/>
    </marker>
    <marker id="arrow-event" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="8"
            markerHeight="8" orient="auto-start-reverse">
      <path d="M 0 0 L 10 5 L 0 10 z" fill="#7a3fa0"/>
    </marker>
    <style>
      .name {{ font-weight: bold; font-size: 15px; }}
      .what {{ font-size: 12.5px; fill: #222; }}
      .mods {{ font-family: "DejaVu Sans Mono", Menlo, Consolas, monospace; font-size: 11px;
              fill: #444; }}
      .title {{ font-weight: bold; font-size: 17px; }}
      .step {{ font-weight: bold; font-size: 14px; }}
      .note {{ font-size: 11.5px; fill: #444; }}
      .box {{ stroke: #555; stroke-width: 1.2; }}
      .room {{ fill: #f7f1e8; stroke: #8a7a66; stroke-width: 0.8; }}
      .side {{ stroke-dasharray: 5 3; }}
      {fills}
    </style>
  </defs>

  <rect x="0" y="0" width="{WIDTH}" height="{height}" fill="#ffffff"/>
"""
    return head + "\n".join([*left, "", *right]) + "\n</svg>\n"


def main() -> int:
    """Write the SVG (or, with --check, exit 1 when the file differs from what it would be)."""
    text = svg()
    if sys.argv[1:] == ["--check"]:
        return 0 if OUT.read_text(encoding="utf-8") == text else 1
    OUT.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
