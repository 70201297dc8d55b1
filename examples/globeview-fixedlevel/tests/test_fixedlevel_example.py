"""Tests of the example plugin, written as its author would: against globeview's pytest
fixtures (``pip install pytest`` brings them in through globeview's ``pytest11`` entry point)
and the plugin API, with the plugin installed (``pip install -e .`` or from a wheel)."""

from __future__ import annotations

import ast
from pathlib import Path

import globeview_fixedlevel
import numpy as np
import pytest
from globeview_fixedlevel.graticule import graticule_paths, read_graticule
from globeview_fixedlevel.provider import cap_render_set

from globeview.plugins.api import (
    GlobeviewError,
    KeyEvent,
    Lines,
    PointerEvent,
    RenderSet,
    level_shape,
)

PACKAGE = Path(globeview_fixedlevel.__file__).parent
WHITE_MOUNTAINS = (-71.3, 44.27)


def test_discovered_with_all_three_kinds(globeview_registry) -> None:
    rec = globeview_registry.get("fixed-level")
    assert rec.status == "ok" and rec.kinds == ("lod", "tool", "layer")
    assert {"fixed-level", "capped-sse"} <= set(globeview_registry.lod_providers())
    assert "marker" in globeview_registry.tools()
    assert "graticule" in globeview_registry.layer_types()


def test_imports_only_the_plugin_api() -> None:
    for path in PACKAGE.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("globeview"):
                assert node.module == "globeview.plugins.api", f"{path.name}: {node.module}"


# -- fixed-level ---------------------------------------------------------------------------
def test_fixed_level_draws_one_level_around_the_view(globeview_registry, headless_view) -> None:
    provider = globeview_registry.lod_providers()["fixed-level"]
    rs = globeview_registry.select(provider, headless_view(10.0, 45.0, 2.0e6), None)
    assert len(rs) > 0 and np.all(rs.keys[:, 0] == 3)
    assert any((k[1], k[2]) == (8, 1) for k in rs.keys)  # the tile under the camera
    ncols, _ = level_shape(3)
    assert not any(k[1] in (0, ncols - 1) for k in rs.keys)  # the far side is culled


# -- capped-sse: delegation to chunked-sse -----------------------------------------------------
@pytest.fixture
def close_view(headless_view):
    return headless_view(*WHITE_MOUNTAINS, 1.5e4)


def test_capped_refines_no_deeper_than_its_setting(
    globeview_registry, globeview_terrain, close_view
) -> None:
    sse = globeview_registry.lod_providers()["chunked-sse"]
    capped = globeview_registry.lod_providers()["capped-sse"]
    globeview_registry.configure(capped, {"max_level": 7})
    full = globeview_registry.select(sse, close_view, globeview_terrain)
    assert full.keys[:, 0].max() > 7  # the default provider goes deeper here
    rs = globeview_registry.select(capped, close_view, globeview_terrain)
    assert isinstance(rs, RenderSet) and rs.keys[:, 0].max() == 7
    assert rs.stats["tiles_capped"] == np.count_nonzero(full.keys[:, 0] > 7)
    rs.validate(globeview_terrain.tile_size)
    # Still a quadtree cut (no tile with its ancestor) covering everything chunked-sse drew.
    codes = {tuple(k) for k in rs.keys.tolist()}
    assert len(codes) == len(rs)
    for level, x, y in full.keys.tolist():
        ancestors = [(lv, x >> (level - lv), y >> (level - lv)) for lv in range(level + 1)]
        assert sum(a in codes for a in ancestors) == 1
    # The delegate's own (cached) render set was not written into.
    assert globeview_registry.select(sse, close_view, globeview_terrain).keys[:, 0].max() > 7


def test_cap_keeps_shallow_sets_as_they_are() -> None:
    rs = RenderSet(np.array([[2, 1, 1], [3, 0, 0]]), np.array([0, 0]), [])
    same, replaced = cap_render_set(rs, 5)
    assert same is rs and replaced == 0
    capped, replaced = cap_render_set(rs, 0)
    assert replaced == 2 and capped.keys.tolist() == [[0, 0, 0]]
    assert capped.variants[capped.variant_ids[0]].pole == "both"


def test_capped_fails_alone_when_chunked_sse_is_off(
    globeview_registry, globeview_terrain, close_view
) -> None:
    capped = globeview_registry.lod_providers()["capped-sse"]
    globeview_registry.disable("chunked-sse")
    assert globeview_registry.select(capped, close_view, globeview_terrain) is None
    fixed = globeview_registry.lod_providers()["fixed-level"]  # the package's others work
    assert len(globeview_registry.select(fixed, close_view, globeview_terrain)) > 0


def test_capped_renders_headless(rendered) -> None:
    frame = rendered(
        "capped-sse",
        camera=(*WHITE_MOUNTAINS, 2.0e4, 0.0, -60.0),
        settings={"capped-sse": {"max_level": 6}},
    )
    assert not frame.fell_back and frame.failures == {}
    assert frame.render_set.keys[:, 0].max() <= 6
    assert frame.image.std() > 5.0  # terrain was drawn, not a blank frame


