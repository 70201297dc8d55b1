"""The dialog asking for the coordinate reference system of a DEM file that has none: the
window's ``--crs``.

The text is checked as it is typed, exactly as ``--crs`` is (`parse_crs`: EPSG:n, WKT or a
PROJ string; an unknown one is the command line's one line, shown under the field), and OK
stays disabled until it is a CRS. The loader (`globeview.ui.loading.DemLoader`) then opens
the file again with it (the CRS keys a store of its own in the cache, as ``--crs`` does).
"""

from __future__ import annotations

from pathlib import Path

from PyQt6.QtWidgets import (
    QDialog,
    QDialogButtonBox,
    QLabel,
    QLineEdit,
    QVBoxLayout,
    QWidget,
)

from globeview.errors import GlobeviewError
from globeview.terrain.dem.reader import parse_crs

__all__ = ["CrsDialog", "ask_crs"]


class CrsDialog(QDialog):
    """Asks for the CRS of ``path``; `crs` is the text typed once accepted.

    Attributes:
        intro: names the file; edit: the CRS field; problem: the one-line reason the text
            is not a CRS yet ("" when it is, or while the field is empty); crs: the accepted
            text, else None.
    """

    def __init__(self, parent: QWidget | None, path: str, reason: str = "") -> None:
        super().__init__(parent)
        name = Path(path).name or path
        self.setWindowTitle("Coordinate reference system")
        self.crs: str | None = None
        self.edit = QLineEdit("")
        self.edit.setPlaceholderText("EPSG:4326")
        self.edit.setToolTip(
            "EPSG:n, WKT or a PROJ string, as the command line's --crs takes; EPSG:4326 for "
            "longitude/latitude degrees on WGS84"
        )
        self.edit.setMinimumWidth(420)
        self.problem = QLabel("")
        self.problem.setStyleSheet("color: #b00020")
        self.buttons = QDialogButtonBox(
            QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel
        )
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        self.intro = QLabel(f"{name} has no coordinate reference system. Open it in this CRS:")
        self.intro.setToolTip(reason)
        layout.addWidget(self.intro)
        layout.addWidget(self.edit)
        layout.addWidget(self.problem)
        layout.addWidget(self.buttons)
        self.edit.textChanged.connect(self._check)
        self._check("")

    def _check(self, text: str) -> bool:
        """Say what is wrong with ``text`` (nothing while the field is empty) and enable OK
        only for a CRS `parse_crs` takes."""
        ok = False
        if not text.strip():
            self.problem.setText("")
        else:
            try:
                parse_crs(text.strip())
            except GlobeviewError as exc:
                self.problem.setText(" ".join(str(exc).split()))
            else:
                self.problem.setText("")
                ok = True
        self.buttons.button(QDialogButtonBox.StandardButton.Ok).setEnabled(ok)
        return ok

    def accept(self) -> None:
        """OK: close with the CRS, or stay open saying what is wrong."""
        text = self.edit.text().strip()
        if self._check(text):
            self.crs = text
            super().accept()


def ask_crs(parent: QWidget | None, path: str, reason: str = "") -> str | None:
    """Ask (modal) for the CRS of the DEM file ``path``, which has none (``reason``: the
    file's error, shown as a tooltip); the CRS typed, or None when cancelled."""
    dialog = CrsDialog(parent, path, reason)
    try:
        return dialog.crs if dialog.exec() == QDialog.DialogCode.Accepted else None
    finally:
        dialog.deleteLater()
