"""Plugin API 1.3 (issue #28 item 4): the tool contract declared.

- `Tool.animate` and `Tool.plot`, which the host called without `Tool` declaring them, are
  declared with neutral defaults, and a tool's plot reaches the window and ``render
  --tool-csv`` through the tool host (`ToolHost.plot`), checked there once;
- `TwoPointPick`: the "click A, then B, a third click restarts, Escape clears" picking the
  measure and collapse tools shared as two copies;
- shared `Setting` declarations (`TILE_BUDGET`, `TEXEL_SIZE`, `TAU_OVERRIDE`) that the
  built-in providers use instead of copies;
- a plugin declaring 1.3 loads, and 1.0 / 1.1 / 1.2 plugins still do.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from globeview.app.testing import PluginSite, plugin_manifest
from globeview.plugins.api import KeyEvent, PointerEvent

A, B, C = (10.0, 46.0), (11.5, 47.25), (-71.3, 44.27)


def _press(lonlat, button="left", kind="press") -> PointerEvent:
    ll = None if lonlat is None else (*lonlat, 0.0)
    return PointerEvent(1.0, 2.0, kind, button=button, lonlat=ll)


# -- the version ---------------------------------------------------------------------------
def test_api_version_is_1_4_and_older_minors_load(plugin_site: PluginSite) -> None:
    from globeview.plugins.api import API_VERSION
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    assert API_VERSION == "1.4"  # 1.4: the flat selection (tests/plugins/test_plugin_api_1_4.py)
    impl = "from globeview.plugins.api import Tool\nclass T(Tool):\n    pass\n"
    versions = ("1.0", "1.1", "1.2", "1.3", "1.4")
    for version in versions:
        pkg = f"gvt_w{version.replace('.', '_')}"
        manifest = plugin_manifest(f"gvt-w{version}", pkg, "tool", "T").replace(
            'api_version = "1.0"', f'api_version = "{version}"'
        )
        plugin_site.add(pkg, manifest, {"impl": impl})
    reg = PluginRegistry(MemorySettings()).discover()
    for version in versions:
        rec = reg.get(f"gvt-w{version}")
        assert rec.status == "ok", (version, rec.error)
        assert reg.find("tool", f"gvt-w{version}") is not None


def test_new_names_are_in_the_facade() -> None:
    import globeview.plugins.api as api

    for name in ("TwoPointPick", "TILE_BUDGET", "TEXEL_SIZE", "TAU_OVERRIDE"):
        assert name in api.__all__ and getattr(api, name) is not None


# -- the tool contract -------------------------------------------------------------------------
def test_tool_declares_animate_and_plot_with_neutral_defaults() -> None:
    from globeview.plugins.api import Tool

    tool = Tool()
    assert tool.animate(0.0) is False and tool.animate(12.5) is False
    assert tool.plot() is None
    for method in ("animate", "plot"):
        assert (getattr(Tool, method).__doc__ or "").strip(), method


def _tool_host(plugin_site: PluginSite, impl: str):
    """A `ToolHost` on a fresh globe with the throwaway tool ``gvt-plotter`` active: no
    renderer, no GL (publishing a plot needs neither)."""
    from globeview.app.tool_host import ToolHost
    from globeview.model.globe import Globe
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.terrain.compose.stack import TerrainStack

    plugin_site.add(
        "gvt_plotter", plugin_manifest("gvt-plotter", "gvt_plotter", "tool", "T"), {"impl": impl}
    )
    registry = PluginRegistry(MemorySettings()).discover()
    host = ToolHost(Globe(TerrainStack()), registry)
    host.activate("gvt-plotter")
    return host, registry


def test_the_tool_host_publishes_the_tools_plot(plugin_site: PluginSite) -> None:
    impl = (
        "from globeview.plugins.api import Plot, Tool\n"
        "class T(Tool):\n"
        "    def __init__(self, context=None):\n"
        "        super().__init__(context)\n"
        "        self.published = Plot('p', [0.0, 1.0], [2.0, 3.0], 'x (m)', 'y (m)')\n"
        "    def plot(self):\n"
        "        return self.published\n"
    )
    host, _registry = _tool_host(plugin_site, impl)
    tool = host.tool()
    first = host.plot()
    assert first is tool.published and host.plot() is first  # the same object: unchanged
    assert host.plot_csv() == "x (m),y (m)\n0.0,2.0\n1.0,3.0\n"
    host.activate(None)
    assert host.plot() is None and host.plot_csv() is None  # no active tool: no plot


def test_a_plot_that_is_not_a_plot_fails_the_tool_at_the_host(plugin_site: PluginSite) -> None:
    impl = (
        "from globeview.plugins.api import Tool\n"
        "class T(Tool):\n"
        "    def plot(self):\n"
        "        return 'a profile'\n"
    )
    host, registry = _tool_host(plugin_site, impl)
    assert host.plot() is None
    assert (
        registry.failure_of("gvt-plotter", "tool") == "TypeError: plot() returned str, not a Plot"
    )
    assert host.tool() is None and host.globe.tool is None  # the tool left the globe


def test_the_window_and_the_cli_take_the_plot_from_the_host() -> None:
    """Neither the Plot dock nor ``render --tool-csv`` calls a tool's ``plot`` itself."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2] / "globeview"
    for path in (root / "ui" / "plot_dock.py", root / "cli" / "render.py"):
        text = path.read_text(encoding="utf-8")
        assert '"plot"' not in text and ".plot()" not in text, path.name
    assert "tool_plot()" in (root / "ui" / "plot_dock.py").read_text(encoding="utf-8")
    assert "tool_plot_csv()" in (root / "cli" / "render.py").read_text(encoding="utf-8")


