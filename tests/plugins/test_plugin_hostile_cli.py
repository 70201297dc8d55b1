"""Misbehaving plugins seen from the command line (issue #13, item 10): real processes of
`.venv/bin/globeview` (forked by `zygote` from its pre-warmed server: a process of their own,
its exit status, stderr and signals, without the ~1 CPU-s interpreter start) with throwaway
plugin distributions made discoverable through PYTHONPATH (a package plus a .dist-info, found
by importlib.metadata like a pip install). Which modules a render imports is read from a
fresh interpreter (`python -c`), where nothing was imported before the command.

The contract: the command completes (exit 0, the PNG drawn by the fallback provider), stderr
has exactly one line about the broken plugin and no traceback; plugins nobody asked for are
not even imported; a real Ctrl-C still interrupts.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zygote
from PIL import Image
from test_plugin_hostile import add_lod, manifest

from globeview.app.testing import PluginSite

GLOBEVIEW = Path(sys.executable).with_name("globeview")
SIZE = "64x48"


def globeview(
    site: PluginSite, config: Path, *args: str, **env: str
) -> subprocess.CompletedProcess:
    environ = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(site.root), os.environ.get("PYTHONPATH", "")]),
        "GLOBEVIEW_CONFIG_DIR": str(config),
        **env,
    }
    environ.pop("GLOBEVIEW_DEBUG", None)
    return zygote.run(
        [str(GLOBEVIEW), *args], capture_output=True, text=True, env=environ, timeout=300
    )


def render(site: PluginSite, tmp_path: Path, lod: str, **env: str):
    out = tmp_path / f"{lod}.png"
    proc = globeview(
        site, tmp_path / "config", "render", "--lod", lod, "--size", SIZE, "--out", str(out), **env
    )
    return proc, out


def stderr_lines(proc: subprocess.CompletedProcess) -> list[str]:
    return [line for line in proc.stderr.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def reference_png(tmp_path_factory: pytest.TempPathFactory) -> np.ndarray:
    """The picture `render --lod chunked-sse` draws (what a fallback must draw)."""
    tmp = tmp_path_factory.mktemp("reference")
    site = PluginSite(tmp / "site")
    site.root.mkdir()
    proc, out = render(site, tmp, "chunked-sse")
    assert proc.returncode == 0, proc.stderr
    return np.asarray(Image.open(out))


@pytest.mark.gl
@pytest.mark.parametrize(
    ("name", "body", "reason"),
    [
        (
            "garbage-level",
            "return RenderSet([[40, 0, 0]], [0], [IndexVariant()])",
            "level 40 outside",
        ),
        ("exits", "raise SystemExit(3)", "SystemExit: 3"),
        ("own-interrupt", "raise KeyboardInterrupt('plugin')", "KeyboardInterrupt: plugin"),
        ("nothing", "return None", "returned NoneType"),
    ],
)
@pytest.mark.slow
def test_render_with_a_broken_provider_completes_with_the_fallback(
    plugin_site: PluginSite,
    tmp_path: Path,
    reference_png: np.ndarray,
    name: str,
    body: str,
    reason: str,
) -> None:
    add_lod(plugin_site, name, body)
    proc, out = render(plugin_site, tmp_path, name)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = stderr_lines(proc)
    assert len(lines) == 1 and name in lines[0] and reason in lines[0], lines
    assert proc.stdout.startswith("wrote ")
    assert np.array_equal(np.asarray(Image.open(out)), reference_png)
    assert not list(tmp_path.glob("*.tmp"))
    # The full traceback went to the log file the line names.
    log = Path(lines[0].rsplit("(details in ", 1)[1].rstrip(")"))
    entry = log.read_text().rsplit(f"plugin {name} failed and was disabled:", 1)[1]
    assert reason in entry
    if "raise" in body:  # raised by plugin code: the traceback reaches into it
        assert "Traceback (most recent call last)" in entry and "impl.py" in entry


@pytest.mark.slow
@pytest.mark.gl
def test_a_real_ctrl_c_during_select_interrupts_the_render(
    plugin_site: PluginSite, tmp_path: Path
) -> None:
    add_lod(
        plugin_site,
        "user-ctrl-c",
        "os.kill(os.getpid(), signal.SIGINT)\ntime.sleep(30)",
        prelude="import os, signal, time",
    )
    proc, out = render(plugin_site, tmp_path, "user-ctrl-c")
    assert proc.returncode == 130, proc.stderr
    assert "interrupted" in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists()


MARKER_MODULE = """
from pathlib import Path
Path({marker!r}).write_text("imported")
from globeview.plugins.api import LodProvider, Tool

class Provider(LodProvider):
    def select(self, view, terrain):
        raise AssertionError("never asked for")

class AnyTool(Tool):
    pass

class Layer:
    name = label = "x"
    extensions = (".x",)
    def __init__(self, context):
        pass
    def open(self, path):
        raise AssertionError("never asked for")
