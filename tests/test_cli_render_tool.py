"""`globeview render --tool NAME --points ... --set NAME.KEY=VALUE` (issue #15 items 4, 5, 7,
9): any enabled tool renders headless, built-in or installed; settings from the command line
are checked against the Setting; provider stats reach --stats namespaced; a provider failure
says which provider drew, and --strict exits 3 writing nothing.

Real processes of `.venv/bin/globeview` (forked by `zygote`); the "installed" plugins are real
distributions (package + .dist-info with an entry point) on PYTHONPATH, found by
importlib.metadata as a pip install is (`globeview.app.testing.PluginSite`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zygote
from PIL import Image

from globeview.app.testing import PluginSite, make_view, plugin_manifest

pytestmark = pytest.mark.gl

GLOBEVIEW = Path(sys.executable).with_name("globeview")
SIZE = (160, 120)
CAMERA = "0,20,20000000"


def globeview(site: PluginSite, tmp: Path, *args: str) -> subprocess.CompletedProcess:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(site.root), os.environ.get("PYTHONPATH", "")]),
        "GLOBEVIEW_CONFIG_DIR": str(tmp / "config"),
        "GVT_EVENTS": str(tmp / "events.json"),
    }
    env.pop("GLOBEVIEW_DEBUG", None)
    return zygote.run([str(GLOBEVIEW), *args], capture_output=True, text=True, env=env, timeout=300)


def render(site: PluginSite, tmp: Path, name: str, *args: str):
    out = tmp / f"{name}.png"
    proc = globeview(
        site,
        tmp,
        "render",
        "--no-borders",
        "--size",
        f"{SIZE[0]}x{SIZE[1]}",
        "--camera",
        CAMERA,
        "--out",
        str(out),
        *args,
    )
    return proc, out


def pixels(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


# A third-party tool that only knows clicks (no place_points): each left press on terrain
# drops a marker in the colour its setting chooses, and the events it saw are written out.
CLICK_TOOL = """
import json, os
from globeview.plugins.api import Marker, Setting, Tool, lonlat_to_ecef

COLOURS = {"green": (0.0, 1.0, 0.0, 1.0), "blue": (0.0, 0.0, 1.0, 1.0)}

class Pins(Tool):
    settings = (
        Setting("size_px", "float", 14.0, min=4.0, max=40.0, help="pin size, pixels"),
        Setting("colour", "choice", "green", choices=("green", "blue")),
    )

    def __init__(self, context=None):
        super().__init__(context)
        self.pins, self.events = [], []

    def on_mouse(self, event):
        self.events.append([event.kind, event.button, event.x, event.y, list(event.lonlat)])
        with open(os.environ["GVT_EVENTS"], "w") as f:
            json.dump(self.events, f)
        if event.kind == "press" and event.button == "left" and event.lonlat is not None:
            lon, lat, _ = event.lonlat
            self.pins.append(tuple(float(v) for v in lonlat_to_ecef(lon, lat, 0.0)))
            return True
        return False

    def overlay(self, view):
        colour = COLOURS[self.values["colour"]]
        return [Marker(p, colour, self.values["size_px"]) for p in self.pins]
"""

# A provider with its own counters (and garbage among them): every level-1 tile.
STATS_PROVIDER = """
import numpy as np
from globeview.plugins.api import IndexVariant, LodProvider, RenderSet

class Provider(LodProvider):
    def select(self, view, terrain):
        keys = np.array([(1, x, y) for x in range(4) for y in range(2)], np.int64)
        stats = {"my_counter": 7, "label": "hello", "lod_ms": 0.5, "obj": object(),
                 "nan": float("nan"), "arr": np.arange(3), "big": "x" * 10_000,
                 "np_int": np.int32(5)}
        stats.update({f"filler_{i}": i for i in range(200)})
        return RenderSet(keys, np.zeros(8, np.int64), [IndexVariant()], stats=stats)
"""

# A tool whose headless entry has a bug (not a GlobeviewError: the plugin is at fault).
BROKEN_TOOL = """
from globeview.plugins.api import Tool

class Tool(Tool):
    def place_points(self, points):
        raise ValueError("cannot count to " + str(len(points)))
"""

BROKEN_PROVIDER = """
from globeview.plugins.api import LodProvider

class Provider(LodProvider):
    def select(self, view, terrain):
        raise ValueError("boom in select")
