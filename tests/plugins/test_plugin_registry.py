"""Discovery through real entry points, enable/disable persistence, lazy loading, and the
installed example plugin (examples/globeview-fixedlevel, pip-installed editable)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from globeview.lod.render_set import RenderSet
from globeview.plugins.api import KeyEvent, LodProvider, Marker, PointerEvent, Tool
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import ENABLED_KEY, JsonFileSettings
from globeview.terrain.quadtree import level_shape


def test_discovery_lists_builtin_and_example(globeview_registry: PluginRegistry) -> None:
    rec = globeview_registry.get("chunked-sse")
    assert rec.builtin and rec.source.startswith("globeview ")
    assert rec.enabled and rec.status == "ok" and rec.kinds == ("lod",)
    ex = globeview_registry.get("fixed-level")
    assert not ex.builtin and ex.source == "globeview-fixedlevel 0.1.0"
    assert ex.enabled and ex.status == "ok" and ex.error is None
    assert ex.kinds == ("lod", "tool", "layer")
    # Built-ins come first.
    assert next(iter(globeview_registry)).builtin


def test_unknown_plugin_name_lists_known(globeview_registry: PluginRegistry) -> None:
    with pytest.raises(KeyError, match="fixed-level"):
        globeview_registry.get("nope")


def test_enable_disable_persists(globeview_config_dir: Path) -> None:
    settings_file = globeview_config_dir / "settings.json"
    reg = PluginRegistry(JsonFileSettings(settings_file)).discover()
    reg.disable("fixed-level")
    assert reg.get("fixed-level").status == "disabled"
    assert "fixed-level" not in reg.lod_providers()
    assert reg.load_contribution("fixed-level", "fixed-level") is None

    again = PluginRegistry(JsonFileSettings(settings_file)).discover()
    assert not again.get("fixed-level").enabled
    assert again.get("fixed-level").status == "disabled"
    assert again.get("chunked-sse").enabled  # untouched plugins keep the default
    assert JsonFileSettings(settings_file).get(ENABLED_KEY) == {"fixed-level": False}

    again.enable("fixed-level")
    third = PluginRegistry(JsonFileSettings(settings_file)).discover()
    assert third.get("fixed-level").enabled and third.get("fixed-level").status == "ok"


def test_default_registry_uses_config_dir_env(globeview_config_dir: Path) -> None:
    reg = PluginRegistry().discover()
    reg.disable("fixed-level")
    assert (globeview_config_dir / "settings.json").is_file()


def test_enabling_loads_example_contributions(globeview_registry: PluginRegistry) -> None:
    providers = globeview_registry.lod_providers()
    provider = providers["fixed-level"]
    assert isinstance(provider, LodProvider)
    assert type(provider).__module__ == "globeview_fixedlevel.provider"
    assert globeview_registry.owner_of(provider) == "fixed-level"
    assert provider.context is not None
    assert provider.context.logger.name == "globeview.plugins.fixed-level"
    tool = globeview_registry.tools()["marker"]
    assert isinstance(tool, Tool)
    # Loaded once: the same object on every request.
    assert globeview_registry.lod_providers()["fixed-level"] is provider
    assert "globeview_fixedlevel.provider" in sys.modules


def test_fixed_level_select_sensible(globeview_registry: PluginRegistry, headless_view) -> None:
    provider = globeview_registry.lod_providers()["fixed-level"]
    view = headless_view(10.0, 45.0, 2.0e6)
    rs = globeview_registry.select(provider, view, None)
    assert isinstance(rs, RenderSet) and len(rs) > 0
    assert np.all(rs.keys[:, 0] == 3)  # the default level
    ncols, nrows = level_shape(3)
    assert np.all((rs.keys[:, 1] >= 0) & (rs.keys[:, 1] < ncols))
    assert np.all((rs.keys[:, 2] >= 0) & (rs.keys[:, 2] < nrows))
    assert len(np.unique(rs.keys, axis=0)) == len(rs)
    # The tile under the camera (lon 10, lat 45 -> column 8, row 1 at level 3) is drawn, and
    # the far side of the globe is not.
    assert any((k[1], k[2]) == (8, 1) for k in rs.keys)
    assert not any(k[1] in (0, 15) for k in rs.keys)  # lon -180..-135 and 157.5..180
    assert rs.stats["tiles_culled_horizon"] + rs.stats["tiles_culled_frustum"] > 0
    for k, vid in zip(rs.keys, rs.variant_ids, strict=True):
        v = rs.variants[vid]
        assert v.stride == 1 and v.skirts
        assert v.pole == ("north" if k[2] == 0 else "south" if k[2] == nrows - 1 else None)


def test_fixed_level_configure_and_budget(globeview_registry: PluginRegistry, headless_view):
    provider = globeview_registry.lod_providers()["fixed-level"]
    globeview_registry.configure(provider, {"level": 6, "max_tiles": 5})
    view = headless_view(10.0, 45.0, 5.0e5)
    rs = globeview_registry.select(provider, view, None)
    assert len(rs) == 5 and np.all(rs.keys[:, 0] == 6)
    assert rs.stats["tiles_over_budget"] > 0
    # The setting persisted: a new registry's provider starts configured.
    reg2 = PluginRegistry(globeview_registry.settings).discover()
    assert reg2.lod_providers()["fixed-level"].values == {"level": 6, "max_tiles": 5}
    # Out-of-range values clamp; the pole rows get fans at level 0 too.
    provider.configure({"level": 99})
    assert provider.values["level"] == 12
    provider.configure({"level": 0})
    rs0 = provider.select(headless_view(0.0, 0.0, 2.0e7), None)
    assert set(map(tuple, rs0.keys[:, :1].tolist())) == {(0,)} and len(rs0) >= 1


def test_marker_tool_events_and_overlay(globeview_registry: PluginRegistry, headless_view):
    tool = globeview_registry.tools()["marker"]
    ev = PointerEvent(
        10, 20, "press", button="left", picked=(6.0e6, 1.0e6, 1.0e6), lonlat=(9.5, 9.0, 0.0)
    )
    assert globeview_registry.invoke(tool, "on_mouse", ev, default=False) is True
    assert not tool.on_mouse(PointerEvent(10, 20, "move"))
    assert not tool.on_mouse(PointerEvent(10, 20, "press", button="left"))  # sky: no pick
    overlay = tool.overlay(headless_view(10.0, 10.0, 1e6))
    assert overlay == [Marker((6.0e6, 1.0e6, 1.0e6), size_px=10.0, label="1")]
    assert tool.markers == [(9.5, 9.0, 0.0)]
    assert tool.context.renderer.redraws == 1
    assert tool.on_key(KeyEvent("Escape")) and tool.overlay(None) == []
    assert tool.displacement_glsl() is None
    pts = np.array([[1.0, 2.0, 3.0]])
    assert np.array_equal(tool.displacement_numpy(pts), pts)
