"""Failure isolation: a broken plugin is disabled and reported, the host and the other
plugins carry on. Throwaway plugins are real distributions (a package plus a .dist-info with
entry_points.txt on sys.path) found by importlib.metadata like pip-installed ones."""

from __future__ import annotations

import logging

import pytest

from globeview.app.testing import PluginSite, plugin_manifest
from globeview.lod.render_set import RenderSet
from globeview.plugins.api import KeyEvent, PointerEvent
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings


def _manifest(name: str, package: str, kind: str = "lod", attr: str = "Provider") -> str:
    return plugin_manifest(name, package, kind, attr, description="throwaway test plugin")


GOOD_LOD = """
    from globeview.plugins.api import LodProvider
    from globeview.lod.render_set import RenderSet

    class Provider(LodProvider):
        def select(self, view, terrain):
            return RenderSet.empty()
    """


def _registry() -> PluginRegistry:
    return PluginRegistry(MemorySettings()).discover()


def _assert_others_fine(reg: PluginRegistry, broken: str) -> None:
    assert reg.get("fixed-level").enabled and reg.get("fixed-level").status == "ok"
    assert "fixed-level" in reg.lod_providers()
    assert reg.get("healthy").status == "ok"
    assert broken not in reg.lod_providers() and broken not in reg.tools()


@pytest.fixture
def healthy(plugin_site: PluginSite) -> PluginSite:
    plugin_site.add("gvt_healthy", _manifest("healthy", "gvt_healthy"), {"impl": GOOD_LOD})
    return plugin_site


def test_throwaway_plugin_is_discovered_and_works(healthy: PluginSite) -> None:
    reg = _registry()
    assert reg.get("healthy").source == "gvt-healthy 0.1.0"
    provider = reg.lod_providers()["healthy"]
    assert isinstance(reg.select(provider, None, None), RenderSet)


def test_import_failure(healthy: PluginSite, caplog: pytest.LogCaptureFixture) -> None:
    healthy.add(
        "gvt_badimport",
        _manifest("bad-import", "gvt_badimport"),
        {"impl": "import gvt_module_that_does_not_exist\n"},
    )
    reg = _registry()
    assert reg.get("bad-import").status == "ok"  # discovery did not import it
    with caplog.at_level(logging.DEBUG, logger="globeview.plugins"):
        providers = reg.lod_providers()
    rec = reg.get("bad-import")
    assert "bad-import" not in providers
    assert rec.status == "failed" and not rec.enabled
    assert rec.error == "ModuleNotFoundError: No module named 'gvt_module_that_does_not_exist'"
    # One line at ERROR (what a terminal shows); the traceback at DEBUG and on the record.
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(errors) == 1
    assert errors[0].startswith(f"plugin bad-import failed and was disabled: {rec.error}")
    assert any(
        "bad-import" in r.getMessage() and "Traceback" in r.getMessage()
        for r in caplog.records
        if r.levelno == logging.DEBUG
    )
    assert "Traceback" in rec.traceback and "gvt_module_that_does_not_exist" in rec.traceback
    _assert_others_fine(reg, "bad-import")


def test_invalid_manifest(healthy: PluginSite) -> None:
    healthy.add(
        "gvt_badmanifest",
        _manifest("bad-manifest", "gvt_badmanifest").replace('kinds = ["lod"]', 'kinds = ["x"]'),
    )
    reg = _registry()
    rec = reg.get("bad-manifest")
    assert rec.status == "failed" and not rec.enabled and rec.manifest is None
    assert "unknown kind 'x'" in rec.error and "\n" not in rec.error
    reg.enable("bad-manifest")  # cannot be enabled without a valid manifest
    assert reg.get("bad-manifest").status == "failed"
    _assert_others_fine(reg, "bad-manifest")


def test_entry_point_name_must_match_manifest(healthy: PluginSite) -> None:
    healthy.add(
        "gvt_renamed", _manifest("inner", "gvt_renamed"), {"impl": GOOD_LOD}, entry_name="outer"
    )
    reg = _registry()
    assert reg.get("outer").status == "failed"
    assert "differs from manifest name 'inner'" in reg.get("outer").error
    _assert_others_fine(reg, "outer")


def test_raises_in_activate(healthy: PluginSite) -> None:
    src = """
        from globeview.plugins.api import LodProvider

        class Provider(LodProvider):
            def __init__(self, context):
                raise RuntimeError("no GPU budget for me")
        """
    healthy.add("gvt_badactivate", _manifest("bad-activate", "gvt_badactivate"), {"impl": src})
    reg = _registry()
    assert reg.load_contribution("bad-activate", "bad-activate") is None
    rec = reg.get("bad-activate")
    assert rec.status == "failed" and rec.error == "RuntimeError: no GPU budget for me"
    _assert_others_fine(reg, "bad-activate")


