"""The example notebook (docs/notebooks/white_mountains.ipynb) executed on a real IPython
kernel with nbclient, its outputs checked: the globe's PNG shows the White Mountains (not a
blank or flat picture), the measured profile peaks at Mount Washington, the widget is made.
And the jupyter_rfb widget itself: frames of its size, drag and wheel move the camera."""

from __future__ import annotations

import base64
import io
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.gl, pytest.mark.slow]

NOTEBOOK = Path(__file__).resolve().parents[2] / "docs" / "notebooks" / "white_mountains.ipynb"


@pytest.fixture(scope="module")
def executed(api_cache):
    """The notebook after a run on a fresh python3 kernel (cwd: its folder), its DEM
    ingested into a cache folder of the module's own (the kernel inherits the variable)."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        kernel_name="python3",
        timeout=600,
        resources={"metadata": {"path": str(NOTEBOOK.parent)}},
    )
    client.execute()
    return nb


def outputs_of(nb, marker: str) -> list:
    """The outputs of the code cell whose source contains ``marker``."""
    cells = [c for c in nb.cells if c.cell_type == "code" and marker in c.source]
    assert len(cells) == 1, marker
    return cells[0].outputs


def test_the_globe_shows_itself_as_a_png_of_the_mountains(executed):
    from PIL import Image

    pngs = [o for o in outputs_of(executed, "globe.render(") if "image/png" in o.get("data", {})]
    assert len(pngs) == 1
    with Image.open(io.BytesIO(base64.b64decode(pngs[0]["data"]["image/png"]))) as im:
        assert im.size == (800, 450)
        rgb = np.asarray(im.convert("RGB")).astype(int)
    ground = rgb[225:]  # the lower half looks at the ground from 9 km at -30 degrees
    assert (ground.max(axis=2) > 24).mean() > 0.95  # not the black of space
    # The hypsometric tint: green valleys and brown summits (the bare ellipsoid, or a DEM
    # drawn flat, is one colour), each a good part of the picture.
    r, g = ground[..., 0], ground[..., 1]
    assert (g > r + 20).mean() > 0.05  # low ground
    assert (r > g + 5).mean() > 0.05  # the Presidential Range
    # Hillshade: slopes facing the light and away from it.
    luminance = ground.mean(axis=2)
    assert luminance.std() > 10.0


def test_the_profile_peaks_at_mount_washington(executed):
    text = "".join(o.get("text", "") for o in outputs_of(executed, "globe.measure("))
    assert float(text.split(" km due east")[0]) == pytest.approx(15.97, abs=0.01)
    highest = float(text.split("highest ")[1].split(" m")[0])
    assert 1850.0 < highest < 1960.0  # Mount Washington, 1917 m
    lon = float(text.split(" at ")[1].split(",")[0])
    assert lon == pytest.approx(-71.303, abs=0.005)


def test_the_widget_cell_makes_a_jupyter_rfb_widget(executed):
    outs = outputs_of(executed, "globe.widget(")
    assert not [o for o in outs if o.output_type == "error"], outs
    bundles = [o.get("data", {}) for o in outs if o.output_type == "execute_result"]
    assert any("application/vnd.jupyter.widget-view+json" in b for b in bundles), bundles


@pytest.fixture
def widget(wm_globe):
    pytest.importorskip("jupyter_rfb")
    before = wm_globe.camera
    w = wm_globe.widget(size=(200, 120))
    yield w
    wm_globe.camera = before
    w.close()


def test_widget_frames_have_its_size(widget):
    frame = widget.get_frame()
    assert frame.shape == (120, 200, 4) and frame.dtype == np.uint8
    widget.handle_event({"event_type": "resize", "width": 150, "height": 100, "pixel_ratio": 2})
    assert widget.get_frame().shape == (200, 300, 4)


def test_widget_drag_turns_and_wheel_zooms(widget, wm_globe):
    widget.get_frame()  # a frame to pick the grabbed point from
    start = wm_globe.camera
    widget.handle_event({"event_type": "pointer_down", "x": 100, "y": 80, "button": 1})
    widget.handle_event({"event_type": "pointer_move", "x": 140, "y": 80, "button": 1})
    widget.handle_event({"event_type": "pointer_up", "x": 140, "y": 80, "button": 1})
    moved = wm_globe.camera
    assert (moved.lon, moved.lat) != pytest.approx((start.lon, start.lat), abs=1e-6)
    assert moved.height == pytest.approx(start.height, rel=0.05)  # orbiting keeps height
    widget.handle_event({"event_type": "wheel", "x": 100, "y": 60, "dx": 0, "dy": -300})
    assert wm_globe.camera.height < moved.height * 0.8  # three notches in
    widget.handle_event({"event_type": "wheel", "x": 100, "y": 60, "dx": 0, "dy": 300})
    assert wm_globe.camera.height == pytest.approx(moved.height, rel=0.05)
