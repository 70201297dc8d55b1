"""`globeview render` when a plugin fails where nothing can stand in for it, and `--set` of a
layer type the render does not use (issue #29 items 7, 9 and 10).

Exit statuses (cli/__init__.py, docs/plugins.md "When a plugin fails"): 2 is the user's bad
input, 3 a plugin failure with nothing written (any plugin failure under ``--strict``; without
it only one no fallback covers: a layer type that cannot open a ``--layer`` file, a tool
whose ``--tool-csv`` plot is asked for). Each error is one line naming the plugin and its
error. Real processes of the installed command (forked by `zygote`); the plugins are real
distributions on PYTHONPATH (`PluginSite`).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import zygote

from globeview.app.testing import PluginSite

pytestmark = pytest.mark.gl

GLOBEVIEW = Path(sys.executable).with_name("globeview")

MANIFEST = """
    name = "gvt-contract"
    version = "0.1.0"
    description = "tools and layer types that fail on purpose"
    kinds = ["tool", "layer"]
    api_version = "1.1"

    [[contributions]]
    name = "gvt-plotfail"
    kind = "tool"
    target = "gvt_contract.impl:PlotFails"

    [[contributions]]
    name = "gvt-pointsfail"
    kind = "tool"
    target = "gvt_contract.impl:PointsFail"

    [[contributions]]
    name = "gvt-crashopen"
    kind = "layer"
    target = "gvt_contract.impl:CrashOpen"
    extensions = [".crash"]

    [[contributions]]
    name = "gvt-crashsniff"
    kind = "layer"
    target = "gvt_contract.impl:CrashSniff"

    [[contributions]]
    name = "gvt-tinted"
    kind = "layer"
    target = "gvt_contract.impl:Tinted"
    extensions = [".tinted"]
    """

IMPL = """
    import numpy as np

    from globeview.plugins.api import LayerType, Lines, Setting, Tool


    class PlotFails(Tool):
        def place_points(self, points):
            return True

        def plot(self):
            raise ValueError("no profile here")


    class PointsFail(Tool):
        def place_points(self, points):
            raise RuntimeError("points went wrong")

        def plot(self):
            return None


    class CrashOpen(LayerType):
        extensions = (".crash",)

        def open(self, path):
            raise RuntimeError("open went wrong")


    class CrashSniff(LayerType):
        def sniff(self, path):
            raise KeyError("sniff went wrong")

        def open(self, path):
            raise AssertionError("never opened")


    class Tinted(LayerType):
        extensions = (".tinted",)
        settings = (Setting("width_px", "float", 2.0, min=0.5, max=20.0),)

        def open(self, path):
            line = np.array([[-40.0, 10.0], [40.0, 10.0]])
            return Lines([line], width_px=self.values["width_px"])
    """


@pytest.fixture
def site(plugin_site: PluginSite) -> PluginSite:
    plugin_site.add("gvt_contract", MANIFEST, {"impl": IMPL})
    return plugin_site


def render(site: PluginSite, tmp: Path, *args: str) -> tuple[subprocess.CompletedProcess, Path]:
    """``globeview render`` of a small whole-globe view into tmp/x.png with ``args``."""
    out = tmp / "x.png"
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(site.root), os.environ.get("PYTHONPATH", "")]),
        "GLOBEVIEW_CONFIG_DIR": str(tmp / "config"),
    }
    env.pop("GLOBEVIEW_DEBUG", None)
    proc = zygote.run(
        [str(GLOBEVIEW), "render", "--no-borders", "--size", "96x64", "--out", str(out), *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    return proc, out


def error_line(proc: subprocess.CompletedProcess) -> str:
    """The run's last stderr line, checked to be its error line (warnings may come before
    it: the registry names a failed plugin once), with no traceback."""
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines and "Traceback" not in proc.stderr, proc.stderr
    assert all(ln.startswith("globeview: warning: ") for ln in lines[:-1]), proc.stderr
    assert lines[-1].startswith("globeview: error: "), proc.stderr
    return lines[-1]


# -- item 7: a tool that fails under --tool-csv -------------------------------------------
@pytest.mark.parametrize("strict", [False, True])
@pytest.mark.parametrize(
    ("tool", "why"),
    [
        ("gvt-plotfail", "ValueError: no profile here"),
        ("gvt-pointsfail", "RuntimeError: points went wrong"),
    ],
)
@pytest.mark.slow
def test_tool_csv_of_a_failed_tool_says_it_failed_exit_3(
    site: PluginSite, tmp_path: Path, tool: str, why: str, strict: bool
) -> None:
    csv = tmp_path / "p.csv"
    flags = ["--strict"] if strict else []
    proc, out = render(site, tmp_path, "--tool", tool, "--point", "1,1", "--tool-csv", str(csv),
                       *flags)  # fmt: skip
    line = error_line(proc)
    assert proc.returncode == 3, proc.stderr
    assert f"tool {tool} failed: {why}" in line and "published no plot" not in line
    assert "nothing written" in line
    assert not out.exists() and not csv.exists()


# -- item 9: a layer type that fails --------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("strict", [False, True])
def test_a_layer_type_that_crashes_in_open_exits_3(
    site: PluginSite, tmp_path: Path, strict: bool
) -> None:
    f = tmp_path / "a.crash"
    f.write_text("anything\n")
    proc, out = render(site, tmp_path, "--layer", str(f), *(["--strict"] if strict else []))
    line = error_line(proc)
    assert proc.returncode == 3, proc.stderr
    assert "layer type gvt-crashopen could not open a.crash: RuntimeError: open went wrong" in line
    assert line.endswith("nothing written (--strict)" if strict else "nothing written")
    assert not out.exists()


@pytest.mark.slow
def test_a_crashed_sniff_is_named_disabled_and_strict_exits_3(
    site: PluginSite, tmp_path: Path
) -> None:
    f = tmp_path / "notes.xyz"
    f.write_bytes(b"\x00\x01 nothing anyone reads")
    proc, out = render(site, tmp_path, "--layer", str(f))
    line = error_line(proc)
    assert proc.returncode == 2  # nobody takes the user's file: their input
    installed = line.split("(installed: ", 1)[1].split(";", 1)[0]
    assert "gvt-crashsniff" not in installed and "gvt-tinted (.tinted)" in installed
    assert "disabled: gvt-crashsniff (its sniff failed: KeyError: 'sniff went wrong')" in line
    assert not out.exists()
    proc, out = render(site, tmp_path, "--layer", str(f), "--strict")
    line = error_line(proc)
    assert proc.returncode == 3 and line.endswith("nothing written (--strict)"), proc.stderr
    assert "gvt-crashsniff (its sniff failed" in line and not out.exists()


@pytest.mark.slow
def test_strict_counts_a_crashed_sniff_when_another_type_took_the_file(
    site: PluginSite, tmp_path: Path
) -> None:
    """GeoJSON saved as .txt: content sniffing asks every type; gvt-crashsniff crashes, the
    built-in vector type takes the file. The picture is drawn; --strict says a plugin failed."""
    f = tmp_path / "line.txt"
    f.write_text('{"type": "LineString", "coordinates": [[0, 0], [10, 10]]}')
    proc, out = render(site, tmp_path, "--layer", str(f))
    assert proc.returncode == 0 and out.exists(), proc.stderr
    assert "layer type gvt-crashsniff failed: KeyError" in proc.stdout
    out.unlink()
    proc, out = render(site, tmp_path, "--layer", str(f), "--strict")
    line = error_line(proc)
    assert proc.returncode == 3 and not out.exists(), proc.stderr
    assert "layer type gvt-crashsniff failed: KeyError: 'sniff went wrong'" in line


# -- item 10: --set of a layer type the render does not use ---------------------------------
@pytest.mark.slow
def test_set_of_a_layer_type_not_used_warns(site: PluginSite, tmp_path: Path) -> None:
    proc, out = render(site, tmp_path, "--set", "gvt-tinted.width_px=4")
    assert proc.returncode == 0 and out.exists(), proc.stderr
    assert proc.stderr.splitlines() == [
        "globeview: warning: --set gvt-tinted.width_px: gvt-tinted is not used by this render "
        "(--layer gvt-tinted:FILE)"
    ]
    f = tmp_path / "a.tinted"
    f.write_text("x\n")
    proc, out = render(site, tmp_path, "--set", "gvt-tinted.width_px=4", "--layer", str(f))
    assert proc.returncode == 0 and out.exists() and proc.stderr == "", proc.stderr
