"""Delegation (issue #15 item 3): a plugin wraps another LOD provider through
`PluginContext.lod_provider`, and the host keeps each provider's faults its own. The wrapping
plugins here are real distributions found through their entry points (`plugin_site`)."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.app.testing import plugin_manifest
from globeview.plugins.api import PluginContext, ProviderUnavailable, RenderSet
from globeview.plugins.registry import PluginRegistry

WRAPPER = """
from globeview.plugins.api import LodProvider, RenderSet


class Provider(LodProvider):
    name = "{name}"

    def __init__(self, context=None):
        super().__init__(context)
        self.inner = context.lod_provider("{inner}")

    def select(self, view, terrain):
        rs = self.inner.select(view, terrain)
        rs = RenderSet(rs.keys.copy(), rs.variant_ids.copy(), list(rs.variants),
                       error_px=rs.error_px, stats=dict(rs.stats))
        rs.stats["wrapped"] = 1.0
        return rs
"""

BROKEN = """
from globeview.plugins.api import LodProvider


class Provider(LodProvider):
    def select(self, view, terrain):
        raise RuntimeError("inner provider bug")
"""


def _add_wrapper(site, name: str, inner: str) -> None:
    package = name.replace("-", "_")
    site.add(
        package,
        plugin_manifest(name, package),
        {"impl": WRAPPER.format(name=name, inner=inner)},
    )


@pytest.fixture(scope="module")
def terrain():
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores

    return TerrainStack.from_stores(embedded_stores())


@pytest.mark.slow
def test_wrapper_gets_chunked_sse_result(plugin_site, globeview_config_dir, terrain, headless_view):
    _add_wrapper(plugin_site, "wrap-sse", "chunked-sse")
    reg = PluginRegistry().discover()
    wrapper = reg.find("lod", "wrap-sse")
    assert wrapper is not None and wrapper.inner.name == "chunked-sse"
    view = headless_view(-71.3, 44.3, 3.0e5)
    rs = reg.select(wrapper, view, terrain)
    own = reg.select(reg.find("lod", "chunked-sse"), view, terrain)
    assert isinstance(rs, RenderSet) and len(rs) > 0
    assert np.array_equal(rs.keys, own.keys) and rs.stats["wrapped"] == 1.0
    # The delegate's setting values are readable (a copy: writing changes nothing).
    values = wrapper.inner.values
    values["max_tiles"] = -1
    assert wrapper.inner.values["max_tiles"] != -1


def test_unknown_provider_is_one_line_naming_the_enabled(globeview_registry):
    ctx = globeview_registry.context("fixed-level")
    with pytest.raises(ProviderUnavailable) as info:
        ctx.lod_provider("no-such-provider")
    msg = str(info.value)
    assert "\n" not in msg and "'no-such-provider'" in msg and "chunked-sse" in msg


def test_bare_context_has_no_providers():
    with pytest.raises(ProviderUnavailable, match="bare context"):
        PluginContext("x").lod_provider("chunked-sse")


def test_failing_delegate_is_blamed_not_the_wrapper_only(
    plugin_site, globeview_config_dir, headless_view
):
    plugin_site.add(
        "gv_broken_inner", plugin_manifest("broken-inner", "gv_broken_inner"), {"impl": BROKEN}
    )
    _add_wrapper(plugin_site, "wrap-broken", "broken-inner")
    reg = PluginRegistry().discover()
    wrapper = reg.find("lod", "wrap-broken")
    assert reg.select(wrapper, headless_view(0.0, 0.0, 1.0e7), None) is None
    # The delegate's own bug is recorded against it, with its real reason ...
    inner = reg.get("broken-inner")
    assert inner.status == "failed" and "inner provider bug" in inner.error
    # ... and the wrapper, which could not draw this frame, says why in one line.
    outer = reg.get("wrap-broken")
    assert outer.status == "failed"
    assert "ProviderUnavailable" in outer.error and "broken-inner" in outer.error
    assert "inner provider bug" in outer.error and "\n" not in outer.error


def test_disabled_delegate_fails_the_wrapper_cleanly(
    plugin_site, globeview_config_dir, terrain, headless_view
):
    _add_wrapper(plugin_site, "wrap-later", "chunked-sse")
    reg = PluginRegistry().discover()
    wrapper = reg.find("lod", "wrap-later")
    reg.disable("chunked-sse")  # after the wrapper was made: noticed at the next frame
    assert reg.select(wrapper, headless_view(0.0, 0.0, 1.0e7), terrain) is None
    assert "'chunked-sse' is disabled or has failed" in reg.get("wrap-later").error


def test_delegation_cycle_fails_instead_of_recursing(
    plugin_site, globeview_config_dir, headless_view
):
    _add_wrapper(plugin_site, "cycle-a", "cycle-b")
    _add_wrapper(plugin_site, "cycle-b", "cycle-a")
    reg = PluginRegistry().discover()
    a = reg.find("lod", "cycle-a")
    assert reg.select(a, headless_view(0.0, 0.0, 1.0e7), None) is None
    errors = " ".join(reg.get(n).error or "" for n in ("cycle-a", "cycle-b"))
    assert "delegation cycle" in errors and "RecursionError" not in errors


SCRIBBLER = """
from globeview.plugins.api import LodProvider


