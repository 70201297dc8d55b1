"""The window's ``--crs``: a DEM file without a coordinate reference system makes the window
ask for one in a dialog (checked as it is typed, exactly as ``--crs`` is), then opens the file
with it; cancelling reports the file's one line, as for any file that cannot be opened."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PyQt6.QtCore import QTimer
from PyQt6.QtWidgets import QApplication, QDialogButtonBox

pytestmark = pytest.mark.gui

TIMEOUT_MS = 60000


def _no_crs_dem(path: Path) -> Path:
    """A 64 x 64 hill at 10..11 E, 45..46 N whose GeoTIFF has a geotransform but no CRS."""
    import rasterio
    from affine import Affine

    n = 64
    yy, xx = np.mgrid[0:n, 0:n]
    z = 1500.0 * np.exp(-(((xx - n / 2) ** 2 + (yy - n / 2) ** 2) / (2 * (n / 6) ** 2)))
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=n,
        height=n,
        count=1,
        dtype="float32",
        crs=None,
        transform=Affine(1.0 / n, 0.0, 10.0, 0.0, -1.0 / n, 46.0),
    ) as ds:
        ds.write(z.astype(np.float32), 1)
    return path


def _when_the_dialog_shows(act) -> None:
    """Call ``act(dialog)`` once the CRS dialog is up (it runs modal: exec() blocks)."""
    from globeview.ui.crs_dialog import CrsDialog

    def poll() -> None:
        dialog = QApplication.activeModalWidget()
        if isinstance(dialog, CrsDialog):
            act(dialog)
        else:
            QTimer.singleShot(50, poll)

    QTimer.singleShot(50, poll)


def test_a_dem_without_crs_asks_for_one_and_opens_with_it(
    reused_window, qtbot, tmp_path, errors_shown
):
    from globeview.terrain.sources import store_path_for

    path = _no_crs_dem(tmp_path / "nocrs_hill.tif")
    win = reused_window
    seen: dict[str, object] = {}

    def answer(dialog) -> None:
        ok = dialog.buttons.button(QDialogButtonBox.StandardButton.Ok)
        seen["asked about"] = path.name in dialog.intro.text()
        seen["empty"] = (ok.isEnabled(), dialog.problem.text())
        dialog.edit.setText("EPSG:999999")  # --crs's own check and words
        seen["unknown"] = (ok.isEnabled(), dialog.problem.text())
        dialog.accept()  # Return pressed anyway: stays open
        seen["still open"] = dialog.isVisible() and dialog.crs is None
        dialog.edit.setText("EPSG:4326")
        seen["valid"] = (ok.isEnabled(), dialog.problem.text())
        ok.click()

    _when_the_dialog_shows(answer)
    win.files.open_paths([str(path)])
    qtbot.waitUntil(
        lambda: "nocrs_hill" in [ly.name for ly in win.terrain.layers], timeout=TIMEOUT_MS
    )
    assert seen == {
        "asked about": True,
        "empty": (False, ""),
        "unknown": (False, "unknown CRS 'EPSG:999999' (use e.g. EPSG:4326 or EPSG:32610)"),
        "still open": True,
        "valid": (True, ""),
    }
    assert errors_shown == []
    layer = next(ly for ly in win.terrain.layers if ly.name == "nocrs_hill")
    # Opened with the CRS given: its own store in the cache, as --crs keys it.
    assert layer.store.path == store_path_for(path, crs="EPSG:4326")
    w, s, e, n = layer.store.bounds
    assert (w, s, e, n) == pytest.approx((10.0, 45.0, 11.0, 46.0), abs=0.05)
    assert win.files.recent_files()[0] == str(path)
    qtbot.waitUntil(lambda: not win.files.loader.busy, timeout=TIMEOUT_MS)


def test_cancelling_the_crs_dialog_reports_the_file_in_one_line(
    reused_window, qtbot, tmp_path, errors_shown, wait_frame
):
    path = _no_crs_dem(tmp_path / "nocrs_cancel.tif")
    win = reused_window
    layers = [ly.name for ly in win.terrain.layers]
    n = len(win.errors.history)
    _when_the_dialog_shows(lambda dialog: dialog.reject())
    win.files.open_paths([str(path)])
    qtbot.waitUntil(
        lambda: len(win.errors.history) > n and not win.files.loader.busy, timeout=TIMEOUT_MS
    )
    new = win.errors.history[n:]
    assert len(new) == 1 and errors_shown == new
    assert path.name in new[0].text and "coordinate reference system" in new[0].text
    assert "\n" not in new[0].text and "Unexpected error" not in new[0].text
    assert [ly.name for ly in win.terrain.layers] == layers
    wait_frame(win)
