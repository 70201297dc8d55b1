"""The Display toolbar: Go to (fly to a typed place), the vertical exaggeration slider, and
the wireframe and hillshade switches. The controls edit the model's display settings and show
them as they are (``display.events``: set here, from code or a plugin).
"""

from __future__ import annotations

import math

from PyQt6.QtCore import Qt
from PyQt6.QtWidgets import QCheckBox, QLabel, QLineEdit, QSlider, QToolBar, QWidget

from globeview.model.camera import Camera
from globeview.model.display import DisplaySettings
from globeview.ui.errors import ErrorReporter
from globeview.ui.globe_widget import GlobeWidget

#: Seconds the Go to flight takes. Issue #17 asks for a complete view <= 1 s after Go to: a
#: 1 s flight (the other flights' length) alone used all of it; the destination's tiles load
#: while it flies (`GlobeWidget.prefetch_pose`), so a short flight is what makes it possible.
GOTO_FLIGHT_S = 0.5
#: Exaggeration slider: tenths, 0.1x .. 50x.
EXAG_MAX_TENTHS = 500


class ViewToolbar(QToolBar):
    """The Display toolbar of ``parent`` over ``display`` (the model's settings), flying
    ``globe``; a bad Go to entry is a notice through ``errors``. The window subscribes
    `show_display` to the settings' events."""

    def __init__(
        self,
        parent: QWidget,
        display: DisplaySettings,
        globe: GlobeWidget,
        errors: ErrorReporter,
    ) -> None:
        super().__init__("Display", parent)
        self.setObjectName("toolbar-display")
        self.display = display
        self.globe = globe
        self.errors = errors
        self._showing = False  # showing the model's values: the controls do not set them
        self.addWidget(QLabel(" Go to "))
        self.goto_edit = QLineEdit()
        self.goto_edit.setPlaceholderText("lon, lat[, height m[, heading, pitch]]")
        self.goto_edit.setToolTip(
            "Fly to a place: longitude and latitude in degrees, optionally a height in metres "
            "and a heading and pitch in degrees (default: looking straight down)"
        )
        self.goto_edit.setMaximumWidth(220)
        self.goto_edit.returnPressed.connect(lambda: self.go_to(self.goto_edit.text()))
        self.addWidget(self.goto_edit)
        self.addSeparator()
        self.addWidget(QLabel(" Exaggeration "))
        self.exag_slider = QSlider(Qt.Orientation.Horizontal)
        self.exag_slider.setRange(1, EXAG_MAX_TENTHS)
        self.exag_slider.setMaximumWidth(160)
        self.exag_slider.setToolTip("Vertical exaggeration of the terrain (1x = true relief)")
        self.exag_label = QLabel()
        self.addWidget(self.exag_slider)
        self.addWidget(self.exag_label)
        self.addSeparator()
        self.wire_check = QCheckBox("Wireframe")
        self.wire_check.setToolTip("Overlay the triangle edges")
        self.hill_check = QCheckBox("Hillshade")
        self.hill_check.setToolTip("Shade relief with a light from the north-west")
        self.addWidget(self.wire_check)
        self.addWidget(self.hill_check)
        self.exag_slider.valueChanged.connect(self._exaggeration_changed)
        self.wire_check.toggled.connect(self._wireframe_changed)
        self.hill_check.toggled.connect(self._hillshade_changed)

    def _exaggeration_changed(self, tenths: int) -> None:
        if not self._showing:
            self.display.exaggeration = tenths / 10.0

    def _wireframe_changed(self, on: bool) -> None:
        if not self._showing:
            self.display.wireframe = bool(on)

    def _hillshade_changed(self, on: bool) -> None:
        if not self._showing:
            self.display.hillshade = bool(on)

    def show_display(self, *_args: object) -> None:
        """Show the model's display settings in the toolbar (set here, from code or a
        plugin); the label gives the exaggeration exactly, the slider as near as its range
        allows. Moving the controls to show it does not set the model again."""
        d = self.display
        self._showing = True
        try:
            exag = float(d.exaggeration)
            if math.isfinite(exag):
                self.exag_slider.setValue(round(min(max(exag * 10, 1), EXAG_MAX_TENTHS)))
            self.exag_label.setText(f"{exag:.1f}×")
            self.wire_check.setChecked(bool(d.wireframe))
            self.hill_check.setChecked(bool(d.hillshade))
        finally:
            self._showing = False

    def go_to(self, text: str) -> bool:
        """Fly to ``"lon, lat[, height[, heading, pitch]]"`` (degrees, metres; default
        looking straight down); a bad entry is a notice."""
        try:
            vals = [float(v) for v in text.replace(";", ",").split(",") if v.strip()]
            if len(vals) not in (2, 3, 5) or not all(math.isfinite(v) for v in vals):
                raise ValueError
        except ValueError:
            self.errors.notify(
                "go to: expected 'lon, lat', 'lon, lat, height' or "
                f"'lon, lat, height, heading, pitch', not {text!r}"
            )
            return False
        lon, lat = vals[0], vals[1]
        if not (-180.0 <= lon <= 360.0 and -90.0 <= lat <= 90.0):
            self.errors.notify(f"go to: {lon}, {lat} is not a longitude, latitude in degrees")
            return False
        height = vals[2] if len(vals) >= 3 else min(self.globe.camera.height, 2.0e6)
        heading, pitch = (vals[3], vals[4]) if len(vals) == 5 else (0.0, -90.0)
        pose = (lon, lat, max(height, 10.0), heading % 360.0, pitch)
        try:  # the camera's own checks (height range, pitch), before the flight starts
            Camera.from_lonlat(*pose)
        except ValueError as exc:
            self.errors.notify(f"go to: {exc}")
            return False
        self.globe.flight.fly_to(pose, GOTO_FLIGHT_S)
        return True
