"""Persistent application settings for plugins: a tiny backend protocol and a JSON file.

Keys are ``/``-separated strings (``plugins/enabled``, ``plugins/<name>/settings``), values
JSON-able (dicts, lists, str, numbers, bools, None). The Qt UI plugs a QSettings-backed object
into the same `SettingsBackend` protocol; headless code and tests use `JsonFileSettings` in
the user's config directory (see `config_dir`) or `MemorySettings`.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator, MutableMapping
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

__all__ = [
    "ENABLED_KEY",
    "JsonFileSettings",
    "MemorySettings",
    "PluginSettings",
    "SettingsBackend",
    "config_dir",
    "default_settings",
]

#: Key of the {plugin name: enabled} choices the user made.
ENABLED_KEY = "plugins/enabled"


@runtime_checkable
class SettingsBackend(Protocol):
    """Get and set JSON-able values by key."""

    def get(self, key: str, default: Any = None) -> Any: ...

    def set(self, key: str, value: Any) -> None: ...


def config_dir() -> Path:
    """The user's globeview config directory.

    ``$GLOBEVIEW_CONFIG_DIR`` if set (tests point it at a tmp dir), else
    ``$XDG_CONFIG_HOME/globeview``, else ``~/.config/globeview``.
    """
    env = os.environ.get("GLOBEVIEW_CONFIG_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CONFIG_HOME")
    base = Path(xdg) if xdg else Path.home() / ".config"
    return base / "globeview"


class MemorySettings:
    """Settings held in a dict (nothing persists)."""

    def __init__(self, data: dict[str, Any] | None = None) -> None:
        self.data: dict[str, Any] = dict(data or {})

    def get(self, key: str, default: Any = None) -> Any:
        return json.loads(json.dumps(self.data[key])) if key in self.data else default

    def set(self, key: str, value: Any) -> None:
        self.data[key] = json.loads(json.dumps(value))  # JSON-able check and a private copy


class JsonFileSettings:
    """Settings in one JSON object file, re-read on every ``get`` and rewritten atomically on
    every ``set`` (so two registries on the same file see each other's changes).

    A missing file reads as empty; an unreadable or corrupt one too (it is replaced on the
    next write), so a damaged settings file never stops the application.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def _load(self) -> dict[str, Any]:
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}
        return data if isinstance(data, dict) else {}

    def get(self, key: str, default: Any = None) -> Any:
        return self._load().get(key, default)

    def set(self, key: str, value: Any) -> None:
        data = self._load()
        data[key] = value
        text = json.dumps(data, indent=2, sort_keys=True)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=".settings-", suffix=".json")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text + "\n")
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise


def default_settings() -> JsonFileSettings:
    """The JSON settings file in `config_dir` (``settings.json``)."""
    return JsonFileSettings(config_dir() / "settings.json")


class PluginSettings(MutableMapping[str, Any]):
    """One plugin's settings: a dict-like view of key ``plugins/<name>/settings`` in a backend.

    Every write stores the whole dict at once.
    """

    def __init__(self, backend: SettingsBackend, plugin_name: str) -> None:
        self._backend = backend
        self._key = f"plugins/{plugin_name}/settings"

    def _data(self) -> dict[str, Any]:
        data = self._backend.get(self._key, None)
        return dict(data) if isinstance(data, dict) else {}

    def __getitem__(self, key: str) -> Any:
        return self._data()[key]

    def __setitem__(self, key: str, value: Any) -> None:
        data = self._data()
        data[key] = value
        self._backend.set(self._key, data)

    def __delitem__(self, key: str) -> None:
        data = self._data()
        del data[key]
        self._backend.set(self._key, data)

    def __iter__(self) -> Iterator[str]:
        return iter(self._data())

    def __len__(self) -> int:
        return len(self._data())

    def __repr__(self) -> str:
        return f"PluginSettings({self._key!r}, {self._data()!r})"
