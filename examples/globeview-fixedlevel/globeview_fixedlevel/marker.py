"""`MarkerTool`: a left click drops a marker at the picked point; Escape clears them.

A tool with settings: the host builds the controls (a spin box for ``size_px``, a combo box
for ``color``, a check box for ``numbered``) from the `Setting`s, persists the values and
calls ``configure``; the tool reads them from ``self.values``.
"""

from __future__ import annotations

from globeview.plugins.api import KeyEvent, Marker, Overlay, PointerEvent, Setting, Tool, ViewState

#: The colours offered by the ``color`` setting (RGBA 0..1); "red" is `Marker`'s default.
COLORS: dict[str, tuple[float, float, float, float]] = {
    "red": (1.0, 0.2, 0.1, 1.0),
    "yellow": (1.0, 0.9, 0.1, 1.0),
    "cyan": (0.1, 0.9, 1.0, 1.0),
}


class MarkerTool(Tool):
    """Records the picked positions of left clicks and draws one marker per click.

    ``markers`` holds (lon, lat, height) in degrees and metres; the overlay draws them at
    their ECEF positions (``PointerEvent.picked``), labelled 1, 2, ... when ``numbered``.
    """

    name = "marker"
    label = "Drop markers"
    settings = (
        Setting("size_px", "float", 10.0, min=2.0, max=64.0, label="Size", help="Pixels."),
        Setting("color", "choice", "red", choices=tuple(COLORS), label="Colour"),
        Setting("numbered", "bool", True, label="Numbered", help="Label markers 1, 2, ..."),
    )

    def __init__(self, context=None) -> None:
        super().__init__(context)
        self.markers: list[tuple[float, float, float]] = []
        self._ecef: list[tuple[float, float, float]] = []

    def on_mouse(self, event: PointerEvent) -> bool:
        if event.kind != "press" or event.button != "left" or event.picked is None:
            return False
        self._ecef.append(tuple(map(float, event.picked)))
        if event.lonlat is not None:
            self.markers.append(tuple(map(float, event.lonlat)))
        if self.context is not None:
            self.context.logger.info("marker %d at %s", len(self._ecef), event.lonlat)
            self.context.renderer.request_redraw()
        return True

    def on_key(self, event: KeyEvent) -> bool:
        if event.kind == "press" and event.key == "Escape" and self._ecef:
            self.markers.clear()
            self._ecef.clear()
            return True
        return False

    def overlay(self, view: ViewState) -> list[Overlay]:
        size = float(self.values["size_px"])
        color = COLORS[self.values["color"]]
        numbered = bool(self.values["numbered"])
        return [
            Marker(p, color=color, size_px=size, label=str(i + 1) if numbered else "")
            for i, p in enumerate(self._ecef)
        ]
