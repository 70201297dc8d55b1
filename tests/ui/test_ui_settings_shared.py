"""The window and the command line share one plugin settings file (issue #15 item 5):
`globeview plugins set/disable` reach the window, the window's changes reach `plugins get`,
plugin settings the window kept in its Qt settings are carried over once, and a settings file
that cannot be written never breaks the window."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
from PyQt6.QtCore import QSettings

from globeview.plugins.api import PluginKind

pytestmark = pytest.mark.gui

GLOBEVIEW = Path(sys.executable).with_name("globeview")


def cli(config: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "GLOBEVIEW_CONFIG_DIR": str(config)}
    return subprocess.run(
        [str(GLOBEVIEW), *args], capture_output=True, text=True, env=env, timeout=120
    )


@pytest.fixture
def config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    d = tmp_path / "config"
    monkeypatch.setenv("GLOBEVIEW_CONFIG_DIR", str(d))
    return d


def qsettings(tmp_path: Path) -> QSettings:
    return QSettings(str(tmp_path / "window.ini"), QSettings.Format.IniFormat)


def test_cli_settings_reach_the_window_and_back(make_window, tmp_path: Path, config: Path):
    from globeview.ui.app import plugin_registry

    assert cli(config, "plugins", "set", "collapse.ratio", "0.35").returncode == 0
    assert cli(config, "plugins", "disable", "wavelet").returncode == 0
    win = make_window(registry=plugin_registry(qsettings(tmp_path)))
    registry = win.plugins.registry
    assert registry.find(PluginKind.TOOL, "collapse").values["ratio"] == 0.35
    assert not registry.get("wavelet").enabled
    # The window's own change (what the Tool options bar does) reaches `plugins get`.
    tool = registry.find(PluginKind.TOOL, "collapse")
    registry.configure(tool, {**tool.values, "ratio": 0.6})
    got = cli(config, "plugins", "get", "collapse.ratio")
    assert got.returncode == 0 and got.stdout == "0.6\n"


def test_qt_plugin_settings_are_carried_over_once(tmp_path: Path, config: Path) -> None:
    from globeview.ui.app import plugin_registry

    old = qsettings(tmp_path)
    old.setValue("plugins/enabled", json.dumps({"wavelet": False}))
    old.setValue("plugins/collapse/contributions/collapse", json.dumps({"ratio": 0.4}))
    old.setValue("window/geometry", "not a plugin key")
    old.sync()
    registry = plugin_registry(old).discover()
    assert not registry.get("wavelet").enabled
    stored = json.loads((config / "settings.json").read_text())
    assert stored == {
        "plugins/enabled": {"wavelet": False},
        "plugins/collapse/contributions/collapse": {"ratio": 0.4},
    }
    # Once: what the file holds now wins over the Qt copy.
    assert cli(config, "plugins", "enable", "wavelet").returncode == 0
    assert plugin_registry(old).discover().get("wavelet").enabled
    # ... and a user who deletes the file to start afresh does not get the Qt values back.
    (config / "settings.json").unlink()
    assert plugin_registry(old).discover().get("wavelet").enabled
    assert (
        not (config / "settings.json").exists()
        or "wavelet" not in (config / "settings.json").read_text()
    )


def test_an_unwritable_settings_file_never_breaks_the_window(
    make_window, tmp_path: Path, config: Path, monkeypatch, caplog
) -> None:
    from globeview.ui.app import plugin_registry

    monkeypatch.setenv("GLOBEVIEW_FAULT_WRITE", "erofs")  # every atomic write fails
    win = make_window(registry=plugin_registry(qsettings(tmp_path)))
    registry = win.plugins.registry
    tool = registry.find(PluginKind.TOOL, "collapse")
    with caplog.at_level(logging.WARNING, logger="globeview.plugins"):
        registry.configure(tool, {**tool.values, "ratio": 0.5})
        registry.configure(tool, {**tool.values, "ratio": 0.7})
    assert tool.values["ratio"] == 0.7  # applied for the session
    warnings = [r.getMessage() for r in caplog.records if "not saved" in r.getMessage()]
    assert len(warnings) == 1 and "read-only" in warnings[0]
    assert not (config / "settings.json").exists()
