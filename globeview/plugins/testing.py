"""pytest fixtures for testing globeview plugins headless (a pytest plugin, ``pytest11``).

Installed with globeview, so a plugin's own test suite gets these fixtures with no conftest:

- ``globeview_config_dir``: a fresh config directory (``$GLOBEVIEW_CONFIG_DIR``) per test.
- ``globeview_registry``: a `PluginRegistry` on that directory, discovery done.
- ``headless_view``: a function ``(lon, lat, height, heading=0, pitch=-90, viewport=(800,
  600), **kw) -> ViewState`` for a camera at a geodetic position (degrees, metres).
- ``plugin_site``: a temporary site directory on ``sys.path`` where tests write throwaway
  plugin distributions (package + ``.dist-info`` with ``entry_points.txt``) that
  `importlib.metadata` discovers like pip-installed ones.

Nothing heavy is imported when pytest loads this module; each fixture imports what it needs.
"""

from __future__ import annotations

import importlib
import sys
import textwrap
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from globeview.plugins.registry import PluginRegistry
    from globeview.render.view_state import ViewState

__all__ = [
    "PluginSite",
    "globeview_config_dir",
    "globeview_registry",
    "headless_view",
    "make_view",
    "plugin_site",
]


def make_view(
    lon: float,
    lat: float,
    height: float,
    heading: float = 0.0,
    pitch: float = -90.0,
    viewport: tuple[int, int] = (800, 600),
    *,
    fovy_deg: float = 45.0,
    tau_px: float = 2.0,
    exaggeration: float = 1.0,
    speed_mps: float = 0.0,
) -> ViewState:
    """A `ViewState` for a camera at (lon, lat) degrees, ``height`` metres above WGS84,
    looking along (heading, pitch) degrees (pitch -90 = straight down)."""
    from globeview.render.camera import Camera
    from globeview.render.view_state import ViewState

    cam = Camera.from_lonlat(lon, lat, height, heading, pitch, fovy_deg=fovy_deg)
    return ViewState.from_camera(
        cam, viewport, tau_px=tau_px, exaggeration=exaggeration, speed_mps=speed_mps
    )


@pytest.fixture
def globeview_config_dir(tmp_path_factory: pytest.TempPathFactory, monkeypatch) -> Path:
    """An empty config directory, set as ``$GLOBEVIEW_CONFIG_DIR`` for the test."""
    d = tmp_path_factory.mktemp("globeview-config")
    monkeypatch.setenv("GLOBEVIEW_CONFIG_DIR", str(d))
    return d


@pytest.fixture
def globeview_registry(globeview_config_dir: Path) -> PluginRegistry:
    """A plugin registry persisting to the test's config dir, with discovery done."""
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import JsonFileSettings

    return PluginRegistry(JsonFileSettings(globeview_config_dir / "settings.json")).discover()


@pytest.fixture
def headless_view() -> Callable[..., ViewState]:
    """`make_view`: builds a ViewState for a camera at lon/lat/height."""
    return make_view


def plugin_manifest(
    name: str,
    package: str,
    kind: str = "lod",
    attr: str = "Provider",
    description: str = "test plugin",
) -> str:
    """The TOML manifest of a one-contribution plugin whose contribution is
    ``package.impl:attr`` (for `PluginSite.add` and plugin tests)."""
    return f"""
        name = "{name}"
        version = "0.0.1"
        description = "{description}"
        kinds = ["{kind}"]
        api_version = "1.0"

        [[contributions]]
        name = "{name}"
        kind = "{kind}"
        target = "{package}.impl:{attr}"
        """


class PluginSite:
    """A directory on ``sys.path`` holding throwaway plugin distributions.

    ``add`` writes a package and a ``<dist>.dist-info`` directory with ``METADATA`` and
    ``entry_points.txt``: the same files pip writes, so discovery finds the plugin through
    `importlib.metadata.entry_points` as it finds a pip-installed one.
    """

    def __init__(self, root: Path) -> None:
        self.root = root
        self.packages: list[str] = []

    def add(
        self,
        package: str,
        manifest: str,
        modules: dict[str, str] | None = None,
        *,
        entry_name: str | None = None,
        dist_name: str | None = None,
        version: str = "0.1.0",
        manifest_file: str = "globeview.toml",
    ) -> Path:
        """Write plugin package ``package`` with ``manifest`` (TOML text) and ``modules``
        ({relative module path, e.g. "__init__" or "tools": source}) and register its entry
        point ``entry_name`` (default: the manifest's name, else the package name).
        Returns the package directory."""
        import tomllib

        pkg_dir = self.root / package
        pkg_dir.mkdir(parents=True, exist_ok=True)
        mods = {"__init__": ""} | dict(modules or {})
        for rel, src in mods.items():
            path = pkg_dir.joinpath(*rel.split(".")).with_suffix(".py")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(textwrap.dedent(src), encoding="utf-8")
        manifest_text = textwrap.dedent(manifest)
        (pkg_dir / manifest_file).write_text(manifest_text, encoding="utf-8")
        if entry_name is None:
            try:
                entry_name = str(tomllib.loads(manifest_text).get("name") or package)
            except tomllib.TOMLDecodeError:
                entry_name = package
        dist = dist_name or package.replace("_", "-")
        info = self.root / f"{dist.replace('-', '_')}-{version}.dist-info"
        info.mkdir(exist_ok=True)
        (info / "METADATA").write_text(
            f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n", encoding="utf-8"
        )
        (info / "entry_points.txt").write_text(
            f"[globeview.plugins]\n{entry_name} = {package}:{manifest_file}\n", encoding="utf-8"
        )
        self.packages.append(package)
        importlib.invalidate_caches()
        return pkg_dir

    def forget_modules(self) -> None:
        """Remove the site's packages from ``sys.modules``."""
        for name in list(sys.modules):
            if name.split(".")[0] in self.packages:
                del sys.modules[name]


@pytest.fixture
def plugin_site(tmp_path_factory: pytest.TempPathFactory, monkeypatch) -> Iterator[PluginSite]:
    """A `PluginSite` on ``sys.path`` for this test; its modules are unloaded afterwards."""
    root = tmp_path_factory.mktemp("plugin-site")
    monkeypatch.syspath_prepend(str(root))
    site = PluginSite(root)
    yield site
    site.forget_modules()
    importlib.invalidate_caches()
