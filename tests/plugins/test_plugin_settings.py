"""Settings backends, per-plugin settings, and `Setting` value coercion."""

from __future__ import annotations

from pathlib import Path

import pytest

from globeview.plugins.api import Setting, resolve_settings
from globeview.plugins.settings import (
    JsonFileSettings,
    MemorySettings,
    PluginSettings,
    SettingsBackend,
    config_dir,
    default_settings,
)


def test_config_dir_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("GLOBEVIEW_CONFIG_DIR", str(tmp_path / "a"))
    assert config_dir() == tmp_path / "a"
    assert default_settings().path == tmp_path / "a" / "settings.json"
    monkeypatch.delenv("GLOBEVIEW_CONFIG_DIR")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    assert config_dir() == tmp_path / "xdg" / "globeview"


def test_json_file_settings_roundtrip(tmp_path: Path) -> None:
    path = tmp_path / "deep" / "settings.json"
    s = JsonFileSettings(path)
    assert isinstance(s, SettingsBackend)
    assert s.get("k", 7) == 7
    s.set("k", {"a": [1, 2.5, True, None]})
    assert JsonFileSettings(path).get("k") == {"a": [1, 2.5, True, None]}
    path.write_text("{ not json")
    assert s.get("k", "fallback") == "fallback"  # corrupt file reads as empty
    s.set("k", 1)
    assert JsonFileSettings(path).get("k") == 1


def test_memory_settings_rejects_non_json() -> None:
    s = MemorySettings()
    with pytest.raises(TypeError):
        s.set("k", object())


def test_plugin_settings_mapping() -> None:
    backend = MemorySettings()
    ps = PluginSettings(backend, "demo")
    ps["colour"] = "red"
    ps["n"] = 3
    assert dict(ps) == {"colour": "red", "n": 3} and len(ps) == 2
    del ps["n"]
    assert backend.get("plugins/demo/settings") == {"colour": "red"}
    assert dict(PluginSettings(backend, "other")) == {}


def test_setting_coerce() -> None:
    lvl = Setting("level", "int", 3, min=0, max=12)
    assert lvl.coerce("5") == 5 and lvl.coerce(40) == 12 and lvl.coerce(-1) == 0
    assert Setting("t", "float", 1.0, min=0.5).coerce(0.1) == 0.5
    b = Setting("b", "bool", False)
    assert b.coerce("yes") is True and b.coerce("off") is False
    with pytest.raises(ValueError, match="not a boolean"):
        b.coerce("maybe")
    c = Setting("mode", "choice", "a", choices=("a", "b"))
    assert c.coerce("b") == "b"
    with pytest.raises(ValueError, match="not one of"):
        c.coerce("z")
    # Stale or bad stored values fall back to defaults; unknown keys are dropped.
    assert resolve_settings([lvl, c], {"level": "x", "mode": "b", "gone": 1}) == {
        "level": 3,
        "mode": "b",
    }
