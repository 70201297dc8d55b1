"""The status bar's cursor height (issue #16): orthometric "m a.s.l." by default, ellipsoidal
"m ell." by the View menu's setting (persisted in QSettings); the two differ by the EGM96
undulation at the picked place. A real window under a display, the real renderer."""

from __future__ import annotations

import re

import numpy as np
import pytest
from PyQt6.QtCore import QPoint

pytestmark = pytest.mark.gui

#: Looking north-ish over the White Mountains (SRTM N44W072 among the embedded data).
WHITE_MOUNTAINS = (-71.3, 44.15, 9000.0, 0.0, -30.0)


def _reading(text: str) -> tuple[float, str]:
    """(height, unit) from the cursor label ``44.2°N 71.3°W  1,917 m a.s.l.``."""
    m = re.search(r"(-?[\d,]+) (m a\.s\.l\.|m ell\.)$", text)
    assert m, text
    return float(m.group(1).replace(",", "")), m.group(2)


def test_cursor_height_orthometric_by_default_and_ellipsoidal_by_setting(
    make_window, qtbot, tmp_path
):
    from globeview.model.camera import Camera
    from globeview.terrain.dem.vdatum import egm96

    settings = tmp_path / "heights.ini"
    win = make_window(camera=Camera.from_lonlat(*WHITE_MOUNTAINS), settings_path=settings)
    assert not win.ellipsoidal_action.isChecked()
    g = win.globe
    qtbot.mouseMove(g, QPoint(g.width() // 2 + 3, g.height() // 2 + 40))
    qtbot.waitUntil(lambda: "m a.s.l." in win.status.cursor.text(), timeout=5000)
    pick = win.status._last_pick
    assert pick is not None and pick.on_terrain
    assert -72.0 < pick.lon < -71.0 and 44.0 < pick.lat < 45.0
    ortho, unit = _reading(win.status.cursor.text())
    assert unit == "m a.s.l."

    win.ellipsoidal_action.trigger()  # View > Ellipsoidal Heights
    ell, unit = _reading(win.status.cursor.text())
    assert unit == "m ell."
    assert ell == round(pick.height)  # the pick is ellipsoidal: what the mesh holds
    n = float(np.asarray(egm96().undulation(np.array([pick.lon]), np.array([pick.lat])))[0])
    assert -40.0 < n < -15.0  # about -27.5 m in New Hampshire
    # Both readings are rounded to the metre: they differ by N within 1 m.
    assert abs((ell - ortho) - n) <= 1.0, (ell, ortho, n)

    # Persisted: a new window with the same settings starts with ellipsoidal heights.
    assert win.qsettings.value("view/height_reference") == "ellipsoidal"
    win2 = make_window(camera=Camera.from_lonlat(*WHITE_MOUNTAINS), settings_path=settings)
    assert win2.ellipsoidal_action.isChecked()
    assert win2.status.height_reference == "ellipsoidal"


def test_layer_panel_opens_a_dem_with_the_chosen_vertical_datum(make_window, small_dem, qtbot):
    """Layers > "Open DEMs as": a DEM declared as ellipsoidal heights is stored unchanged, in a
    cache store of its own (the default EGM96 store of the same file is another folder, so a
    re-open never rebuilds a store in use); the row's tooltip says which datum it has."""
    from globeview.terrain.dem.vdatum import egm96
    from globeview.terrain.sources import store_path_for
    from globeview.ui.layer_panel import VDATUM_CHOICES
    from globeview.ui.loading import open_store

    win = make_window()
    combo = win.layer_panel.vdatum_combo
    combo.setCurrentIndex([v for _, v in VDATUM_CHOICES].index("ellipsoid"))
    win.files.open_paths([str(small_dem)])
    qtbot.waitUntil(lambda: "hill" in [ly.name for ly in win.terrain.layers], timeout=60000)
    layer = next(ly for ly in win.terrain.layers if ly.name == "hill")
    assert layer.store.path != store_path_for(small_dem)
    assert [s.vertical_datum for s in layer.store.manifest.sources] == ["ellipsoid"]
    tip = win.layer_panel.list.item(0).toolTip()
    assert "heights: WGS84 ellipsoid" in tip, tip

    default = open_store(small_dem)  # the file's own datum: a plain GeoTIFF -> EGM96
    assert default.path == store_path_for(small_dem)
    key = (default.max_level, *_centre_tile(default))
    ell, geo = layer.store.heights(key), default.heights(key)
    lon, lat = _node_lonlat(default, key)
    n = egm96().undulation(lon, lat)
    data = np.isfinite(ell) & np.isfinite(geo)  # the tile reaches past the 1-degree DEM
    assert data.sum() > 100
    np.testing.assert_allclose((geo - ell)[data], n[data], atol=0.01)


def _centre_tile(store) -> tuple[int, int]:
    """(x, y) of the finest-level tile at the store's footprint centre."""
    from globeview.terrain.quadtree import tiles_covering

    w, s, e, n = store.bounds
    lon, lat, eps = (w + e) / 2, (s + n) / 2, 1e-6
    xs, ys = tiles_covering(store.max_level, lon - eps, lat - eps, lon + eps, lat + eps)
    return int(xs[0]), int(ys[0])


def _node_lonlat(store, key) -> tuple[np.ndarray, np.ndarray]:
    """Longitudes and latitudes (degrees) of a tile's nodes, row 0 at its north edge."""
    from globeview.terrain.quadtree import TileKey, tile_bounds

    w, s, e, n = tile_bounds(TileKey(*key))
    size = store.heights(key).shape[0]
    lon, lat = np.meshgrid(np.linspace(w, e, size), np.linspace(n, s, size))
    return lon, lat