def test_wrong_contribution_type(healthy: PluginSite) -> None:
    healthy.add(
        "gvt_notlod",
        _manifest("not-lod", "gvt_notlod"),
        {"impl": "class Provider:\n    def __init__(self, context):\n        pass\n"},
    )
    reg = _registry()
    assert "not-lod" not in reg.lod_providers()
    assert reg.get("not-lod").error.startswith("TypeError:")
    assert "without select()" in reg.get("not-lod").error
    _assert_others_fine(reg, "not-lod")


def test_raises_in_select_per_frame(healthy: PluginSite, headless_view) -> None:
    src = """
        from globeview.plugins.api import LodProvider

        class Provider(LodProvider):
            frames = 0
            def select(self, view, terrain):
                type(self).frames += 1
                if type(self).frames == 3:
                    raise ZeroDivisionError("division by zero")
                from globeview.lod.render_set import RenderSet
                return RenderSet.empty()
        """
    healthy.add("gvt_badselect", _manifest("bad-select", "gvt_badselect"), {"impl": src})
    reg = _registry()
    provider = reg.lod_providers()["bad-select"]
    view = headless_view(0.0, 0.0, 1e6)
    results = [reg.select(provider, view, None) for _ in range(5)]
    assert [r is not None for r in results] == [True, True, False, False, False]
    assert type(provider).frames == 3  # not called again once failed
    rec = reg.get("bad-select")
    assert rec.status == "failed" and rec.error == "ZeroDivisionError: division by zero"
    _assert_others_fine(reg, "bad-select")
    # The fixed-level provider still answers frames.
    assert len(reg.select(reg.lod_providers()["fixed-level"], view, None)) > 0


def test_select_returning_wrong_type(healthy: PluginSite) -> None:
    src = """
        from globeview.plugins.api import LodProvider

        class Provider(LodProvider):
            def select(self, view, terrain):
                return [(3, 1, 1)]
        """
    healthy.add("gvt_badreturn", _manifest("bad-return", "gvt_badreturn"), {"impl": src})
    reg = _registry()
    assert reg.select(reg.lod_providers()["bad-return"], None, None) is None
    assert reg.get("bad-return").error == "TypeError: select() returned list, not a RenderSet"
    _assert_others_fine(reg, "bad-return")


def test_raises_in_tool_event(healthy: PluginSite) -> None:
    src = """
        from globeview.plugins.api import Tool

        class BadTool(Tool):
            def on_mouse(self, event):
                raise KeyError("button")
        """
    healthy.add(
        "gvt_badtool", _manifest("bad-tool", "gvt_badtool", "tool", "BadTool"), {"impl": src}
    )
    reg = _registry()
    tool = reg.tools()["bad-tool"]
    assert reg.invoke(tool, "on_mouse", PointerEvent(1, 2, "press"), default=False) is False
    rec = reg.get("bad-tool")
    assert rec.status == "failed" and rec.error == "KeyError: 'button'"
    # Later events are not delivered to the failed plugin.
    assert reg.invoke(tool, "on_key", KeyEvent("a"), default="skipped") == "skipped"
    assert "bad-tool" not in reg.tools()
    assert "marker" in reg.tools()
    _assert_others_fine(reg, "bad-tool")


def test_host_reported_shader_failure_and_reenable(healthy: PluginSite) -> None:
    src = """
        from globeview.plugins.api import Tool

        class WarpTool(Tool):
            def displacement_glsl(self):
                return "vec3 gv_displace(vec3 p, vec3 up, float h, vec3 c) { return p +; }"
        """
    healthy.add("gvt_warp", _manifest("warp", "gvt_warp", "tool", "WarpTool"), {"impl": src})
    reg = _registry()
    tool = reg.tools()["warp"]
    glsl = reg.invoke(tool, "displacement_glsl")
    assert "gv_displace" in glsl
    # The renderer's compile fails: it reports the failure against the tool's plugin.
    reg.report_failure(reg.owner_of(tool), RuntimeError("GLSL compile error: 0:1: syntax error"))
    rec = reg.get("warp")
    assert rec.status == "failed" and "GLSL compile error" in rec.error
    _assert_others_fine(reg, "warp")
    # The user re-enables it: the failure is cleared and the tool loads afresh.
    reg.enable("warp")
    assert reg.get("warp").status == "ok" and reg.tools()["warp"] is not tool


def test_failure_is_not_persisted(healthy: PluginSite) -> None:
    settings = MemorySettings()
    reg = PluginRegistry(settings).discover()
    reg.report_failure("healthy", ValueError("boom"))
    assert reg.get("healthy").status == "failed"
    assert PluginRegistry(settings).discover().get("healthy").status == "ok"
