"""The dialog asking for the coordinate reference system of a DEM file that has none: the
window's ``--crs``.

The text is checked as it is typed, exactly as ``--crs`` is (`parse_crs`: EPSG:n, WKT or a
PROJ string; an unknown one is the command line's one line, shown under the field), and OK
stays disabled until it is a CRS. The loader (`globeview.ui.loading.DemLoader`) then opens
the file again with it (the CRS keys a store of its own in the cache, as ``--crs`` does).
"""

from __future__ import annotations

from pathlib import Path

from PyQt6.QtWidgets import QDialog, QWidget

from globeview.ui.checked_text_dialog import CheckedTextDialog

__all__ = ["CrsDialog", "ask_crs"]


class CrsDialog(CheckedTextDialog):
    """Asks for the CRS of ``path``; `crs` is the text typed once accepted.

    Attributes (beyond `CheckedTextDialog`'s): intro names the file (its tooltip: why the
    file has no CRS); crs: the accepted text, else None.
    """

    def __init__(self, parent: QWidget | None, path: str, reason: str = "") -> None:
        self.crs: str | None = None
        super().__init__(
            parent,
            title="Coordinate reference system",
            intro=f"{Path(path).name or path} has no coordinate reference system. "
            "Open it in this CRS:",
            placeholder="EPSG:4326",
            tooltip="EPSG:n, WKT or a PROJ string, as the command line's --crs takes; "
            "EPSG:4326 for longitude/latitude degrees on WGS84",
            width=420,
        )
        self.intro.setToolTip(reason)

    def checked(self, text: str) -> str:
        """``text`` stripped, once `parse_crs` (``--crs``'s check) takes it."""
        from globeview.terrain.dem.reader import parse_crs  # deferred: off the launch path

        parse_crs(text.strip())
        return text.strip()

    def accepted_value(self, value: str) -> None:
        self.crs = value


def ask_crs(parent: QWidget | None, path: str, reason: str = "") -> str | None:
    """Ask (modal) for the CRS of the DEM file ``path``, which has none (``reason``: the
    file's error, shown as a tooltip); the CRS typed, or None when cancelled."""
    dialog = CrsDialog(parent, path, reason)
    try:
        return dialog.crs if dialog.exec() == QDialog.DialogCode.Accepted else None
    finally:
        dialog.deleteLater()
