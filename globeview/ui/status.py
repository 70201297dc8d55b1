"""The status bar: cursor position, camera altitude, frame figures, active LOD provider, and
one-line notices (non-modal errors)."""

from __future__ import annotations

from PyQt6.QtWidgets import QLabel, QStatusBar, QWidget

from globeview.render.picking import Pick
from globeview.render.render_set import FrameStats

#: How long a notice stays in the status bar (ms).
NOTICE_MS = 10000


def format_lonlat(lon: float, lat: float) -> str:
    """``49.28000°N 123.12000°W`` (degrees, five decimals ≈ 1 m)."""
    ns = "N" if lat >= 0 else "S"
    ew = "E" if lon >= 0 else "W"
    return f"{abs(lat):.5f}°{ns} {abs(lon):.5f}°{ew}"


def format_distance(m: float) -> str:
    """Metres below 10 km, kilometres above."""
    return f"{m / 1000.0:,.1f} km" if abs(m) >= 10000.0 else f"{m:,.0f} m"


class StatusBar(QStatusBar):
    """Permanent fields (cursor, altitude, fps, triangles, tiles, LOD) plus transient notices."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.cursor = QLabel("—")
        self.cursor.setToolTip("Lon, lat and height above the ellipsoid under the cursor")
        self.altitude = QLabel("alt —")
        self.altitude.setToolTip("Camera height above the WGS84 ellipsoid")
        self.fps = QLabel("— fps")
        self.triangles = QLabel("0 tris")
        self.tiles = QLabel("0 tiles")
        self.tiles.setToolTip("Tiles drawn / loading")
        self.lod = QLabel("LOD —")
        self.lod.setToolTip("Active LOD provider")
        for w in (self.cursor, self.altitude, self.fps, self.triangles, self.tiles, self.lod):
            self.addPermanentWidget(w)

    def show_pick(self, pick: Pick | None) -> None:
        if pick is None:
            self.cursor.setText("—")
            return
        where = format_lonlat(pick.lon, pick.lat)
        h = f"{pick.height:,.0f} m" if pick.on_terrain else "ellipsoid"
        self.cursor.setText(f"{where}  {h}")

    def show_altitude(self, height_m: float) -> None:
        self.altitude.setText(f"alt {format_distance(height_m)}")

    def show_frame(self, stats: FrameStats, fps: float) -> None:
        self.fps.setText(f"{fps:.0f} fps")
        self.fps.setToolTip(f"last frame: LOD {stats.lod_ms:.1f} ms, draw {stats.draw_ms:.1f} ms")
        self.triangles.setText(f"{stats.triangles:,} tris")
        self.tiles.setText(f"{stats.tiles_drawn} tiles / {stats.tiles_loading} loading")
        self.lod.setText(f"LOD {stats.lod_provider or '—'}")

    def notice(self, text: str) -> None:
        """A non-modal one-line message."""
        self.showMessage(text, NOTICE_MS)
