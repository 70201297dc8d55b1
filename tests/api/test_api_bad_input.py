"""Bad input to the Python API: one `GlobeviewError` line each, the globe unchanged and
nothing written to the cache; a kernel without EGL gets one line from render()."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import globeview
from globeview.errors import DemError, GlobeviewError

GEO = "EPSG:4326"


@pytest.fixture
def globe(api_cache, registry):
    """An empty globe (no GL is made by these tests)."""
    return globeview.Globe(registry=registry)


def transform_for(rows: int, cols: int):
    from affine import Affine

    return Affine(1.0 / cols, 0.0, -72.0, 0.0, -1.0 / rows, 45.0)


def cache_files(api_cache: str) -> list[str]:
    return sorted(str(p.relative_to(api_cache)) for p in Path(api_cache).rglob("*"))


@pytest.mark.parametrize(
    ("data", "kwargs", "words"),
    [
        (np.full((50, 50), np.nan), {"crs": GEO}, "every height is NaN"),
        (np.full((50, 50), np.inf), {"crs": GEO}, "every height is NaN or infinite"),
        (np.full((50, 50), -32768, np.int16), {"crs": GEO, "nodata": -32768}, "infinite or nodata"),
        (np.ones((50, 50)), {"crs": GEO, "transform": None}, "needs transform="),
        (np.ones((50, 50)), {}, "needs crs="),
        (np.ones((3, 50, 50)), {"crs": GEO}, "shape (3, 50, 50)"),
        (np.ones(50), {"crs": GEO}, "shape (50,)"),
        (np.ones((1, 50)), {"crs": GEO}, "too small"),
        (np.array([["a", "b"], ["c", "d"]]), {"crs": GEO}, "numbers"),
        (np.ones((50, 50)), {"crs": "EPSG:999999"}, "not a CRS"),
        (np.ones((50, 50)), {"crs": GEO, "transform": (1, 2, 3)}, "3 numbers"),
        (np.ones((50, 50)), {"crs": GEO, "transform": (0, 0, 0, 0, 0, 0)}, "no pixel size"),
        (np.ones((50, 50)), {"crs": GEO, "nodata": "x"}, "nodata must be a number"),
    ],
)
def test_bad_arrays_are_one_line_and_add_nothing(globe, api_cache, data, kwargs, words, capfd):
    """The DemError's line is all: GDAL/PROJ print nothing of their own (an unknown EPSG
    code made PROJ write ``ERROR 1: PROJ: ...`` to the process's stderr)."""
    kwargs = dict(kwargs)
    kwargs.setdefault("transform", transform_for(*data.shape[-2:]) if data.ndim >= 2 else None)
    if data.ndim < 2 and "transform" in kwargs and kwargs["transform"] is None:
        kwargs["transform"] = transform_for(50, 50)
    before = cache_files(api_cache)
    with pytest.raises(DemError) as exc:
        globe.add_dem(data, **kwargs)
    message = str(exc.value)
    assert words in message and "\n" not in message, message
    assert globe.dems == []
    assert cache_files(api_cache) == before
    assert capfd.readouterr().err == ""


def test_a_single_band_3d_array_is_taken(globe, api_cache):
    """(1, rows, cols), as rasterio and rioxarray give a band: one band of heights."""
    y, x = np.mgrid[0:40, 0:40]
    heights = (500.0 + 10.0 * x + 5.0 * y)[None].astype(np.float32)
    globe.add_dem(heights, transform=transform_for(40, 40), crs=GEO, name="ramp")
    assert globe.dems == ["ramp"]
    # Pixel centre (row 20, col 20) of the ramp: 500 + 200 + 100 m above the geoid.
    h = globe.height_at(-72.0 + 20.5 / 40, 45.0 - 20.5 / 40)
    assert h == pytest.approx(800.0 - 27.0, abs=15.0)  # EGM96 N is about -27 m here


def test_other_sources_are_one_line(globe):
    with pytest.raises(GlobeviewError, match="takes a path"):
        globe.add_dem(12345)
    with pytest.raises(GlobeviewError, match="arrays only"):
        globe.add_dem("x.tif", transform=(1, 0, 0, 0, -1, 0))
    with pytest.raises(GlobeviewError):
        globe.add_dem("/no/such/dem.tif")
    with pytest.raises(GlobeviewError, match="not supported"):
        globe.add_dem("ftp://example.invalid/store")
    assert globe.dems == []


def test_a_data_array_without_rioxarray_is_one_line(globe, monkeypatch):
    xr = pytest.importorskip("xarray")
    monkeypatch.setitem(sys.modules, "rioxarray", None)  # import fails as if not installed
    da = xr.DataArray(np.ones((20, 20)), dims=("y", "x"))
    with pytest.raises(DemError, match="pip install rioxarray"):
        globe.add_dem(da)
    assert globe.dems == []


def test_a_data_array_without_crs_is_one_line(globe):
    xr = pytest.importorskip("xarray")
    pytest.importorskip("rioxarray")
    da = xr.DataArray(
        np.ones((20, 20)), dims=("y", "x"), coords={"y": np.arange(20.0), "x": np.arange(20.0)}
    )
    with pytest.raises(DemError, match="no CRS"):
        globe.add_dem(da)
    assert globe.dems == []


@pytest.mark.gl
def test_render_without_egl_is_one_line(tmp_path):
    """A kernel whose EGL finds no driver (libglvnd told of no vendor library): render()
    raises one `RenderError` line naming EGL, the globe stays usable, and its picture in a
    notebook (`_repr_png_`) is None, so Jupyter shows its text."""
    script = (
        "import globeview\n"
        "from globeview.errors import GlobeviewError\n"
        "g = globeview.Globe()\n"
        "try:\n"
        "    g.render((64, 64))\n"
        "except GlobeviewError as exc:\n"
        "    print('ERROR', type(exc).__name__, exc)\n"
        "g.fly_to(10, 10, 1e6)\n"
        "print('camera', round(g.camera.lon))\n"
        "print('png', g._repr_png_())\n"
    )
    env = {
        **os.environ,
        "__EGL_VENDOR_LIBRARY_FILENAMES": str(tmp_path / "none.json"),
        "__EGL_VENDOR_LIBRARY_DIRS": str(tmp_path),
        "GLOBEVIEW_CACHE_DIR": str(tmp_path / "cache"),
    }
    out = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("ERROR RenderError cannot create a headless OpenGL context")
    assert "EGL" in lines[0] and "Traceback" not in out.stderr
    assert lines[1] == "camera 10"
    # A notebook shows the text form instead of a traceback, the reason logged once.
    assert lines[2] == "png None" and "cannot show the globe as an image" in out.stderr


def test_show_without_a_display_is_one_line(globe, monkeypatch):
    for var in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"):
        monkeypatch.delenv(var, raising=False)
    with pytest.raises(GlobeviewError, match="no display") as exc:
        globeview.show(globe)
    assert "globe.render()" in str(exc.value)
    with pytest.raises(GlobeviewError, match=r"takes a globeview\.Globe"):
        globeview.show(globe.model)
