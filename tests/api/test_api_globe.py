"""`globeview.Globe` headless: DEMs from arrays and paths, the camera, LOD settings, measure,
render and save, through the one frame pipeline (real EGL, the real White Mountains DEM)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import globeview
from globeview.errors import GlobeviewError

pytestmark = pytest.mark.gl

#: Mount Washington (degrees) and its summit's orthometric height (m; USGS 1917 m, SRTM's
#: 90 m posts read a little lower).
WASHINGTON = (-71.3036, 44.2705)


def terrain_pixels(rgba: np.ndarray, background: tuple[float, float, float]) -> float:
    """Fraction of pixels that are not the background colour."""
    bg = np.round(np.asarray(background) * 255).astype(int)
    diff = np.abs(rgba[..., :3].astype(int) - bg).max(axis=2)
    return float((diff > 8).mean())


def test_render_is_rgba_of_the_size_asked_with_terrain(wm_globe):
    rgba = wm_globe.render((320, 200))
    assert rgba.shape == (200, 320, 4) and rgba.dtype == np.uint8
    assert (rgba[..., 3] == 255).all()
    # Looking at the mountains from 9 km up at -30 degrees: the lower half is ground.
    assert terrain_pixels(rgba[100:], wm_globe.display.background) > 0.95
    # Not a flat colour: hillsides are shaded differently.
    assert rgba[100:, :, :3].std() > 5.0


def test_the_dem_is_drawn_not_the_ellipsoid(wm_globe, registry, api_cache):
    """The same view without the DEM differs: the terrain relief is what is drawn."""
    with_dem = wm_globe.render((240, 160)).astype(int)
    bare = globeview.Globe(registry=registry)
    try:
        bare.camera = wm_globe.camera
        without = bare.render((240, 160)).astype(int)
    finally:
        bare.close()
    assert np.abs(with_dem - without).max(axis=2).mean() > 10


def test_camera_round_trips_in_degrees_and_metres(wm_globe):
    before = wm_globe.camera
    try:
        pose = wm_globe.fly_to(-71.3, 44.27, 15000.0, heading=20.0, pitch=-45.0)
        assert pose.lon == pytest.approx(-71.3, abs=1e-9)
        assert pose.lat == pytest.approx(44.27, abs=1e-9)
        assert pose.height == pytest.approx(15000.0, abs=1e-3)
        assert pose.heading == pytest.approx(20.0, abs=1e-6)
        assert pose.pitch == pytest.approx(-45.0, abs=1e-6)
        assert wm_globe.fly_to(-71.0, 44.0).height == pytest.approx(15000.0, abs=1e-3)
    finally:
        wm_globe.camera = before
    assert wm_globe.camera.lon == pytest.approx(before.lon, abs=1e-9)


def test_camera_refuses_bad_values_in_one_line(wm_globe):
    before = wm_globe.camera
    with pytest.raises(GlobeviewError, match="latitude") as exc:
        wm_globe.fly_to(0.0, 95.0, 1000.0)
    assert "\n" not in str(exc.value)
    with pytest.raises(GlobeviewError, match="camera takes"):
        wm_globe.camera = (1.0, 2.0)
    assert wm_globe.camera == before


@pytest.mark.parametrize("value", [math.inf, math.nan, -1.0, "x"])
def test_display_settings_refuse_bad_values_in_one_line(wm_globe, value):
    before = wm_globe.display.exaggeration
    with pytest.raises(GlobeviewError, match="exaggeration") as exc:
        wm_globe.display.exaggeration = value
    assert "\n" not in str(exc.value) and isinstance(exc.value, ValueError)
    assert wm_globe.display.exaggeration == before


def test_measure_profile_crosses_mount_washington(wm_globe):
    profile = wm_globe.measure((-71.40, 44.2705), (-71.20, 44.2705), samples=201)
    assert profile.s_m.shape == profile.height_m.shape == (201,)
    assert profile.distance_m == pytest.approx(15_968, abs=2)  # 0.2 deg of longitude at 44.27 N
    assert 85.0 < profile.azimuth_deg < 95.0  # due east
    top = int(np.nanargmax(profile.height_m))
    assert profile.lon[top] == pytest.approx(WASHINGTON[0], abs=0.01)
    assert 1800.0 < profile.height_m[top] < 1960.0
    # Orthometric + the geoid (about -27 m here) is ellipsoidal.
    assert np.nanmedian(profile.ellipsoidal_m - profile.height_m) == pytest.approx(-27.5, abs=3)


def test_measure_refuses_bad_points_in_one_line(wm_globe):
    with pytest.raises(GlobeviewError, match="latitude"):
        wm_globe.measure((0.0, 91.0), (1.0, 1.0))
    with pytest.raises(GlobeviewError, match="B must be"):
        wm_globe.measure((0.0, 1.0), "north")
    with pytest.raises(GlobeviewError, match="samples"):
        wm_globe.measure((0.0, 1.0), (1.0, 1.0), samples=1)


def test_lod_provider_and_settings(wm_globe):
    assert "chunked-sse" in wm_globe.lod_providers()
    assert wm_globe.lod == "chunked-sse"
    values = wm_globe.set_lod("distance-regions")
    try:
        assert wm_globe.lod == "distance-regions" and values == wm_globe.lod_settings()
        key, value = next(iter(values.items()))
        with pytest.raises(GlobeviewError, match="no setting"):
            wm_globe.set_lod("chunked-sse", no_such_setting=1)
        assert wm_globe.lod == "distance-regions"  # refused: nothing changed
        rgba = wm_globe.render((160, 120))
        assert terrain_pixels(rgba[60:], wm_globe.display.background) > 0.9
        assert wm_globe.session.last.stats.lod_provider == "distance-regions"
        del key, value
    finally:
        wm_globe.lod = "chunked-sse"


def test_lod_setting_values_are_checked_and_applied(wm_globe):
    settings = wm_globe.set_lod("chunked-sse")
    numeric = [k for k, v in settings.items() if isinstance(v, float)]
    assert numeric, settings
    key = numeric[0]
    with pytest.raises(GlobeviewError, match=key):
        wm_globe.set_lod("chunked-sse", **{key: float("nan")})
    assert wm_globe.lod_settings() == settings


def test_unknown_lod_name_is_one_line_and_changes_nothing(wm_globe):
    with pytest.raises(GlobeviewError) as exc:
        wm_globe.lod = "no-such-lod"
    assert "no-such-lod" in str(exc.value) and "\n" not in str(exc.value)
    assert wm_globe.lod == "chunked-sse"
    with pytest.raises(GlobeviewError):
        globeview.Globe(lod="no-such-lod")


def test_save_writes_the_png_render_draws(wm_globe, tmp_path):
    from PIL import Image

    out = wm_globe.save(tmp_path / "wm.png", size=(200, 120))
    with Image.open(out) as im:
        assert im.size == (200, 120) and im.mode == "RGBA"
        np.testing.assert_array_equal(np.asarray(im), wm_globe.render((200, 120)))
    with pytest.raises(GlobeviewError):
        wm_globe.save(tmp_path / "no-folder" / "x.png")
    with pytest.raises(GlobeviewError):
        wm_globe.save(tmp_path / "x.jpg")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["wm.png"]


@pytest.mark.parametrize("size", [(8, 8), (100,), "800x600", (100.5, 80), (True, 80)])
def test_render_refuses_bad_sizes(wm_globe, size):
    with pytest.raises(GlobeviewError, match="size"):
        wm_globe.render(size)


def test_add_dem_from_a_path_and_remove(wm_globe, api_cache):
    from globeview.terrain.dem.data import EMBEDDED_DATA_DIR

    layer = wm_globe.add_dem(EMBEDDED_DATA_DIR / "craterlake-elev-16bit-30m.tif")
    try:
        assert wm_globe.dems == ["white_mountains", "craterlake-elev-16bit-30m"]
        west, south, east, north = layer.store.bounds
        assert west < -122.1 < east and south < 42.94 < north  # Crater Lake
        h = wm_globe.height_at((west + east) / 2, (south + north) / 2)
        assert 1000.0 < h < 2800.0
        assert math.isnan(wm_globe.height_at(-40.0, 0.0))  # no DEM there: no terrain
    finally:
        wm_globe.remove_dem("craterlake-elev-16bit-30m")
    assert wm_globe.dems == ["white_mountains"]


def test_array_dem_is_cached_by_content(wm_globe, white_mountains, api_cache):
    """Adding the same array again reuses its GeoTIFF and store (no second file)."""
    from pathlib import Path

    heights, transform, crs = white_mountains
    before = sorted(Path(api_cache, "arrays").iterdir())
    wm_globe.add_dem(heights, transform=transform, crs=crs, name="again")
    try:
        assert sorted(Path(api_cache, "arrays").iterdir()) == before
    finally:
        wm_globe.remove_dem("again")


def test_add_overlay_and_the_model_events(wm_globe):
    from globeview.terrain.dem.data import EMBEDDED_DATA_DIR

    seen = []
    wm_globe.model.events.overlays.connect(lambda: seen.append("overlays"))
    layer = wm_globe.add_overlay(EMBEDDED_DATA_DIR / "ne_110m_countries.geojson")
    try:
        assert wm_globe.overlays == [layer] and seen
        wm_globe.render((120, 80))
    finally:
        wm_globe.remove_overlay(layer)
    assert wm_globe.overlays == []
    with pytest.raises(GlobeviewError, match="no such file"):
        wm_globe.add_overlay("/no/such/file.geojson")


def test_repr_png_is_a_png_of_the_last_size(wm_globe):
    import io

    from PIL import Image

    wm_globe.render((180, 100))
    data = wm_globe._repr_png_()
    with Image.open(io.BytesIO(data)) as im:
        assert im.format == "PNG" and im.size == (180, 100)
    assert "white_mountains" in repr(wm_globe)


def test_a_dropped_globe_releases_its_gl(registry, api_cache):
    """Without close(): the session's GL objects and the context are released when the
    globe is collected (the finalizer), and close() twice is harmless."""
    import gc

    globe = globeview.Globe(registry=registry)
    globe.render((32, 32))
    session = globe.session
    ctx = session.ctx
    del globe
    gc.collect()
    assert type(ctx.mglo).__name__ == "InvalidObject"  # the context was released
    other = globeview.Globe(registry=registry)
    other.render((32, 32))
    other.close()
    other.close()
    assert other.session is None


def test_add_dem_from_a_data_array_matches_the_numpy_array(wm_globe, white_mountains):
    """A DataArray with rioxarray's CRS and coordinates (no transform given): the same
    heights, in the same place, as the numpy array with its transform."""
    xr = pytest.importorskip("xarray")
    pytest.importorskip("rioxarray")
    heights, transform, crs = white_mountains
    rows, cols = heights.shape
    x = transform.c + transform.a * (np.arange(cols) + 0.5)  # pixel centres
    y = transform.f + transform.e * (np.arange(rows) + 0.5)
    da = xr.DataArray(heights[None], dims=("band", "y", "x"), coords={"y": y, "x": x})
    da = da.rio.write_crs(crs).rio.write_nodata(-32768)
    da.name = "wm_xarray"
    layer = wm_globe.add_dem(da)
    try:
        assert layer.name == "wm_xarray" and wm_globe.dems[-1] == "wm_xarray"
        np.testing.assert_allclose(layer.store.bounds, wm_globe.terrain.layers[0].store.bounds)
        here = wm_globe.height_at(*WASHINGTON)
        wm_globe.terrain.set_visible("wm_xarray", False)
        assert wm_globe.height_at(*WASHINGTON) == pytest.approx(here, abs=1e-6)
    finally:
        wm_globe.remove_dem("wm_xarray")


def test_render_and_measure_leave_what_a_shared_registry_hands_plugins(wm_globe, registry):
    """A window sharing the registry keeps its own hooks: a headless frame or a measurement
    attaches this globe's session and terrain for its duration only."""
    hooks, scene = object(), object()
    before = registry.host_objects()
    registry.attach(renderer=hooks, scene=scene)
    other = globeview.Globe(registry=registry)
    try:
        other.render((32, 32))  # its session is made
        other.close()
        wm_globe.render((64, 48))
        wm_globe.measure((-71.4, 44.27), (-71.2, 44.27), samples=16)
        now = registry.host_objects()
        assert now["renderer"] is hooks and now["scene"] is scene
    finally:
        registry.attach(**before)
