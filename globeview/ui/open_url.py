"""File > Open URL...: the dialog asking for the URL of a tile store served over HTTP.

The URL's form is checked as it is typed (`check_store_url`: http(s) only, a host, a port in
range; spaces in the path are encoded): the dialog says what is wrong in one line under the
field and OK stays disabled until it is a URL the remote reader can ask for. Whether a
server answers there, and with a store, is found out off the UI thread by the window's
loader (`DemLoader`), whose failure is one line in a dialog.
"""

from __future__ import annotations

from PyQt6.QtWidgets import QDialog, QWidget

from globeview.terrain.sources import check_store_url
from globeview.ui.checked_text_dialog import CheckedTextDialog

__all__ = ["UrlDialog", "ask_store_url"]


class UrlDialog(CheckedTextDialog):
    """Asks for a store URL; `url` is the checked URL once accepted.

    Attributes (beyond `CheckedTextDialog`'s): url: the checked URL (`check_store_url`)
    after OK, else None.
    """

    def __init__(self, parent: QWidget | None = None, initial: str = "") -> None:
        self.url: str | None = None
        super().__init__(
            parent,
            title="Open URL",
            intro="URL of a tile store:",
            placeholder="https://host/path/store",
            tooltip="The URL of a globeview tile store folder served over HTTP(S) (the folder "
            "that holds manifest.json); tiles are streamed with range requests and cached on "
            "disk",
            width=460,
            initial=initial,
        )

    def checked(self, text: str) -> str:
        """The URL `check_store_url` makes of ``text`` (spaces in the path encoded)."""
        return check_store_url(text)

    def accepted_value(self, value: str) -> None:
        self.url = value


def ask_store_url(parent: QWidget | None, initial: str = "") -> str | None:
    """Show the dialog modally; the checked URL, or None when cancelled."""
    dialog = UrlDialog(parent, initial)
    return dialog.url if dialog.exec() == QDialog.DialogCode.Accepted else None
