"""`globeview render --layer` reaches installed layer plugins (issue #15 item 1): a real
subprocess of the CLI, the plugin a real distribution on PYTHONPATH. An explicit TYPE:FILE
is honoured; an unknown file fails in one line naming the installed layer types."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_plugin_layers_draw import STRIPES_IMPL, STRIPES_MANIFEST

from globeview.app.testing import PluginSite

pytestmark = pytest.mark.gl
GLOBEVIEW = Path(sys.executable).parent / "globeview"
SIZE = "200x150"


def _run(site: PluginSite, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(site.root), os.environ.get("PYTHONPATH", "")]),
        "GLOBEVIEW_CONFIG_DIR": str(tmp_path / "config"),
    }
    env.pop("GLOBEVIEW_DEBUG", None)
    return subprocess.run(
        [str(GLOBEVIEW), *args], capture_output=True, text=True, env=env, timeout=300
    )


@pytest.fixture
def site(plugin_site: PluginSite) -> PluginSite:
    plugin_site.add("gvt_stripes", STRIPES_MANIFEST, {"impl": STRIPES_IMPL})
    return plugin_site


def _magenta(path: Path) -> int:
    rgb = np.asarray(Image.open(path).convert("RGB")).astype(int)
    return int(((rgb[..., 0] > 200) & (rgb[..., 1] < 80) & (rgb[..., 2] > 200)).sum())


@pytest.mark.slow
def test_render_layer_with_a_plugin_format(site, tmp_path) -> None:
    f = tmp_path / "grid.stripes"
    f.write_text("rhumb -60 30 60 30 1 0 1\nrhumb -60 0 60 0 1 0 1\n")
    out, plain = tmp_path / "with.png", tmp_path / "without.png"
    proc = _run(site, tmp_path, "render", "--size", SIZE, "--out", str(out), "--layer", str(f))
    assert proc.returncode == 0, proc.stderr
    ref = _run(site, tmp_path, "render", "--size", SIZE, "--out", str(plain))
    assert ref.returncode == 0, ref.stderr
    assert _magenta(out) > 100 and _magenta(plain) == 0


@pytest.mark.slow
def test_render_unknown_file_names_the_installed_types(site, tmp_path) -> None:
    f = tmp_path / "notes.xyz"
    f.write_bytes(b"\x00\x01 nothing anyone reads")
    out = tmp_path / "x.png"
    proc = _run(site, tmp_path, "render", "--size", SIZE, "--out", str(out), "--layer", str(f))
    assert proc.returncode == 2 and not out.exists()
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert lines[0].startswith("globeview: error: notes.xyz: no layer type opens this file")
    assert "stripes (.stripes)" in lines[0] and "vector (.geojson .json)" in lines[0]


@pytest.mark.slow
def test_render_explicit_layer_type(site, tmp_path) -> None:
    lines = tmp_path / "lines.geojson"
    lines.write_text('{"type": "LineString", "coordinates": [[0, 0], [10, 10]]}')
    out = tmp_path / "x.png"
    # The points type, chosen explicitly, is asked even though lines.geojson holds lines.
    proc = _run(
        site, tmp_path, "render", "--size", SIZE, "--out", str(out), "--layer", f"points:{lines}"
    )
    assert proc.returncode == 2 and not out.exists()
    assert proc.stderr.strip() == "globeview: error: lines.geojson: no Point geometry"
    proc = _run(
        site, tmp_path, "render", "--size", SIZE, "--out", str(out), "--layer", f"gpx:{lines}"
    )
    assert proc.returncode == 2 and "no enabled layer type named 'gpx'" in proc.stderr
    assert "stripes" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    proc = _run(
        site, tmp_path, "render", "--size", SIZE, "--out", str(out), "--layer", f"vector:{lines}"
    )
    assert proc.returncode == 0, proc.stderr


@pytest.mark.slow
def test_infinite_point_coordinates_are_the_users_error(site, tmp_path) -> None:
    """1e400 parses as infinity: the built-in points type refuses the file in one line and
    stays enabled (it used to hand the host garbage and be disabled for it)."""
    f = tmp_path / "inf.geojson"
    f.write_text('{"type": "Point", "coordinates": [1e400, 0]}')
    out = tmp_path / "x.png"
    proc = _run(site, tmp_path, "render", "--size", SIZE, "--out", str(out), "--layer", str(f))
    assert proc.returncode == 2 and not out.exists()
    assert proc.stderr.strip() == (
        "globeview: error: inf.geojson: coordinates are not WGS84 lon/lat degrees"
    )