# -- two points --------------------------------------------------------------------------------
def test_two_point_pick_a_then_b_then_a_new_pair() -> None:
    from globeview.plugins.api import TwoPointPick

    pick = TwoPointPick()
    assert (pick.state, pick.a, pick.b) == ("idle", None, None)
    assert pick.on_mouse(_press(A)) == "a"
    assert (pick.state, pick.a, pick.b) == ("a_set", A, None)
    assert pick.on_mouse(_press(B)) == "b"
    assert (pick.state, pick.a, pick.b) == ("complete", A, B)
    assert pick.on_mouse(_press(C)) == "a"  # the third click starts a new pair
    assert (pick.state, pick.a, pick.b) == ("a_set", C, None)
    assert isinstance(pick.a[0], float)


@pytest.mark.parametrize(
    "event",
    [
        _press(A, kind="move"),
        _press(A, kind="release"),
        _press(A, button="right"),
        _press(None),  # the sky: no terrain under the cursor
        PointerEvent(1.0, 2.0, "wheel", wheel_delta=1.0, lonlat=(*A, 0.0)),
    ],
)
def test_two_point_pick_leaves_other_events_to_navigation(event) -> None:
    from globeview.plugins.api import TwoPointPick

    pick = TwoPointPick()
    pick.on_mouse(_press(A))
    assert pick.on_mouse(event) is None
    assert (pick.a, pick.b) == (A, None)


def test_two_point_pick_escape_clears_and_check_refuses_a_pair() -> None:
    from globeview.plugins.api import TwoPointPick

    pick = TwoPointPick()
    assert not pick.on_key(KeyEvent("Escape"))  # nothing to clear: the host's Escape
    pick.on_mouse(_press(A))
    assert not pick.on_key(KeyEvent("a")) and not pick.on_key(KeyEvent("Escape", kind="release"))

    def far_enough(a, b):
        if abs(b[0] - a[0]) < 1.0:
            raise ValueError("A and B are less than a degree apart")

    with pytest.raises(ValueError, match="less than a degree"):
        pick.on_mouse(_press((10.5, 46.0)), check=far_enough)
    assert (pick.state, pick.a, pick.b) == ("a_set", A, None)  # B refused, A kept
    assert pick.on_mouse(_press(B), check=far_enough) == "b"
    assert pick.on_key(KeyEvent("Escape"))
    assert (pick.state, pick.a, pick.b) == ("idle", None, None)


@pytest.mark.parametrize("name", ["measure", "collapse"])
def test_measure_and_collapse_pick_with_two_point_pick(name, globeview_registry) -> None:
    """Both built-in tools follow the same state machine through their `TwoPointPick`."""
    from globeview.plugins.api import TwoPointPick

    tool = globeview_registry.tools()[name]
    assert isinstance(tool.pick, TwoPointPick)
    assert tool.on_mouse(_press(A)) and tool.state == "a_set" and tool.a == A
    assert not tool.on_mouse(_press(A, kind="move"))
    assert tool.on_mouse(_press(B)) and tool.a == A and tool.b == B
    assert tool.on_mouse(_press(C)) and tool.state == "a_set" and (tool.a, tool.b) == (C, None)
    assert tool.on_key(KeyEvent("Escape")) and tool.state == "idle"
    assert not tool.on_key(KeyEvent("Escape"))


# -- shared settings ---------------------------------------------------------------------------
def test_the_builtin_providers_declare_the_shared_settings(globeview_registry) -> None:
    from globeview.plugins.api import MAX_TILES, TAU_OVERRIDE, TEXEL_SIZE, TILE_BUDGET

    providers = globeview_registry.lod_providers()
    settings = {name: {s.name: s for s in p.settings} for name, p in providers.items()}
    for name in ("chunked-sse", "quadtree-clod"):
        assert settings[name]["max_tiles"] is TILE_BUDGET, name
        assert settings[name]["texel_px"] is TEXEL_SIZE, name
    assert settings["wavelet"]["tau_px"] is TAU_OVERRIDE
    for name in ("wavelet", "distance-regions"):
        budget = settings[name]["max_tiles"]
        assert budget == dataclasses.replace(TILE_BUDGET, default=1500, max=MAX_TILES), name
    clod_tau = settings["quadtree-clod"]["tau_px"]
    assert dataclasses.replace(clod_tau, help=TAU_OVERRIDE.help) == TAU_OVERRIDE
    # A value coerces as before: clamped to the budget's range.
    assert TILE_BUDGET.coerce(5000) == 2000 and np.isclose(TEXEL_SIZE.coerce("0.1"), 0.5)
