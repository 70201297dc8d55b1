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
    from globeview.render.camera import Camera
    from globeview.terrain.vdatum import egm96

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