# -- the marker tool and its settings ------------------------------------------------------
def test_marker_settings_change_the_overlay(globeview_registry) -> None:
    tool = globeview_registry.tools()["marker"]
    press = PointerEvent(5, 5, "press", button="left", picked=(6.4e6, 0.0, 0.0), lonlat=(0, 0, 0))
    assert globeview_registry.invoke(tool, "on_mouse", press, default=False)
    (m,) = tool.overlay(None)
    assert m.label == "1" and m.size_px == 10.0
    globeview_registry.configure(tool, {"color": "cyan", "numbered": False, "size_px": 500})
    (m,) = tool.overlay(None)
    assert m.label == "" and m.color == (0.1, 0.9, 1.0, 1.0) and m.size_px == 64.0  # clamped
    globeview_registry.configure(tool, {"color": "mauve"})  # not offered: the default
    assert tool.values["color"] == "red"
    assert tool.on_key(KeyEvent("Escape")) and tool.overlay(None) == []


# -- the .graticule layer type -----------------------------------------------------------------
def test_graticule_file_opens_as_rhumb_lines(globeview_registry, tmp_path: Path) -> None:
    path = tmp_path / "grid.graticule"
    path.write_text("# a coarse grid\nlat_step_deg = 30\nlon_step_deg = 45\ncolor = 0 1 0 1\n")
    layer_type = globeview_registry.layer_types()["graticule"]
    lines = globeview_registry.invoke(layer_type, "open", str(path), user_errors=True)
    assert isinstance(lines, Lines) and lines.interpolation == "rhumb"
    assert lines.color == (0.0, 1.0, 0.0, 1.0) and lines.name == "grid.graticule"
    paths = lines.path_list()
    parallels = [p for p in paths if np.ptp(p[:, 1]) == 0]
    meridians = [p for p in paths if np.ptp(p[:, 0]) == 0]
    assert sorted(p[0, 1] for p in parallels) == [-60.0, -30.0, 0.0, 30.0, 60.0]
    assert len(meridians) == 8 and len(parallels) + len(meridians) == len(paths)


def test_graticule_defaults() -> None:
    assert len(graticule_paths(15.0, 15.0)) == 11 + 24


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("step_deg = 0.01\n", ":1: step_deg 0.01 is outside 0.5..90"),
        ("\n\nspacing = 3\n", ":3: unknown key 'spacing'"),
        ("color = 1 1 1\n", ":1: color needs 4 numbers"),
        ("color = 1 1 1 2\n", "within 0..1"),
        ("width_px = nan\n", "not a finite number"),
        ("step_deg = 10\nstep_deg = 20\n", ":2: step_deg given twice"),
        ("just words\n", "expected 'key = value'"),
    ],
)
def test_bad_graticule_files_fail_in_one_line(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.graticule"
    path.write_text(text)
    with pytest.raises(GlobeviewError) as info:
        read_graticule(path)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_unreadable_graticule_files_fail_in_one_line(tmp_path: Path) -> None:
    binary = tmp_path / "b.graticule"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    for path, message in ((binary, "not UTF-8"), (tmp_path / "missing.graticule", "cannot read")):
        with pytest.raises(GlobeviewError, match=message):
            read_graticule(path)
    huge = tmp_path / "huge.graticule"
    huge.write_text("# x\n" * 40_000)
    with pytest.raises(GlobeviewError, match="larger than"):
        read_graticule(huge)


def _magenta_pixels(png: Path) -> int:
    from PIL import Image

    rgb = np.asarray(Image.open(png).convert("RGB")).astype(int)
    return int(np.count_nonzero((rgb[..., 0] > 200) & (rgb[..., 1] < 90) & (rgb[..., 2] > 200)))


def test_graticule_renders_from_the_command_line(tmp_path: Path, globeview_config_dir) -> None:
    """End to end as a user runs it: ``globeview render --layer grid.graticule`` dispatches
    the file to this plugin by its declared extension and draws the lines."""
    import os
    import subprocess
    import sys

    grid = tmp_path / "grid.graticule"
    grid.write_text("step_deg = 10\ncolor = 1 0 1 1\nwidth_px = 3\n")
    env = dict(os.environ, GLOBEVIEW_CACHE_DIR=str(tmp_path / "cache"))
    counts = []
    for extra in ((), ("--layer", str(grid))):
        out = tmp_path / f"frame{len(extra)}.png"
        args = [
            sys.executable,
            "-m",
            "globeview",
            "render",
            "--no-borders",
            "--size",
            "320x240",
            "-o",
            str(out),
            *extra,
        ]
        res = subprocess.run(args, capture_output=True, text=True, env=env, timeout=600)
        assert res.returncode == 0, res.stderr
        counts.append(_magenta_pixels(out))
    assert counts[0] == 0 and counts[1] > 2000
