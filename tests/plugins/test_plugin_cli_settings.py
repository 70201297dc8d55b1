"""`globeview plugins set NAME.KEY VALUE` / `plugins get NAME[.KEY]` and `plugins validate
--import` (issue #15 items 5 and 11), as real processes of `.venv/bin/globeview` (forked by
`zygote` from its pre-warmed server: exit status, stdout and stderr of a process of their own,
without the ~1 CPU-s interpreter start) with an installed (real distribution, entry point)
plugin on PYTHONPATH.

The contract: a setting is checked against its `Setting` (type, range, choices) and stored in
``$GLOBEVIEW_CONFIG_DIR/settings.json`` atomically; a bad name or value is one line, exit 2,
and the file is unchanged; a corrupt settings file is kept aside, never lost; what is stored
is what the next render uses.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zygote
from PIL import Image

from globeview.app.testing import PluginSite, plugin_manifest

GLOBEVIEW = Path(sys.executable).with_name("globeview")

TOOL = """
from globeview.plugins.api import Marker, Setting, Tool, lonlat_to_ecef

COLOURS = {"green": (0.0, 1.0, 0.0, 1.0), "blue": (0.0, 0.0, 1.0, 1.0)}

class Pins(Tool):
    settings = (
        Setting("size_px", "float", 14.0, min=4.0, max=40.0, help="pin size, pixels"),
        Setting("count", "int", 3, min=1, max=9),
        Setting("colour", "choice", "green", choices=("green", "blue")),
        Setting("labels", "bool", False),
    )

    def __init__(self, context=None):
        super().__init__(context)
        self.pins = []

    def on_mouse(self, event):
        if event.kind == "press" and event.lonlat is not None:
            self.pins.append(tuple(float(v) for v in lonlat_to_ecef(*event.lonlat[:2], 0.0)))
            return True
        return False

    def overlay(self, view):
        colour = COLOURS[self.values["colour"]]
        return [Marker(p, colour, self.values["size_px"]) for p in self.pins]
