"""`render --tool-csv` writes every curve of the plot a tool publishes (plugin API 1.2,
issue #29 item 11): the plot's own columns, then each `PlotSeries` (one with its own x as
two columns, shorter columns padded with empty fields). A real process of the installed
command (forked by `zygote`); the tool is a real distribution on PYTHONPATH."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
import zygote

from globeview.app.testing import PluginSite, plugin_manifest
from globeview.plugins.api import read_csv_columns

pytestmark = pytest.mark.gl

GLOBEVIEW = Path(sys.executable).with_name("globeview")

TOOL = """
import numpy as np
from globeview.plugins.api import Plot, PlotSeries, Tool

class Sight(Tool):
    def __init__(self, context=None):
        super().__init__(context)
        self.points = []

    def place_points(self, points):
        self.points = list(points)
        return True

    def plot(self):
        if not self.points:
            return None
        x = np.arange(len(self.points), dtype=float)
        lons = np.array([p[0] for p in self.points])
        return Plot("sight", x, lons, "index", "lon (deg)", series=(
            PlotSeries("lat (deg)", np.array([p[1] for p in self.points])),
            PlotSeries("ends", np.array([lons[0], lons[-1]]), x=np.array([0.0, x[-1]])),
        ))
"""


@pytest.mark.slow
def test_tool_csv_writes_every_series(plugin_site: PluginSite, tmp_path: Path) -> None:
    manifest = plugin_manifest("gvt-sight", "gvt_sight", "tool", "Sight").replace(
        'api_version = "1.0"', 'api_version = "1.2"'
    )
    plugin_site.add("gvt_sight", manifest, {"impl": TOOL})
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(plugin_site.root), os.environ.get("PYTHONPATH", "")]),
        "GLOBEVIEW_CONFIG_DIR": str(tmp_path / "config"),
    }
    env.pop("GLOBEVIEW_DEBUG", None)
    out, csv = tmp_path / "x.png", tmp_path / "p.csv"
    proc = zygote.run(
        [str(GLOBEVIEW), "render", "--no-borders", "--size", "96x64", "--out", str(out),
         "--tool", "gvt-sight", "--points", "-3,1;7.5,2;10,-4", "--tool-csv", str(csv)],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert out.exists()
    lines = csv.read_text().splitlines()
    assert lines == [
        "index,lon (deg),lat (deg),ends x,ends",
        "0.0,-3.0,1.0,0.0,-3.0",
        "1.0,7.5,2.0,2.0,10.0",
        "2.0,10.0,-4.0,,",
    ]
    cols = read_csv_columns(csv)
    np.testing.assert_array_equal(cols["lat (deg)"], [1.0, 2.0, -4.0])
