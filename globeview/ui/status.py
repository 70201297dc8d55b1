"""The status bar: cursor position and height, camera altitude, frame figures, active LOD
provider, and one-line notices (non-modal errors).

Heights under the cursor (issue #16): picking returns the ellipsoidal height h the mesh holds;
the bar shows, by the View menu's setting, the orthometric height H = h - N ("m a.s.l.", the
default: what maps and SRTM call elevation) or h itself ("m ell."), N being the EGM96 geoid
undulation at the picked lon/lat."""

from __future__ import annotations

import logging

import numpy as np
from PyQt6.QtWidgets import QLabel, QStatusBar, QWidget

from globeview.errors import GlobeviewError
from globeview.lod.render_set import FrameStats
from globeview.render.picking import Pick

log = logging.getLogger("globeview.ui")

#: How long a notice stays in the status bar (ms).
NOTICE_MS = 10000

#: The two height references of the cursor read-out and their unit labels.
ORTHOMETRIC = "orthometric"
ELLIPSOIDAL = "ellipsoidal"
HEIGHT_UNITS = {ORTHOMETRIC: "m a.s.l.", ELLIPSOIDAL: "m ell."}


def format_lonlat(lon: float, lat: float) -> str:
    """``49.28000°N 123.12000°W`` (degrees, five decimals ≈ 1 m)."""
    return f"{_hemisphere(lat, 'N', 'S')} {_hemisphere(lon, 'E', 'W')}"


def _hemisphere(deg: float, positive: str, negative: str) -> str:
    """``|deg|`` to five decimals and its hemisphere letter. What shows as zero (a negative
    zero, -4e-6) is on the equator or the prime meridian: N or E, never 0.00000°S."""
    shown = f"{abs(deg):.5f}"
    return f"{shown}°{negative if deg < 0 and float(shown) != 0.0 else positive}"


def format_distance(m: float) -> str:
    """Metres below 10 km, kilometres above."""
    return f"{m / 1000.0:,.1f} km" if abs(m) >= 10000.0 else f"{m:,.0f} m"


#: Most provider stats entries the LOD field's tooltip lists.
TOOLTIP_STATS = 16


def provider_tooltip(stats: FrameStats) -> str:
    """The LOD field's tooltip: the provider that drew the last frame, the tiles it drew per
    quadtree level, and the provider's own counters (`FrameStats.provider_stats`, already
    cleaned by the renderer: JSON scalars, clipped), a line each."""
    lines = [f"Active LOD provider: {stats.lod_provider or '—'}"]
    if stats.levels:
        lines.append(
            "Tiles per level: " + ", ".join(f"L{lv}: {n}" for lv, n in stats.levels.items())
        )
    items = list(stats.provider_stats.items())
    if items:
        lines.append(f"{stats.lod_provider or 'Provider'} stats:")
        for key, value in items[:TOOLTIP_STATS]:
            shown = f"{value:.4g}" if isinstance(value, float) else str(value)
            lines.append(f"  {key} = {shown[:60]}")
        if len(items) > TOOLTIP_STATS:
            lines.append(f"  ... {len(items) - TOOLTIP_STATS} more")
    if stats.provider_stats_dropped:
        lines.append(f"  ({stats.provider_stats_dropped} entries dropped: not numbers or text)")
    return "\n".join(lines)


def loading_text(stats: FrameStats) -> str:
    """The loading field: "loading N tiles" while the frame's tiles stream in, with
    ", M failed" when some could not be built ("M tiles failed" once nothing else loads);
    "" when the view is complete."""
    failed = int(stats.extra.get("tiles_failed", 0))
    loading = int(stats.tiles_loading)
    parts = []
    if loading:
        parts.append(f"loading {loading} tile{'s' if loading != 1 else ''}")
    if failed:
        parts.append(
            f"{failed} failed" if loading else f"{failed} tile{'s' if failed != 1 else ''} failed"
        )
    return ", ".join(parts)