"""


@pytest.fixture
def site(plugin_site: PluginSite) -> PluginSite:
    plugin_site.add("gvt_pins", plugin_manifest("gvt-pins", "gvt_pins", "tool", "Pins"),
                    {"impl": CLICK_TOOL})  # fmt: skip
    plugin_site.add("gvt_stats", plugin_manifest("gvt-stats", "gvt_stats"),
                    {"impl": STATS_PROVIDER})  # fmt: skip
    plugin_site.add("gvt_boom", plugin_manifest("gvt-boom", "gvt_boom"),
                    {"impl": BROKEN_PROVIDER})  # fmt: skip
    plugin_site.add("gvt_badtool", plugin_manifest("gvt-badtool", "gvt_badtool", "tool", "Tool"),
                    {"impl": BROKEN_TOOL})  # fmt: skip
    return plugin_site


def projected(lon: float, lat: float) -> tuple[float, float]:
    """Pixel of a point on the ellipsoid in the test's view."""
    from globeview.geodesy import lonlat_to_ecef

    view = make_view(0.0, 20.0, 2.0e7, viewport=SIZE)
    x, y, _ = view.project(np.asarray(lonlat_to_ecef(lon, lat, 0.0)).reshape(1, 3))[0]
    return float(x), float(y)


@pytest.mark.slow
def test_installed_tool_gets_clicks_at_the_points_and_draws(site: PluginSite, tmp_path: Path):
    """An installed tool with no headless code: the host clicks each point at its pixel, with
    lonlat and picked set, and the tool's markers land there in the colour --set chose."""
    proc, plain = render(site, tmp_path, "plain", "--tool", "gvt-pins")
    assert proc.returncode == 0, proc.stderr
    proc, out = render(site, tmp_path, "pins", "--tool", "gvt-pins", "--points", "10,20;-15,5")
    assert proc.returncode == 0 and lines(proc.stderr) == [], proc.stderr
    events = json.loads((tmp_path / "events.json").read_text())
    assert [e[:2] for e in events] == [["press", "left"], ["release", "left"]] * 2
    for event, (lon, lat) in zip(events[::2], [(10.0, 20.0), (-15.0, 5.0)], strict=True):
        assert event[4][:2] == [lon, lat]
        x, y = projected(lon, lat)
        assert abs(event[2] - x) < 1.5 and abs(event[3] - y) < 1.5
        px = pixels(out)[round(y), round(x)]
        assert px[1] > 200 and px[0] < 80 and px[2] < 80, px  # a green pin
        assert not np.array_equal(px, pixels(plain)[round(y), round(x)])
    # The same points as repeated --point, negative longitude first, and a blue pin.
    proc, blue = render(
        site, tmp_path, "blue", "--tool", "gvt-pins", "--point", "-15,5", "--set",
        "gvt-pins.colour=blue",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    x, y = projected(-15.0, 5.0)
    px = pixels(blue)[round(y), round(x)]
    assert px[2] > 200 and px[0] < 80 and px[1] < 80, px


@pytest.mark.slow
def test_collapse_is_a_spelling_of_tool_points_set(site: PluginSite, tmp_path: Path) -> None:
    proc, a = render(site, tmp_path, "a", "--collapse=-10,0,10,0,0.3", "--stats",
                     str(tmp_path / "a.json"))  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    proc, b = render(site, tmp_path, "b", "--tool", "collapse", "--points", "-10,0;10,0",
                     "--set", "collapse.ratio=0.3")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    proc, c = render(site, tmp_path, "c")
    assert np.array_equal(pixels(a), pixels(b))
    assert np.abs(pixels(a) - pixels(c)).sum() > 10_000  # the collapse changed the picture
    stats = json.loads((tmp_path / "a.json").read_text())
    overlay_drawn = stats["tool"].pop("overlay_drawn")
    assert stats["tool"] == {"name": "collapse", "points": [[-10.0, 0.0], [10.0, 0.0]]}
    assert overlay_drawn > 0  # the fold lines and markers, drawn by the frame itself
    assert stats["settings"] == {"collapse.ratio": 0.3}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--set", "gvt-pins.colour=red"), "colour: 'red' is not offered (one of green, blue)"),
        (("--set", "gvt-pins.size_px=400"), "--set gvt-pins.size_px: 400 is outside 4..40"),
        (("--set", "gvt-pins.size_px=nan"), "is not a finite number"),
        (("--set", "gvt-pins.nope=1"), "has no setting 'nope' (settings: size_px, colour)"),
        (("--set", "nobody.x=1"), "no plugin contribution named 'nobody'"),
        (("--set", "gvt-pins=1"), "--set takes NAME.KEY=VALUE"),
        (("--tool", "nobody"), "--tool: no enabled tool named 'nobody' (tools: "),
        (("--points", "1,2"), "need a --tool"),
        (("--tool", "gvt-pins", "--points", "1,2;3,95"), "latitude must be"),
        (("--tool", "collapse", "--points", "1,2"), "collapse tool takes two points"),
        (("--collapse=0,0,10,10,0.005",), "--collapse collapse.ratio: 0.005 is outside 0.01..1"),
        (("--collapse=0,0,10,10", "--tool", "gvt-pins"), "--collapse is --tool collapse"),
    ],
)  # fmt: skip
def test_bad_tool_and_setting_arguments_are_one_line(
    site: PluginSite, tmp_path: Path, args: tuple[str, ...], message: str
) -> None:
    proc, out = render(site, tmp_path, "bad", *args)
    assert proc.returncode == 2, proc.stderr
    assert lines(proc.stderr) == [lines(proc.stderr)[0]] and message in proc.stderr, proc.stderr
    assert proc.stderr.startswith("globeview: error: ")
    assert not out.exists() and proc.stdout == ""


