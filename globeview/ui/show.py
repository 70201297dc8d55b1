"""`globeview.show(globe)`: the window on a `globeview.Globe` from a script or IPython.

The window shows the globe's own model (`globeview.model.Globe`), registry and overlay
host: what the script changes (``globe.fly_to``, ``globe.add_dem``, ``globe.lod``,
``globe.display``) redraws the window, and what the window changes (navigation, layers, the
LOD provider, a tool) is what the script reads next. In IPython run ``%gui qt`` first: the
window then lives beside the prompt. Elsewhere ``show(globe, block=True)`` runs Qt's event
loop until the window closes.
"""

from __future__ import annotations

from typing import Any

__all__ = ["show"]

#: The QApplication `show` made or found, kept alive (see `show`).
_KEEP: list[Any] = []


def show(globe: Any, *, block: bool = False, settings: Any = None) -> Any:
    """Open the globeview window on ``globe`` (a `globeview.Globe`) and return it (a
    `MainWindow`).

    Args:
        globe: the globe to show; the window edits this very globe.
        block: run Qt's event loop until the window closes (scripts); without it the
            window needs a running loop (IPython's ``%gui qt``, or a Qt application's).
        settings: the window's layout settings (a ``QSettings``; default: the user's).

    Raises a one-line `GlobeviewError` when there is no display to open a window on.
    """
    from globeview.app.globe import Globe
    from globeview.errors import GlobeviewError

    if not isinstance(globe, Globe):
        raise GlobeviewError(f"show() takes a globeview.Globe, not {type(globe).__name__}")
    from globeview.ui.app import create_application, has_display

    if not has_display():
        raise GlobeviewError(
            "no display (DISPLAY/WAYLAND_DISPLAY unset): the window cannot open; use "
            "globe.render() or globe.save() headless"
        )
    from PyQt6.QtCore import QSettings

    from globeview.ui.main_window import MainWindow

    app = create_application()
    # PyQt destroys a QApplication whose Python object is collected: keep ours (IPython's
    # %gui qt keeps its own) for as long as windows may open.
    _KEEP.append(app) if app not in _KEEP else None
    window = MainWindow(
        globe.terrain,
        settings if settings is not None else QSettings("globeview", "globeview"),
        globe.registry,
        model=globe.model,
        overlay_host=globe.overlay_host,
    )
    window.show()
    if block:
        app.exec()
    return window