"""


@pytest.mark.slow
@pytest.mark.gl
def test_render_imports_only_the_plugins_it_uses(plugin_site: PluginSite, tmp_path: Path) -> None:
    markers = {}
    for kind, attr in (("lod", "Provider"), ("tool", "AnyTool"), ("layer", "Layer")):
        package = f"gvt_side_{kind}"
        markers[kind] = tmp_path / f"{kind}-imported"
        plugin_site.add(
            package,
            manifest(f"side-{kind}", package, kind, attr),
            {"impl": MARKER_MODULE.format(marker=str(markers[kind]))},
        )
    # One more that would print its own traceback if it were imported.
    plugin_site.add("gvt_side_boom", manifest("side-boom", "gvt_side_boom"), {"impl": "1 / 0\n"})
    proc, out = render(plugin_site, tmp_path, "chunked-sse")
    assert proc.returncode == 0, proc.stderr
    assert out.exists() and stderr_lines(proc) == []
    assert not [k for k, m in markers.items() if m.exists()]
    # Using the collapse tool loads that tool's plugin, not every tool plugin.
    folded = globeview(
        plugin_site,
        tmp_path / "config",
        "render",
        "--collapse=-10,0,10,0",
        "--size",
        SIZE,
        "--out",
        str(tmp_path / "folded.png"),
    )
    assert folded.returncode == 0 and stderr_lines(folded) == [], folded.stderr
    assert not [k for k, m in markers.items() if m.exists()]
    # The same command through the CLI's entry function, listing the modules it imported.
    listing = tmp_path / "modules.txt"
    code = (
        "import atexit, sys\n"
        f"atexit.register(lambda: open({str(listing)!r}, 'w').write('\\n'.join(sys.modules)))\n"
        "from globeview.cli import main\n"
        "sys.exit(main())\n"
    )
    args = ["render", "--size", SIZE, "--out", str(tmp_path / "again.png")]
    environ = {**os.environ, "PYTHONPATH": str(plugin_site.root)}
    environ["GLOBEVIEW_CONFIG_DIR"] = str(tmp_path / "config")
    again = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, env=environ
    )
    assert again.returncode == 0, again.stderr
    imported = set(listing.read_text().split())
    assert "globeview.plugins.builtin.chunked.provider" in imported  # the listing works
    unwanted = {
        "globeview.plugins.builtin.wavelet.provider",
        "globeview.plugins.builtin.regions.provider",
        "globeview.plugins.builtin.clod.provider",
        "globeview.plugins.builtin.collapse.tool",
        "gvt_side_boom.impl",
        "gvt_side_lod.impl",
        "gvt_side_tool.impl",
        "gvt_side_layer.impl",
    }
    assert not unwanted & imported


@pytest.mark.slow
def test_plugins_validate_other_is_quiet_about_broken_plugins(
    plugin_site: PluginSite, tmp_path: Path
) -> None:
    plugin_site.add("gvt_boom", manifest("boom", "gvt_boom"), {"impl": "raise SystemExit(1)\n"})
    plugin_site.add("gvt_badtoml", "", entry_name="bad-toml")
    (plugin_site.root / "gvt_badtoml" / "globeview.toml").write_bytes(b"name = \xff\xfe\n")
    proc = globeview(plugin_site, tmp_path, "plugins", "validate", "chunked-sse", "--import")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("valid: chunked-sse")
    assert "Traceback" not in proc.stderr
    # Nothing about the broken plugins: the invalid manifest is shown by `plugins list`, and
    # the import-failing plugin is never imported for validating another one.
    lines = stderr_lines(proc)
    assert lines == [], lines
    listed = globeview(plugin_site, tmp_path, "plugins", "list", "--check")
    assert listed.returncode == 0 and "Traceback" not in listed.stderr
    row = next(line for line in listed.stdout.splitlines() if line.startswith("boom "))
    assert "failed" in row and "SystemExit: 1" in row


@pytest.mark.slow
def test_plugins_validate_hostile_manifest_files(plugin_site: PluginSite, tmp_path: Path) -> None:
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)  # opening it for reading would block forever
    latin1 = tmp_path / "latin1.toml"
    latin1.write_bytes(b'name = "caf\xe9"\n')
    big = tmp_path / "big.toml"
    big.write_text('name = "x"\ndescription = "' + "d" * 10_000_000 + '"\n')
    cases = {
        str(fifo): "not a regular file",
        "/dev/null": "not a regular file",
        str(tmp_path): "a directory",
        str(latin1): "not UTF-8",
        str(big): "larger than 64 KiB",
    }
    for target, reason in cases.items():
        proc = globeview(plugin_site, tmp_path, "plugins", "validate", target)
        lines = stderr_lines(proc)
        assert proc.returncode == 2, (target, proc.stderr)
        assert len(lines) == 1 and lines[0].startswith("invalid: ") and reason in lines[0], lines


@pytest.mark.slow
def test_plugins_list_check_stays_json_and_validate_import_is_one_line(
    plugin_site: PluginSite, tmp_path: Path
) -> None:
    import json

    noisy = "print('hello from a plugin import')\nraise SystemExit(7)\n"
    plugin_site.add("gvt_noisy", manifest("noisy", "gvt_noisy"), {"impl": noisy})
    listed = globeview(plugin_site, tmp_path, "plugins", "list", "--json", "--check")
    assert listed.returncode == 0 and listed.stderr == "", listed.stderr
    rows = {r["name"]: r for r in json.loads(listed.stdout)}
    assert rows["noisy"]["status"] == "failed" and rows["noisy"]["error"] == "SystemExit: 7"
    assert "Traceback" in rows["noisy"]["traceback"]
    checked = globeview(plugin_site, tmp_path, "plugins", "validate", "noisy", "--import")
    assert checked.returncode == 2 and checked.stdout == ""
    assert stderr_lines(checked) == ["invalid: noisy: SystemExit: 7"]
