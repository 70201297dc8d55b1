"""A dialog asking for one line of text that is checked as it is typed: what is wrong shows in
one line under the field and OK stays disabled until the text passes. The CRS dialog and
File > Open URL... are two of them."""

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

__all__ = ["CheckedTextDialog"]


class CheckedTextDialog(QDialog):
    """One checked line of text. Subclasses give `checked` (the accepted value of a text, or
    `GlobeviewError` saying why not) and receive it in `accepted_value`.

    Attributes:
        intro: the label above the field; edit: the field; problem: the one-line reason the
            text does not pass yet ("" when it does, or while the field is empty); buttons:
            OK and Cancel.
    """

    def __init__(
        self,
        parent: QWidget | None,
        *,
        title: str,
        intro: str,
        placeholder: str,
        tooltip: str,
        width: int,
        initial: str = "",
    ) -> None:
        super().__init__(parent)
        self.setWindowTitle(title)
        self.edit = QLineEdit(initial)
        self.edit.setPlaceholderText(placeholder)
        self.edit.setToolTip(tooltip)
        self.edit.setMinimumWidth(width)
        self.problem = QLabel("")
        self.problem.setWordWrap(False)
        self.problem.setStyleSheet("color: #b00020")
        self.buttons = QDialogButtonBox(
            QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel
        )
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)
        layout = QVBoxLayout(self)
        self.intro = QLabel(intro)
        layout.addWidget(self.intro)
        layout.addWidget(self.edit)
        layout.addWidget(self.problem)
        layout.addWidget(self.buttons)
        self.edit.textChanged.connect(self._check)
        self._check(initial)

    def checked(self, text: str) -> str:
        """The value ``text`` stands for; `GlobeviewError` (one line) when it is not one."""
        raise NotImplementedError

    def accepted_value(self, value: str) -> None:
        """Receives the checked value when OK closes the dialog."""
        raise NotImplementedError

    def _check(self, text: str) -> bool:
        """Say what is wrong with ``text`` (nothing while the field is empty) and enable OK
        only for a text `checked` takes."""
        ok = False
        self.problem.setText("")
        if text.strip():
            try:
                self.checked(text)
            except GlobeviewError as exc:
                self.problem.setText(" ".join(str(exc).split()))
            else:
                ok = True
        ok_button = self.buttons.button(QDialogButtonBox.StandardButton.Ok)
        if ok_button is not None:  # the box made it above; Qt's stubs say it may not exist
            ok_button.setEnabled(ok)
        return ok

    def accept(self) -> None:
        """OK: close with the checked value, or stay open saying what is wrong."""
        text = self.edit.text()
        if self._check(text):
            self.accepted_value(self.checked(text))
            super().accept()