"""


def run(site: PluginSite, config: Path, *args: str, **env: str) -> subprocess.CompletedProcess:
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


@pytest.fixture
def site(plugin_site: PluginSite) -> PluginSite:
    plugin_site.add("gvt_setpins", plugin_manifest("gvt-setpins", "gvt_setpins", "tool", "Pins"),
                    {"impl": TOOL})  # fmt: skip
    return plugin_site


def stored(config: Path) -> dict:
    return json.loads((config / "settings.json").read_text())[
        "plugins/gvt-setpins/contributions/gvt-setpins"
    ]


@pytest.mark.slow
def test_set_stores_checked_values_and_get_reads_them(site: PluginSite, tmp_path: Path) -> None:
    config = tmp_path / "config"
    proc = run(site, config, "plugins", "get", "gvt-setpins")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == [
        "gvt-setpins.size_px = 14.0  (default; float in 4..40, default 14.0)",
        "gvt-setpins.count = 3  (default; int in 1..9, default 3)",
        "gvt-setpins.colour = green  (default; one of green, blue, default green)",
        "gvt-setpins.labels = false  (default; true or false, default false)",
    ]
    for key, value, shown in [
        ("size_px", "22.5", "22.5"),
        ("count", "7", "7"),
        ("colour", "blue", "blue"),
        ("labels", "yes", "true"),
    ]:
        proc = run(site, config, "plugins", "set", f"gvt-setpins.{key}", value)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.strip() == (
            f"gvt-setpins.{key} = {shown} (saved in {config / 'settings.json'})"
        )
    assert stored(config) == {"size_px": 22.5, "count": 7, "colour": "blue", "labels": True}
    proc = run(site, config, "plugins", "get", "gvt-setpins.colour")
    assert proc.returncode == 0 and proc.stdout == "blue\n"
    proc = run(site, config, "plugins", "get", "gvt-setpins")
    assert "gvt-setpins.count = 7  (stored; int in 1..9, default 3)" in proc.stdout
    # --default forgets the stored value.
    proc = run(site, config, "plugins", "set", "gvt-setpins.count", "--default")
    assert proc.returncode == 0, proc.stderr
    assert "count" not in stored(config)
    assert run(site, config, "plugins", "get", "gvt-setpins.count").stdout == "3\n"


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("gvt-setpins.count", "2.5"), "count: '2.5' is not a whole number (int in 1..9)"),
        (("gvt-setpins.count", "10"), "gvt-setpins.count: 10 is outside 1..9"),
        (("gvt-setpins.size_px", "inf"), "is not a finite number"),
        (("gvt-setpins.colour", "red"), "'red' is not offered (one of green, blue)"),
        (("gvt-setpins.labels", "maybe"), "'maybe' is not a boolean (true or false)"),
        (("gvt-setpins.nope", "1"), "gvt-setpins has no setting 'nope' (settings: size_px"),
        (("nobody.x", "1"), "no plugin contribution named 'nobody' (known: "),
        (("gvt-setpins", "1"), "plugins set takes NAME.KEY VALUE"),
        (("gvt-setpins.count",), "give a VALUE or --default"),
    ],
)  # fmt: skip
def test_bad_settings_are_one_line_and_leave_the_file_alone(
    site: PluginSite, tmp_path: Path, args: tuple[str, ...], message: str
) -> None:
    config = tmp_path / "config"
    assert run(site, config, "plugins", "set", "gvt-setpins.count", "5").returncode == 0
    before = (config / "settings.json").read_bytes()
    proc = run(site, config, "plugins", "set", *args)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.startswith("globeview: error: ") and proc.stderr.count("\n") == 1
    assert message in proc.stderr, proc.stderr
    assert (config / "settings.json").read_bytes() == before


@pytest.mark.slow
def test_a_failed_write_leaves_the_settings_file_whole(site: PluginSite, tmp_path: Path) -> None:
    config = tmp_path / "config"
    assert run(site, config, "plugins", "set", "gvt-setpins.count", "5").returncode == 0
    before = (config / "settings.json").read_bytes()
    proc = run(
        site, config, "plugins", "set", "gvt-setpins.count", "6", GLOBEVIEW_FAULT_WRITE="enospc"
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "settings.json" in proc.stderr and "Traceback" not in proc.stderr
    assert (config / "settings.json").read_bytes() == before
    left = sorted(p.name for p in config.iterdir())
    assert left == ["settings.json", "settings.json.lock"]  # no temporaries


@pytest.mark.slow
def test_a_corrupt_settings_file_is_kept_aside_not_lost(site: PluginSite, tmp_path: Path) -> None:
    config = tmp_path / "config"
    config.mkdir()
    garbage = b'{"plugins/enabled": {"x": tru'  # half a file from some other program
    (config / "settings.json").write_bytes(garbage)
    proc = run(site, config, "plugins", "set", "gvt-setpins.count", "4")
    assert proc.returncode == 0, proc.stderr
    assert stored(config) == {"count": 4}
    aside = [p for p in config.iterdir() if p.name.startswith("settings.json.corrupt-")]
    assert len(aside) == 1 and aside[0].read_bytes() == garbage
    assert "kept as" in proc.stderr and proc.stderr.count("\n") == 1  # one warning line


@pytest.mark.slow
@pytest.mark.gl
def test_stored_setting_is_what_the_next_render_uses(site: PluginSite, tmp_path: Path) -> None:
    config = tmp_path / "config"

    def centre_pixel(name: str, *extra: str) -> np.ndarray:
        out = tmp_path / f"{name}.png"
        proc = run(
            site, config, "render", "--no-borders", "--size", "96x64", "--camera",
            "0,0,20000000", "--tool", "gvt-setpins", "--point", "0,0", "--out", str(out), *extra,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        return np.asarray(Image.open(out).convert("RGB")).astype(int)[32, 48]

    green = centre_pixel("green")
    assert green[1] > 200 and green[2] < 80
    assert run(site, config, "plugins", "set", "gvt-setpins.colour", "blue").returncode == 0
    blue = centre_pixel("blue")
    assert blue[2] > 200 and blue[1] < 80
    # --set overrides the stored value for one render.
    again = centre_pixel("again", "--set", "gvt-setpins.colour=green")
    assert again[1] > 200 and again[2] < 80
    assert stored(config) == {"colour": "blue"}


TWO_KINDS = """
name = "gvt-halfbroken"
version = "0.0.1"
description = "a provider that loads and a tool whose module does not import"
kinds = ["lod", "tool"]
api_version = "1.0"

[[contributions]]
name = "gvt-halfbroken"
kind = "lod"
target = "gvt_halfbroken.good:Provider"

[[contributions]]
name = "gvt-halfbroken-tool"
kind = "tool"
target = "gvt_halfbroken.bad:Tool"
"""

GOOD = """
from globeview.plugins.api import LodProvider, Setting

class Provider(LodProvider):
    settings = (Setting("level", "int", 3, min=0, max=9),)

    def select(self, view, terrain):
        raise NotImplementedError
