"""Plugin API 1.2 (issue #29 item 11): what the first outside author could not do.

- a `Plot` with more than one curve (`PlotSeries`), the single-curve form unchanged;
- the triangles a candidate selection would draw (`triangle_count`), the same count the
  frame's stats make;
- `rendered(...).session.pick` works (the frame's target was released under it);
- a tool the test registry creates has the terrain when the test uses `globeview_terrain`;
- a plugin declaring API 1.2 loads, and 1.0 / 1.1 plugins still do.

Oracles: the frame's own triangle count, `sample_terrain` (what `globeview height` prints)
for the picked point, the CSV read back.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from globeview.app.testing import PluginSite, plugin_manifest


# -- the version ---------------------------------------------------------------------------
def test_api_version_is_1_2_or_newer_and_older_minors_load(plugin_site: PluginSite) -> None:
    from globeview.plugins.api import API_VERSION
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    major, minor = (int(v) for v in API_VERSION.split("."))
    assert major == 1 and minor >= 2  # 1.3 only added (tests/plugins/test_plugin_api_1_3.py)
    impl = "from globeview.plugins.api import Tool\nclass T(Tool):\n    pass\n"
    for version in ("1.0", "1.1", "1.2"):
        pkg = f"gvt_v{version.replace('.', '_')}"
        manifest = plugin_manifest(f"gvt-v{version}", pkg, "tool", "T").replace(
            'api_version = "1.0"', f'api_version = "{version}"'
        )
        plugin_site.add(pkg, manifest, {"impl": impl})
    reg = PluginRegistry(MemorySettings()).discover()
    for version in ("1.0", "1.1", "1.2"):
        rec = reg.get(f"gvt-v{version}")
        assert rec.status == "ok", (version, rec.error)
        assert reg.find("tool", f"gvt-v{version}") is not None


def test_new_names_are_in_the_facade() -> None:
    import globeview.plugins.api as api

    for name in ("PlotSeries", "triangle_count"):
        assert name in api.__all__ and getattr(api, name) is not None


# -- plots with several curves ---------------------------------------------------------------
def _profile_and_sight_line():
    from globeview.plugins.api import Plot, PlotSeries

    s = np.array([0.0, 1000.0, 2000.0, 3000.0])
    terrain = np.array([100.0, 350.0, np.nan, 200.0])
    sight = np.array([120.0, 180.0, 240.0, 300.0])
    return Plot(
        "profile and sight line",
        s,
        terrain,
        "distance (m)",
        "terrain (m)",
        series=(
            PlotSeries("sight line (m)", sight),
            PlotSeries("peaks (m)", np.array([350.0]), x=np.array([1000.0])),
        ),
    )


def test_plot_with_series_lists_every_curve_and_writes_every_column(tmp_path: Path) -> None:
    from globeview.plugins.api import read_csv_columns

    plot = _profile_and_sight_line()
    labels = [label for label, _, _ in plot.curves()]
    assert labels == ["terrain (m)", "sight line (m)", "peaks (m)"]
    x0, y0 = plot.curves()[0][1:]
    assert np.array_equal(x0, plot.x) and np.array_equal(y0, plot.y, equal_nan=True)
    assert np.array_equal(plot.curves()[1][1], plot.x)  # shares the plot's x
    lines = plot.csv_text().splitlines()
    assert lines[0] == "distance (m),terrain (m),sight line (m),peaks (m) x,peaks (m)"
    assert lines[1] == "0.0,100.0,120.0,1000.0,350.0"
    assert lines[3] == "2000.0,,240.0,,"  # a gap, and the short series padded
    back = read_csv_columns(plot.write_csv(tmp_path / "p.csv"))
    np.testing.assert_array_equal(back["sight line (m)"], [120.0, 180.0, 240.0, 300.0])
    np.testing.assert_array_equal(back["peaks (m) x"][:1], [1000.0])
    assert np.isnan(back["peaks (m)"][1:]).all()


def test_single_curve_plot_is_unchanged() -> None:
    from globeview.plugins.api import Plot

    plot = Plot("t", [0.0, 1.0], [2.0, 3.0], "x (m)", "h (m)")
    assert plot.series == () and len(plot.curves()) == 1
    assert plot.csv_text() == "x (m),h (m)\n0.0,2.0\n1.0,3.0\n"


@pytest.mark.parametrize(
    ("series", "words"),
    [
        (("not a series",), "series 0: str, not a PlotSeries"),
        ((("label", [1.0, 2.0]),), "series 0: tuple, not a PlotSeries"),
        ((dict(label="s", y=[1.0]),), "series 's' has 1 values, x has 2"),
        ((dict(label="s", y=[1.0, 2.0], x=[0.0, np.inf]),), "series 's' x values must be finite"),
        ((dict(label="s", y=[1.0], x=[0.0, 1.0]),), "series 's' x and y need equal"),
        ((dict(label="h (m)", y=[1.0, 2.0]),), "series 'h (m)': empty or repeated name"),
        ((dict(label=" ", y=[1.0, 2.0]),), "empty or repeated name"),
    ],
)
def test_malformed_series_are_refused_in_one_line(series, words) -> None:
    from globeview.plugins.api import Plot, PlotSeries

    built = tuple(PlotSeries(**s) if isinstance(s, dict) else s for s in series)
    with pytest.raises(ValueError, match=re.escape(words)) as info:
        Plot("t", [0.0, 1.0], [2.0, 3.0], "x (m)", "h (m)", series=built)
    assert words in str(info.value) and "\n" not in str(info.value)


# -- triangles of a candidate selection ------------------------------------------------------
@pytest.mark.slow
def test_triangle_count_is_the_frames_count(rendered) -> None:
    from globeview.plugins.api import triangle_count

    # A provider drawing its render set as built: the count is the frame's.
    frame = rendered("quadtree-clod", camera=(-71.3, 44.27, 3.0e5), size=(320, 240))
    assert not frame.failures and frame.stats["tiles_drawn"] == len(frame.render_set) > 10
    assert triangle_count(frame.render_set) == frame.stats["triangles"] > 0
    # The default provider's frame stitches same-level tile edges instead of skirting them
    # and draws blocks at their own strides (issue #27): never more than the count.
    frame = rendered(camera=(-71.3, 44.27, 3.0e5), size=(320, 240))
    assert not frame.failures and frame.stats["tiles_drawn"] == len(frame.render_set) > 10
    assert triangle_count(frame.render_set) >= frame.stats["triangles"] > 0


def test_triangle_count_of_a_selection(globeview_terrain, headless_view) -> None:
    """A `Selection` (what a policy's ``render_set`` receives) counts as the render set the
    default policy builds from it (skirts, pole fans, no stitching)."""
    from globeview.plugins.api import ScreenSpaceErrorPolicy, traverse, triangle_count

    seen = []

    class Capture(ScreenSpaceErrorPolicy):
        def render_set(self, selection, size):
            seen.append(selection)
            return super().render_set(selection, size)

    view = headless_view(-71.3, 44.27, 3.0e5, viewport=(640, 480))
    rs = traverse(view, globeview_terrain, Capture())
    assert len(seen) == 1 and len(seen[0].keys) == len(rs) > 10
    n = triangle_count(seen[0], globeview_terrain.tile_size)
    assert n == triangle_count(rs, globeview_terrain.tile_size) > 0
    # A coarser stride everywhere draws fewer triangles: the count follows the strides.
    coarser = type(seen[0])(
        seen[0].keys, np.minimum(seen[0].stride_idx + 1, 6), seen[0].error_px, 0, 0
    )
    assert triangle_count(coarser, globeview_terrain.tile_size) < n


# -- the fixtures ---------------------------------------------------------------------------
@pytest.mark.slow
def test_rendered_frame_session_picks_the_terrain(rendered) -> None:
    from globeview.plugins.api import sample_terrain

    frame = rendered(camera=(-71.3033, 44.2706, 3.0e4), size=(320, 240))
    hit = frame.session.pick(160.0, 120.0)  # the centre pixel: straight down
    assert hit is not None and hit.on_terrain
    assert hit.lon == pytest.approx(-71.3033, abs=0.01)
    assert hit.lat == pytest.approx(44.2706, abs=0.01)
    want = float(sample_terrain(frame.session.terrain, hit.lon, hit.lat).ellipsoidal)
    assert hit.height == pytest.approx(want, abs=1.0)
    sky = rendered(camera=(0.0, 20.0, 2.0e7), size=(160, 120))
    corner = sky.session.pick(0.0, 0.0)  # off the globe: no depth, not on the terrain
    assert corner is None or not corner.on_terrain


def test_a_tool_from_the_test_registry_has_the_terrain(
    globeview_registry, globeview_terrain
) -> None:
    tool = globeview_registry.tools()["measure"]
    assert tool.context.terrain is globeview_terrain
    assert tool.place_points([(-71.45, 44.23), (-71.22, 44.31)]) is True
    plot = tool.plot()
    assert plot is not None and np.isfinite(plot.y).all() and plot.y.max() > 1000.0