@pytest.mark.slow
def test_set_for_one_render_is_not_stored(site: PluginSite, tmp_path: Path) -> None:
    proc, _ = render(site, tmp_path, "once", "--set", "gvt-pins.colour=blue")
    assert proc.returncode == 0, proc.stderr
    settings = tmp_path / "config" / "settings.json"
    assert not settings.exists() or "blue" not in settings.read_text()


@pytest.mark.slow
def test_provider_stats_reach_stats_json_namespaced_and_clipped(
    site: PluginSite, tmp_path: Path
) -> None:
    stats_path = tmp_path / "s.json"
    proc, _ = render(site, tmp_path, "stats", "--lod", "gvt-stats", "--stats", str(stats_path))
    assert proc.returncode == 0, proc.stderr
    assert "provider: gvt-stats" in proc.stdout
    stats = json.loads(stats_path.read_text())
    provider = stats["provider"]
    assert provider["name"] == provider["requested"] == "gvt-stats"
    mine = provider["stats"]
    assert mine["my_counter"] == 7 and mine["label"] == "hello" and mine["np_int"] == 5
    assert len(mine["big"]) == 200
    assert not {"obj", "nan", "arr"} & set(mine)
    assert len(mine) == 64 and provider["stats_dropped"] == 208 - 64
    assert stats["levels"] == {"1": 8} and stats["tiles_drawn"] == 8
    assert "my_counter" not in stats  # namespaced: a plugin never overwrites a host figure


@pytest.mark.slow
def test_default_provider_stats_and_level_histogram(site: PluginSite, tmp_path: Path) -> None:
    stats_path = tmp_path / "s.json"
    proc, _ = render(site, tmp_path, "default", "--stats", str(stats_path))
    assert proc.returncode == 0, proc.stderr
    stats = json.loads(stats_path.read_text())
    assert stats["provider"]["name"] == "chunked-sse"
    assert "tiles_culled_horizon" in stats["provider"]["stats"]
    assert sum(stats["levels"].values()) == stats["tiles_drawn"] > 0


@pytest.mark.slow
def test_a_failed_provider_is_named_in_the_wrote_line(site: PluginSite, tmp_path: Path) -> None:
    stats_path = tmp_path / "s.json"
    proc, out = render(site, tmp_path, "boom", "--lod", "gvt-boom", "--stats", str(stats_path))
    assert proc.returncode == 0, proc.stderr
    assert out.exists()
    assert (
        "provider: chunked-sse, fell back from gvt-boom: ValueError: boom in select" in proc.stdout
    )
    stats = json.loads(stats_path.read_text())
    assert stats["provider"]["name"] == "chunked-sse"
    assert stats["provider"]["fell_back_from"] == {
        "name": "gvt-boom",
        "error": "ValueError: boom in select",
    }
    assert len(lines(proc.stderr)) == 1 and "gvt-boom" in proc.stderr  # the plugin warning


@pytest.mark.slow
def test_strict_exits_3_and_writes_nothing_when_a_plugin_fails(
    site: PluginSite, tmp_path: Path
) -> None:
    stats_path = tmp_path / "s.json"
    proc, out = render(
        site, tmp_path, "strict", "--lod", "gvt-boom", "--strict", "--stats", str(stats_path)
    )
    assert proc.returncode == 3, proc.stderr
    assert not out.exists() and not stats_path.exists() and proc.stdout == ""
    last = lines(proc.stderr)[-1]
    assert last.startswith("globeview: error: fell back from gvt-boom: ValueError: boom")
    assert last.endswith("nothing written (--strict)")
    assert "Traceback" not in proc.stderr
    # --strict with nothing failing is an ordinary render.
    proc, out = render(site, tmp_path, "fine", "--strict", "--tool", "gvt-pins", "--point", "1,1")
    assert proc.returncode == 0 and out.exists(), proc.stderr