class Provider(LodProvider):
    def __init__(self, context=None):
        super().__init__(context)
        self.inner = context.lod_provider("chunked-sse")

    def select(self, view, terrain):
        rs = self.inner.select(view, terrain)
        rs.keys[:, 0] = 99  # writes into chunked-sse's (cached) render set
        return rs
"""

GARBAGE_ARGS = """
from globeview.plugins.api import LodProvider


class Provider(LodProvider):
    def __init__(self, context=None):
        super().__init__(context)
        self.inner = context.lod_provider("chunked-sse")

    def select(self, view, terrain):
        return self.inner.select("not a view", terrain)
"""


def test_writing_into_the_delegates_set_fails_the_writer(
    plugin_site, globeview_config_dir, terrain, headless_view
):
    """chunked-sse hands out its cached set again next frame: a wrapper scribbling on it
    must fail itself, not poison chunked-sse."""
    plugin_site.add(
        "gv_scribbler", plugin_manifest("scribbler", "gv_scribbler"), {"impl": SCRIBBLER}
    )
    reg = PluginRegistry().discover()
    view = headless_view(-71.3, 44.3, 3.0e5)
    assert reg.select(reg.find("lod", "scribbler"), view, terrain) is None
    assert "read-only" in reg.get("scribbler").error
    sse = reg.find("lod", "chunked-sse")
    rs = reg.select(sse, view, terrain)
    assert rs is not None and rs.keys[:, 0].max() < 30
    assert reg.get("chunked-sse").status == "ok"


def test_garbage_arguments_fail_the_caller_not_the_delegate(
    plugin_site, globeview_config_dir, terrain, headless_view
):
    plugin_site.add(
        "gv_garbage_args",
        plugin_manifest("garbage-args", "gv_garbage_args"),
        {"impl": GARBAGE_ARGS},
    )
    reg = PluginRegistry().discover()
    view = headless_view(0.0, 0.0, 1.0e7)
    assert reg.select(reg.find("lod", "garbage-args"), view, terrain) is None
    assert "TypeError" in reg.get("garbage-args").error
    assert reg.get("chunked-sse").status == "ok"


def test_huge_provider_name_gives_a_short_line(globeview_registry):
    ctx = globeview_registry.context("fixed-level")
    with pytest.raises(ProviderUnavailable) as info:
        ctx.lod_provider("x" * 100_000)
    assert len(str(info.value)) < 400


def test_a_provider_wrapping_itself_fails_once_in_one_line(
    plugin_site, globeview_config_dir, headless_view
):
    _add_wrapper(plugin_site, "ouroboros", "ouroboros")
    reg = PluginRegistry().discover()
    assert reg.select(reg.find("lod", "ouroboros"), headless_view(0, 0, 1e7), None) is None
    rec = reg.get("ouroboros")
    assert rec.status == "failed" and "delegation cycle" in rec.error
    assert "\n" not in rec.error
