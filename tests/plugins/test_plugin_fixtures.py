"""The pytest fixtures globeview gives plugin authors (issue #15 item 10): ``globeview_terrain``
(the embedded stores, real terrain for providers) and ``rendered`` (a headless frame + stats
for a provider/tool/view), from a plugin's point of view.

The plugin under test is a real distribution on sys.path (package + .dist-info, found by
importlib.metadata like a pip install) written against the facade only. The last test is the
outsider's view exactly: a separate ``pytest`` run in a directory of its own, whose test
module uses only the fixtures that globeview's ``pytest11`` entry point provides.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from globeview.app.testing import PluginSite
from globeview.errors import GlobeviewError

MANIFEST = """
    name = "probe"
    version = "0.2.0"
    description = "a provider that needs terrain, a tool with a setting, a broken provider"
    kinds = ["lod", "tool"]
    api_version = "1.0"

    [[contributions]]
    name = "probe"
    kind = "lod"
    target = "gvt_probe.impl:Probe"

    [[contributions]]
    name = "dot"
    kind = "tool"
    target = "gvt_probe.impl:Dot"

    [[contributions]]
    name = "broken"
    kind = "lod"
    target = "gvt_probe.impl:Broken"

    [[contributions]]
    name = "pins"
    kind = "tool"
    target = "gvt_probe.impl:Pins"

    [[contributions]]
    name = "ghost"
    kind = "tool"
    target = "gvt_probe.missing:Ghost"
    """

IMPL = """
    from globeview.plugins.api import (
        IndexVariant, LodProvider, Marker, RenderSet, Setting, Tool, lonlat_to_ecef,
    )

    class Probe(LodProvider):
        '''The two level-0 tiles, but only over real terrain: without it, nothing.'''

        def select(self, view, terrain):
            if terrain is None or terrain.max_level == 0:
                return RenderSet.empty()
            rs = RenderSet([[0, 0, 0], [0, 1, 0]], [0, 0], [IndexVariant(stride=8, pole="both")])
            rs.stats["terrain_max_level"] = terrain.max_level
            return rs

    class Broken(LodProvider):
        def select(self, view, terrain):
            raise ZeroDivisionError("probe bug")

    class Dot(Tool):
        '''A magenta dot 5 km above (0 E, 20 N), over the terrain; its size a setting.'''

        settings = (Setting("size", "float", 6.0, min=1.0, max=100.0),)

        def overlay(self, view):
            p = tuple(float(v) for v in lonlat_to_ecef(0.0, 20.0, 5000.0))
            return [Marker(p, color=(1.0, 0.0, 1.0, 1.0), size_px=self.values["size"])]

    class Pins(Tool):
        '''A magenta dot 5 km above every place clicked (the host clicks headless points).'''

        def __init__(self, context=None):
            super().__init__(context)
            self.clicked = []

        def on_mouse(self, event):
            if event.kind == "press" and event.lonlat is not None:
                self.clicked.append(event.lonlat[:2])
                return True
            return False

        def overlay(self, view):
            return [
                Marker(tuple(float(v) for v in lonlat_to_ecef(lon, lat, 5000.0)),
                       color=(1.0, 0.0, 1.0, 1.0), size_px=12.0)
                for lon, lat in self.clicked
            ]
    """


def add_probe(site: PluginSite) -> None:
    site.add("gvt_probe", MANIFEST, {"impl": IMPL})


def magenta(image: np.ndarray) -> np.ndarray:
    """(h, w) bool: magenta pixels (the dot's fill; nothing else in the frame is)."""
    px = image.astype(np.int32)
    return (px[..., 0] > 200) & (px[..., 1] < 40) & (px[..., 2] > 200)


def test_globeview_terrain_is_the_embedded_terrain(globeview_terrain, tmp_path: Path) -> None:
    from globeview.paths import cache_dir

    # The White Mountains SRTM tile: Mount Washington is ~1917 m above the geoid (~1890 m
    # ellipsoidal); the global base alone is far coarser there.
    assert 1700.0 < globeview_terrain.height_at(-71.3033, 44.2706) < 2000.0
    assert globeview_terrain.max_level >= 10  # the regional DEMs, not just the base
    assert len(globeview_terrain.visible_layers) == 4
    # Built in a temporary cache, not the user's (nor the one this run points at).
    store_dirs = {Path(ly.store.path).parent for ly in globeview_terrain.visible_layers}
    assert all(cache_dir() not in d.parents and d != cache_dir() for d in store_dirs)


def test_a_provider_gets_real_terrain(
    plugin_site: PluginSite, globeview_registry, globeview_terrain, headless_view
) -> None:
    add_probe(plugin_site)
    globeview_registry.discover()
    provider = globeview_registry.lod_providers()["probe"]
    view = headless_view(-71.3, 44.27, 3.0e5)
    assert len(globeview_registry.select(provider, view, None)) == 0  # no terrain: nothing
    rs = globeview_registry.select(provider, view, globeview_terrain)
    assert len(rs) == 2 and rs.stats["terrain_max_level"] == globeview_terrain.max_level


@pytest.mark.slow
@pytest.mark.gl
def test_rendered_draws_the_provider_with_real_terrain(
    plugin_site: PluginSite, globeview_registry, rendered
) -> None:
    add_probe(plugin_site)
    globeview_registry.discover()
    frame = rendered("probe", size=(96, 64))
    assert frame.provider == "probe" and not frame.fell_back and not frame.failures
    assert frame.image.shape == (64, 96, 3) and frame.image.dtype == np.uint8
    assert frame.stats["lod_provider"] == "probe" and frame.stats["tiles_drawn"] == 2
    assert len(frame.render_set) == 2
    # The provider's own stats, namespaced as `render --stats` writes them: it saw terrain.
    assert frame.stats["provider"]["name"] == "probe"
    assert frame.stats["provider"]["stats"]["terrain_max_level"] >= 10
    assert frame.stats["levels"] == {"0": 2}
    corner, centre = frame.image[0, 0], frame.image[32, 48]
    assert not np.array_equal(corner, centre)  # the globe is drawn over the background
    # A camera 300 km above the White Mountains: chunked-sse refines into the SRTM tiles.
    close = rendered("chunked-sse", camera=(-71.3, 44.27, 3.0e5), size=(96, 64))
    assert close.stats["tiles_drawn"] > 2
    assert int(close.render_set.keys[:, 0].max()) >= 5
    # Only the latest frame keeps its session (a GPU tile pool each); the earlier frame's
    # image and stats stay.
    assert frame.session is None and close.session is not None
    assert not np.array_equal(frame.image[0, 0], frame.image[32, 48])


@pytest.mark.slow
@pytest.mark.gl
def test_rendered_tool_overlay_and_settings(
    plugin_site: PluginSite, globeview_registry, rendered
) -> None:
    add_probe(plugin_site)
    globeview_registry.discover()
    small = rendered("chunked-sse", tool="dot", size=(96, 64))
    big = rendered("chunked-sse", tool="dot", settings={"dot": {"size": 30.0}}, size=(96, 64))
    # The camera looks straight down at (0, 20): the dot sits in the middle of the frame.
    assert magenta(small.image)[28:36, 44:52].any() and magenta(big.image)[32, 48]
    assert magenta(big.image).sum() > 4 * magenta(small.image).sum() > 0
    # The setting persisted in the test's registry (the test's config directory).
    assert globeview_registry.settings.get("plugins/probe/contributions/dot") == {"size": 30.0}
    with pytest.raises(KeyError, match="dot has no setting colour"):
        rendered("chunked-sse", tool="dot", settings={"dot": {"colour": 1}})
    with pytest.raises(ValueError, match=r"dot\.size: .*'huge'"):
        rendered("chunked-sse", tool="dot", settings={"dot": {"size": "huge"}})
    with pytest.raises(KeyError, match="no enabled contribution named 'nope'"):
        rendered("chunked-sse", settings={"nope": {}})


@pytest.mark.slow
@pytest.mark.gl
def test_rendered_gives_a_tool_its_points(
    plugin_site: PluginSite, globeview_registry, rendered
) -> None:
    add_probe(plugin_site)
    globeview_registry.discover()
    none = rendered("chunked-sse", tool="pins", size=(96, 64))
    assert not magenta(none.image).any()
    # (0 E, 20 N) is in the middle of the default view; (60 E, 20 N) right of it.
    frame = rendered("chunked-sse", tool="pins", points=[(0.0, 20.0), (60.0, 20.0)], size=(96, 64))
    tool = frame.session.tool()
    assert np.allclose(tool.clicked, [(0.0, 20.0), (60.0, 20.0)])
    dots = magenta(frame.image)
    assert dots[28:36, 44:52].any() and dots[:, 56:].any() and not dots[:, :40].any()


@pytest.mark.slow
@pytest.mark.gl
def test_rendered_reports_a_fallback(plugin_site: PluginSite, globeview_registry, rendered) -> None:
    add_probe(plugin_site)
    globeview_registry.discover()
    frame = rendered("broken", size=(64, 48))
    assert frame.fell_back and frame.provider == "chunked-sse" and frame.requested == "broken"
    assert frame.failures == {"broken": "ZeroDivisionError: probe bug"}
    # Per-contribution isolation: the package's other provider and tool still work.
    frame = rendered("probe", tool="dot", size=(64, 48))
    assert frame.provider == "probe" and not frame.failures
    # A tool that cannot even be imported is a failure of the frame, not an exception.
    frame = rendered("probe", tool="ghost", size=(64, 48))
    assert frame.failures == {"ghost": "ModuleNotFoundError: No module named 'gvt_probe.missing'"}
    assert frame.session.tool() is None and frame.provider == "probe"
    with pytest.raises(GlobeviewError, match="no enabled tool named 'nosuch'"):
        rendered("probe", tool="nosuch")


# -- the outsider's view: a plugin project's own pytest run -------------------------------
OUTSIDER_TESTS = """
    import numpy as np


    def test_terrain(globeview_terrain):
        assert globeview_terrain.max_level >= 10


    def test_provider_draws(rendered):
        frame = rendered("probe", size=(64, 48))
        assert frame.provider == "probe" and frame.stats["tiles_drawn"] == 2
        assert frame.image.shape == (48, 64, 3)


    def test_tool_dot(rendered):
        frame = rendered("chunked-sse", tool="dot", settings={"dot": {"size": 20.0}})
        px = frame.image[120, 160].astype(int)
        assert px[0] > 200 and px[1] < 40 and px[2] > 200, px
    """


@pytest.mark.slow
@pytest.mark.gl
def test_a_plugin_project_uses_the_fixtures_with_no_conftest(
    plugin_site: PluginSite, tmp_path: Path
) -> None:
    add_probe(plugin_site)
    project = tmp_path / "gvt-probe-project"
    (project / "tests").mkdir(parents=True)
    (project / "tests" / "test_probe.py").write_text(textwrap.dedent(OUTSIDER_TESTS))
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(plugin_site.root), os.environ.get("PYTHONPATH", "")]),
        "GLOBEVIEW_CONFIG_DIR": str(tmp_path / "config"),
        "GLOBEVIEW_CACHE_DIR": str(tmp_path / "user-cache"),
    }
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests"],
        cwd=project,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "3 passed" in proc.stdout
    # The fixtures built their terrain in pytest's temporary directory, not the user's cache.
    assert not (tmp_path / "user-cache" / "stores").exists()