@pytest.mark.slow
def test_a_failed_tool_is_named_and_strict_refuses(site: PluginSite, tmp_path: Path) -> None:
    proc, out = render(site, tmp_path, "badtool", "--tool", "gvt-badtool", "--point", "1,2")
    assert proc.returncode == 0 and out.exists(), proc.stderr
    assert "provider: chunked-sse, tool gvt-badtool failed: ValueError: cannot count to 1" in (
        proc.stdout
    )
    proc, out = render(
        site, tmp_path, "badtool-strict", "--tool", "gvt-badtool", "--point", "1,2", "--strict"
    )
    assert proc.returncode == 3 and not out.exists(), proc.stderr
    assert lines(proc.stderr)[-1] == (
        "globeview: error: tool gvt-badtool failed: ValueError: cannot count to 1; "
        "nothing written (--strict)"
    )


@pytest.mark.slow
def test_no_provider_left_says_nothing_was_drawn(site: PluginSite, tmp_path: Path) -> None:
    """The requested provider fails and the fallback is disabled: the frame is empty, and
    the line must not claim chunked-sse drew it."""
    assert globeview(site, tmp_path, "plugins", "disable", "chunked-sse").returncode == 0
    proc, out = render(site, tmp_path, "empty", "--lod", "gvt-boom")
    assert out.exists()
    assert proc.returncode == 0, proc.stderr
    assert "(160x120; provider: none, no terrain drawn, fell back from gvt-boom: " in proc.stdout
    assert ": 0 triangles, 0 tiles" in proc.stdout


# A third-party tool that publishes a plot and a status line (as the measure tool does).
PLOT_TOOL = """
import numpy as np
from globeview.plugins.api import Plot, Tool

class Profile(Tool):
    def __init__(self, context=None):
        super().__init__(context)
        self.lons = []

    def place_points(self, points):
        self.lons = [lon for lon, _ in points]
        self.context.renderer.set_status(f"profile: {len(points)} points")
        return True

    def plot(self):
        if not self.lons:
            return None
        x = np.arange(len(self.lons), dtype=float)
        return Plot("lons", x, np.array(self.lons), "index", "lon (deg)")
"""


@pytest.fixture
def plot_site(site: PluginSite) -> PluginSite:
    site.add("gvt_profile", plugin_manifest("gvt-profile", "gvt_profile", "tool", "Profile"),
             {"impl": PLOT_TOOL})  # fmt: skip
    return site


@pytest.mark.slow
def test_tool_csv_writes_the_tools_plot_with_the_png(plot_site: PluginSite, tmp_path: Path):
    csv, stats = tmp_path / "p.csv", tmp_path / "p.json"
    proc, out = render(
        plot_site, tmp_path, "profile", "--tool", "gvt-profile", "--points", "-3,1;7.5,2",
        "--tool-csv", str(csv), "--stats", str(stats),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert out.exists()
    assert csv.read_text().splitlines() == ["index,lon (deg)", "0.0,-3.0", "1.0,7.5"]
    # The tool's status line, named after the tool (unless the text starts with its name).
    assert proc.stdout.splitlines()[1] == "gvt-profile: profile: 2 points"
    assert json.loads(stats.read_text())["tool"]["status"] == "profile: 2 points"


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--tool", "gvt-profile"), "the tool gvt-profile published no plot; nothing written"),
        (("--tool", "gvt-pins", "--point", "1,1"), "the tool gvt-pins published no plot"),
        ((), "--tool-csv needs a --tool"),
    ],
)
def test_tool_csv_without_a_plot_writes_nothing(
    plot_site: PluginSite, tmp_path: Path, args: tuple[str, ...], message: str
) -> None:
    csv = tmp_path / "p.csv"
    proc, out = render(plot_site, tmp_path, "noplot", *args, "--tool-csv", str(csv))
    assert proc.returncode == 2 and len(lines(proc.stderr)) == 1, proc.stderr
    assert proc.stderr.startswith("globeview: error: ") and message in proc.stderr
    assert not out.exists() and not csv.exists()


@pytest.mark.slow
def test_point_longitudes_are_reduced_like_the_cameras(site: PluginSite, tmp_path: Path):
    proc, _ = render(site, tmp_path, "wrap", "--tool", "gvt-pins", "--points", "370,20;-1e308,5")
    assert proc.returncode == 0, proc.stderr
    events = json.loads((tmp_path / "events.json").read_text())
    lons = [e[4][0] for e in events[::2]]
    assert lons[0] == pytest.approx(10.0) and -180.0 <= lons[1] <= 180.0


@pytest.mark.slow
def test_set_of_a_contribution_not_used_warns(site: PluginSite, tmp_path: Path) -> None:
    proc, out = render(site, tmp_path, "unused", "--set", "gvt-pins.colour=blue")
    assert proc.returncode == 0 and out.exists(), proc.stderr
    assert lines(proc.stderr) == [
        "globeview: warning: --set gvt-pins.colour: gvt-pins is not used by this render "
        "(--tool gvt-pins)"
    ]
    proc, _ = render(site, tmp_path, "used", "--set", "chunked-sse.texel_px=2")
    assert proc.returncode == 0 and lines(proc.stderr) == [], proc.stderr
