"""`globeview gui` takes the view and plugin options of `globeview render` (issue #29 item
12): ``--camera``, ``--lod``, ``--tool``, ``--set``, defined once (cli/view_options.py) and
checked before any window exists, so a bad value is the same one line as `render`'s, exit 2,
even where no window can open; ``gui --help`` says overlay files open there too.

Real processes of the installed command (forked by `zygote`), with no display: a command line
that passes the checks ends at "no display" (exit 1), one that does not at its error line (exit
2). The bad options' gui-and-render pairs run in this process (`inprocess_cli`, no display
either: Qt is never imported, and render refuses them before any GL context). The window itself
is tested in tests/ui/test_ui_gui_start.py.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
import zygote
from inprocess_cli import run_globeview

from .run_cli import GLOBEVIEW, one_error_line


def gv(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.pop("QT_QPA_PLATFORM", None)
    env.pop("GLOBEVIEW_DEBUG", None)
    env["GLOBEVIEW_CONFIG_DIR"] = str(tmp / "config")
    env["GLOBEVIEW_CACHE_DIR"] = str(tmp / "cache")
    return zygote.run([str(GLOBEVIEW), *args], capture_output=True, text=True, env=env, timeout=120)


def gv_here(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    """`gv` in this process: the same environment changes for the call only."""
    env: dict[str, str | None] = {k: None for k in ("DISPLAY", "WAYLAND_DISPLAY")}
    env |= {"QT_QPA_PLATFORM": None, "GLOBEVIEW_DEBUG": None}
    env["GLOBEVIEW_CONFIG_DIR"] = str(tmp / "config")
    env["GLOBEVIEW_CACHE_DIR"] = str(tmp / "cache")
    return run_globeview(list(args), env=env)


def test_gui_help_names_the_options_and_overlays(tmp_path: Path) -> None:
    res = gv(tmp_path, "gui", "--help")
    assert res.returncode == 0, res.stderr
    text = " ".join(res.stdout.split())
    for option in ("--camera", "--lod", "--tool NAME", "--set NAME.KEY=VALUE"):
        assert option in text
    assert "overlay files" in text and "GeoJSON" in text


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--camera", "1,2"), "--camera takes 3 or 5 or 6 numbers"),
        (("--camera", "0,95,1000"), "--camera"),
        (("--lod", "no-such-lod"), "no enabled LOD provider named 'no-such-lod'"),
        (("--tool", "no-such-tool"), "--tool: no enabled tool named 'no-such-tool'"),
        (("--set", "measure.samples=1"), "--set measure.samples: 1 is outside 2..4096"),
        (("--set", "no-such.key=1"), "no plugin contribution named 'no-such'"),
    ],
)
def test_bad_options_are_one_line_exit_2_as_in_render(tmp_path: Path, args, message) -> None:
    line = one_error_line(gv_here(tmp_path, "gui", *args))
    assert message in line
    # The same check as render's, word for word (render refuses it before any work too).
    out = tmp_path / "x.png"
    assert one_error_line(gv_here(tmp_path, "render", "--out", str(out), *args)) == line
    assert not out.exists()


@pytest.mark.slow
@pytest.mark.parametrize(
    "argv",
    [
        (
            *("gui", "--camera", "-71.3,44.27,30000,10,-60", "--lod", "distance-regions"),
            *("--tool", "measure", "--set", "measure.samples=64"),
        ),
        ("--camera=-71.3,44.27,30000", "--tool", "measure"),  # no subcommand: the window
    ],
)
def test_good_options_reach_the_display_check(tmp_path: Path, argv) -> None:
    res = gv(tmp_path, *argv)
    assert res.returncode == 1, res.stderr
    assert res.stderr.startswith("globeview: no display"), res.stderr