class StatusBar(QStatusBar):
    """Permanent fields (cursor, altitude, fps, triangles, tiles, LOD) plus transient notices."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.cursor = QLabel("—")
        self.height_reference = ORTHOMETRIC
        self._last_pick: Pick | None = None
        self._geoid_failed = False
        self.altitude = QLabel("alt —")
        self.altitude.setToolTip("Camera height above the WGS84 ellipsoid")
        self.fps = QLabel("— fps")
        self.triangles = QLabel("0 tris")
        self.tiles = QLabel("0 tiles")
        self.tiles.setToolTip("Tiles drawn")
        #: "loading N tiles" while tiles stream in (", M failed" for tiles that could not be
        #: built, which stay stood in by coarser ones); empty when the view is complete.
        self.loading = QLabel("")
        self.loading.setToolTip(
            "Tiles of this view still being built in the background (coarser ones are drawn "
            "until they arrive)"
        )
        self.lod = QLabel("LOD —")
        self.lod.setToolTip("Active LOD provider")
        fields = (self.cursor, self.altitude, self.fps, self.triangles, self.tiles, self.loading)
        for w in (*fields, self.lod):
            self.addPermanentWidget(w)
        self._cursor_tooltip()

    def set_height_reference(self, reference: str) -> None:
        """Show cursor heights as `ORTHOMETRIC` (m a.s.l.) or `ELLIPSOIDAL` (m ell.)."""
        if reference not in HEIGHT_UNITS:
            raise ValueError(f"unknown height reference {reference!r}")
        self.height_reference = reference
        self._cursor_tooltip()
        self.show_pick(self._last_pick)

    def _cursor_tooltip(self) -> None:
        above = (
            "the EGM96 geoid (sea level)"
            if self.height_reference == ORTHOMETRIC
            else ("the WGS84 ellipsoid")
        )
        self.cursor.setToolTip(f"Lon, lat and height above {above} under the cursor")

    def cursor_reading(self, pick: Pick) -> tuple[float, str]:
        """The picked height (m) in the chosen reference and its unit label: h ("m ell."), or
        H = h - N(lon, lat) ("m a.s.l."). Without a geoid (its grid unreadable) the bar says
        "m ell." rather than label h as sea-level height; the cause is logged once."""
        if self.height_reference == ELLIPSOIDAL:
            return pick.height, HEIGHT_UNITS[ELLIPSOIDAL]
        try:
            from globeview.terrain.compose.height_query import geoid_undulation

            n = float(geoid_undulation(np.array([pick.lon]), np.array([pick.lat]))[0])
        except (ImportError, OSError, GlobeviewError) as exc:
            if not self._geoid_failed:
                self._geoid_failed = True
                log.warning("no geoid for sea-level heights, showing ellipsoidal: %s", exc)
            return pick.height, HEIGHT_UNITS[ELLIPSOIDAL]
        return pick.height - n, HEIGHT_UNITS[ORTHOMETRIC]

    def show_pick(self, pick: Pick | None) -> None:
        self._last_pick = pick
        if pick is None:
            self.cursor.setText("—")
            return
        where = format_lonlat(pick.lon, pick.lat)
        if pick.on_terrain:
            value, unit = self.cursor_reading(pick)
            h = f"{value:,.0f} {unit}"
        else:
            h = "ellipsoid"
        self.cursor.setText(f"{where}  {h}")

    def show_altitude(self, height_m: float) -> None:
        self.altitude.setText(f"alt {format_distance(height_m)}")

    def show_frame(self, stats: FrameStats, fps: float) -> None:
        self.fps.setText(f"{fps:.0f} fps")
        self.fps.setToolTip(f"last frame: LOD {stats.lod_ms:.1f} ms, draw {stats.draw_ms:.1f} ms")
        self.triangles.setText(f"{stats.triangles:,} tris")
        self.tiles.setText(f"{stats.tiles_drawn} tiles")
        self.loading.setText(loading_text(stats))
        self.lod.setText(f"LOD {stats.lod_provider or '—'}")
        self.lod.setToolTip(provider_tooltip(stats))

    def notice(self, text: str) -> None:
        """A non-modal one-line message."""
        self.showMessage(text, NOTICE_MS)
