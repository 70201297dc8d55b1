"""File > Open URL...: the dialog asking for the URL of a tile store served over HTTP.

The URL's form is checked as it is typed (`check_store_url`: http(s) only, a host, a port in
range; spaces in the path are encoded): the dialog says what is wrong in one line under the
field and OK stays disabled until it is a URL the remote reader can ask for. Whether a
server answers there, and with a store, is found out off the UI thread by the window's
loader (`DemLoader`), whose failure is one line in a dialog.
"""

from __future__ import annotations

from PyQt6.QtWidgets import (
    QDialog,
    QDialogButtonBox,
    QLabel,
    QLineEdit,
    QVBoxLayout,
    QWidget,
)

from globeview.errors import GlobeviewError
from globeview.terrain.sources import check_store_url

__all__ = ["UrlDialog", "ask_store_url"]


class UrlDialog(QDialog):
    """Asks for a store URL; `url` is the checked URL once accepted.

    Attributes:
        edit: the URL field; problem: the one-line reason the text is not a store URL yet
            ("" when it is); url: the checked URL (`check_store_url`) after OK, else None.
    """

    def __init__(self, parent: QWidget | None = None, initial: str = "") -> None:
        super().__init__(parent)
        self.setWindowTitle("Open URL")
        self.url: str | None = None
        self.edit = QLineEdit(initial)
        self.edit.setPlaceholderText("https://host/path/store")
        self.edit.setToolTip(
            "The URL of a globeview tile store folder served over HTTP(S) (the folder that "
            "holds manifest.json); tiles are streamed with range requests and cached on disk"
        )
        self.edit.setMinimumWidth(460)
        self.problem = QLabel("")
        self.problem.setWordWrap(False)
        self.problem.setStyleSheet("color: #b00020")
        self.buttons = QDialogButtonBox(
            QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel
        )
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        layout.addWidget(QLabel("URL of a tile store:"))
        layout.addWidget(self.edit)
        layout.addWidget(self.problem)
        layout.addWidget(self.buttons)
        self.edit.textChanged.connect(self._check)
        self._check(initial)

    def _check(self, text: str) -> bool:
        """Say what is wrong with ``text`` (nothing while the field is empty) and enable OK
        only for a URL that passes `check_store_url`."""
        ok = False
        if not text.strip():
            self.problem.setText("")
        else:
            try:
                check_store_url(text)
            except GlobeviewError as exc:
                self.problem.setText(" ".join(str(exc).split()))
            else:
                self.problem.setText("")
                ok = True
        self.buttons.button(QDialogButtonBox.StandardButton.Ok).setEnabled(ok)
        return ok

    def accept(self) -> None:
        """OK: close with the checked URL, or stay open saying what is wrong."""
        if not self._check(self.edit.text()):
            return  # stays open, saying why
        self.url = check_store_url(self.edit.text())
        super().accept()


def ask_store_url(parent: QWidget | None, initial: str = "") -> str | None:
    """Show the dialog modally; the checked URL, or None when cancelled."""
    dialog = UrlDialog(parent, initial)
    return dialog.url if dialog.exec() == QDialog.DialogCode.Accepted else None