"""


@pytest.mark.slow
def test_validate_import_says_what_it_imported(site: PluginSite, tmp_path: Path) -> None:
    config = tmp_path / "config"
    plain = run(site, config, "plugins", "validate", "gvt-setpins")
    imported = run(site, config, "plugins", "validate", "gvt-setpins", "--import")
    assert plain.returncode == imported.returncode == 0
    assert plain.stdout != imported.stdout
    assert plain.stdout.strip() == (
        "valid: gvt-setpins 0.0.1 (tool; 1 contribution; API 1.0) "
        "(manifest only; --import also loads the code)"
    )
    assert imported.stdout.strip() == (
        "valid: gvt-setpins 0.0.1 (tool; 1 contribution; API 1.0); imported and created "
        "gvt-setpins (tool: Pins, 4 settings)"
    )


@pytest.mark.slow
def test_validate_import_names_the_contribution_that_fails(
    site: PluginSite, tmp_path: Path
) -> None:
    site.add(
        "gvt_halfbroken",
        TWO_KINDS,
        {"good": GOOD, "bad": "raise ImportError('needs libfoo')\n"},
    )
    config = tmp_path / "config"
    assert run(site, config, "plugins", "validate", "gvt-halfbroken").returncode == 0
    proc = run(site, config, "plugins", "validate", "gvt-halfbroken", "--import")
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip() == (
        "invalid: gvt-halfbroken: gvt-halfbroken-tool: ImportError: needs libfoo"
    )


@pytest.mark.slow
def test_a_config_dir_that_is_a_file_is_one_line(site: PluginSite, tmp_path: Path) -> None:
    not_a_folder = tmp_path / "config"
    not_a_folder.write_text("mine\n")
    proc = run(site, not_a_folder, "plugins", "set", "gvt-setpins.count", "4")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert (
        f"{not_a_folder} is not a folder" in proc.stderr and "GLOBEVIEW_CONFIG_DIR" in proc.stderr
    )
    assert not_a_folder.read_text() == "mine\n"


@pytest.mark.slow
def test_get_says_when_a_stored_value_is_not_used_as_stored(
    site: PluginSite, tmp_path: Path
) -> None:
    config = tmp_path / "config"
    config.mkdir()
    key = "plugins/gvt-setpins/contributions/gvt-setpins"
    (config / "settings.json").write_text(
        json.dumps({key: {"count": "lots", "size_px": 400, "colour": "blue"}})
    )
    proc = run(site, config, "plugins", "get", "gvt-setpins")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout.splitlines()
    assert (
        out[0]
        == "gvt-setpins.size_px = 40.0  (stored '400', read as 40.0; float in 4..40, default 14.0)"
    )
    assert out[1] == "gvt-setpins.count = 3  (stored 'lots', read as 3; int in 1..9, default 3)"
    assert out[2] == "gvt-setpins.colour = blue  (stored; one of green, blue, default green)"


WRITER = """
import sys
from globeview.plugins.settings import JsonFileSettings

settings = JsonFileSettings(sys.argv[1])
for j in range(15):
    settings.set(f"plugins/p{sys.argv[2]}/k{j}", j)
"""


@pytest.mark.slow
def test_concurrent_writers_lose_no_update(tmp_path: Path) -> None:
    """Six processes setting different keys at once (a `plugins set` beside a render, two
    windows): every key is there afterwards (without the lock about 40% were lost)."""
    path = tmp_path / "settings.json"
    procs = [subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(i)]) for i in range(6)]
    assert [p.wait(timeout=120) for p in procs] == [0] * 6
    data = json.loads(path.read_text())
    assert len(data) == 6 * 15 and data["plugins/p5/k14"] == 14


BAD_SETTINGS = """
from globeview.plugins.api import Setting, Tool

class Sloppy(Tool):
    settings = (
        Setting("size", "float", 100.0, min=1.0, max=10.0),
        Setting("size", "int", 1),
        Setting("mode", "choice", "fast"),
        Setting("flag", "bool", "yes"),
        Setting("span", "int", 5, min=9, max=1),
    )
"""


@pytest.mark.slow
def test_validate_import_checks_settings_declarations(site: PluginSite, tmp_path: Path) -> None:
    site.add("gvt_sloppy", plugin_manifest("gvt-sloppy", "gvt_sloppy", "tool", "Sloppy"),
             {"impl": BAD_SETTINGS})  # fmt: skip
    config = tmp_path / "config"
    assert run(site, config, "plugins", "validate", "gvt-sloppy").returncode == 0
    proc = run(site, config, "plugins", "validate", "gvt-sloppy", "--import")
    assert proc.returncode == 2 and proc.stdout == "" and proc.stderr.count("\n") == 1
    assert proc.stderr.strip() == (
        "invalid: gvt-sloppy: gvt-sloppy: setting 'size': default 100.0 is outside 1..10; "
        "gvt-sloppy: setting 'size' declared twice; "
        "gvt-sloppy: setting 'mode': a choice with no choices; "
        "gvt-sloppy: setting 'mode': default 'fast' is not offered; "
        "gvt-sloppy: setting 'flag': default 'yes' is not a boolean; "
        "gvt-sloppy: setting 'span': min 9 > max 1; "
        "gvt-sloppy: setting 'span': default 5 is outside 9..1"
    )
