"""Registry details of issue #15 item 11: a layer type gets settings and ``configure`` like
the other contribution kinds (stored values applied when it is created, changes persisted),
and ``registry.invoke(..., user_errors=True)`` lets the user's bad input through without
failing the contribution. The plugin is a real distribution on sys.path."""

from __future__ import annotations

import pytest

from globeview.app.testing import PluginSite
from globeview.errors import GlobeviewError
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings

MANIFEST = """
    name = "widths"
    version = "0.1.0"
    description = "a layer type with a setting"
    kinds = ["layer"]
    api_version = "1.0"

    [[contributions]]
    name = "widths"
    kind = "layer"
    target = "gvt_widths.impl:Widths"
    """

IMPL = """
    from globeview.plugins.api import GlobeviewError, LayerType, Setting

    class Widths(LayerType):
        label = "Width files"
        extensions = (".width",)
        settings = (Setting("width", "float", 2.0, min=0.5, max=10.0, label="Line width"),)

        def open(self, path):
            if path.endswith(".bad"):
                raise GlobeviewError(f"{path}: not a width file")
            if path.endswith(".bug"):
                raise ValueError("a bug in the layer type")
            return {"path": path, "width": self.values["width"]}
    """


@pytest.fixture
def widths(plugin_site: PluginSite) -> PluginSite:
    plugin_site.add("gvt_widths", MANIFEST, {"impl": IMPL})
    return plugin_site


def test_layer_type_settings_are_configured_and_persisted(widths: PluginSite) -> None:
    settings = MemorySettings()
    reg = PluginRegistry(settings).discover()
    lt = reg.layer_types()["widths"]
    assert lt.values == {"width": 2.0}  # defaults applied at creation
    reg.configure(lt, {"width": 4.0})
    assert lt.values == {"width": 4.0}
    assert reg.invoke(lt, "open", "a.width")["width"] == 4.0
    reg.configure(lt, {"width": 99.0})  # clamped like every Setting
    assert lt.values == {"width": 10.0}
    assert settings.get("plugins/widths/contributions/widths") == {"width": 99.0}
    # A later session on the same settings creates it with the stored values.
    again = PluginRegistry(settings).discover().layer_types()["widths"]
    assert again.values == {"width": 10.0}
    assert reg.get("widths").status == "ok"


def test_user_errors_pass_through_and_bugs_fail_the_layer_type(widths: PluginSite) -> None:
    reg = PluginRegistry(MemorySettings()).discover()
    lt = reg.layer_types()["widths"]
    with pytest.raises(GlobeviewError, match=r"x\.bad: not a width file"):
        reg.invoke(lt, "open", "x.bad", user_errors=True)
    assert reg.get("widths").status == "ok"  # the user's bad file is not the plugin's fault
    # Without user_errors the same GlobeviewError is a plugin failure.
    assert reg.invoke(lt, "open", "y.bad", default="failed") == "failed"
    assert reg.get("widths").status == "failed"
    reg.enable("widths")
    lt = reg.layer_types()["widths"]
    # A bug is a bug even with user_errors: the contribution fails, the caller gets default.
    assert reg.invoke(lt, "open", "z.bug", default="failed", user_errors=True) == "failed"
    assert reg.get("widths").error == "ValueError: a bug in the layer type"
