"""Errors never crash the window: user errors show their one-line message, bugs show
"Unexpected error" with the details folded away, and everything goes to the log.

`ErrorReporter` is the one place the UI reports problems. Its ``show`` callable (a modal
message box by default) is injectable, so tests record messages instead of blocking on a
dialog. `install_excepthook` routes exceptions escaping Qt slots (which PyQt6 would otherwise
turn into an abort) to the reporter.
"""

from __future__ import annotations

import logging
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType

from PyQt6.QtCore import QObject, pyqtSignal
from PyQt6.QtWidgets import QMessageBox, QWidget

from globeview.errors import GlobeviewError

log = logging.getLogger("globeview.ui")


@dataclass(frozen=True)
class UserMessage:
    """What a person sees about an error: a title, one line of text, optional details."""

    title: str
    text: str
    details: str = ""


def describe(exc: BaseException, context: str = "") -> UserMessage:
    """The message shown for ``exc``: a `GlobeviewError`'s own one-line text, or "Unexpected
    error" with the traceback as details for anything else (a bug)."""
    prefix = f"{context}: " if context else ""
    if isinstance(exc, GlobeviewError):
        line = " ".join(str(exc).split()) or type(exc).__name__
        return UserMessage("globeview", prefix + line)
    details = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    summary = " ".join(str(exc).split())
    text = f"{prefix}Unexpected error ({type(exc).__name__}{': ' + summary if summary else ''})"
    return UserMessage("globeview: unexpected error", text, details)


def message_box(parent: QWidget | None, msg: UserMessage) -> None:
    """The default display: a modal warning box, with the traceback under "Show Details"."""
    box = QMessageBox(QMessageBox.Icon.Warning, msg.title, msg.text, parent=parent)
    if msg.details:
        box.setDetailedText(msg.details)
    box.exec()


class ErrorReporter(QObject):
    """Shows errors to the user and logs them.

    Args:
        show: called with each modal `UserMessage` (default: `message_box`).
        parent: the widget dialogs belong to.

    Signals:
        notified(str): a non-modal one-line notice (the status bar shows it).
        reported(object): every `UserMessage`, modal or not (for tests and the log view).
    """

    notified = pyqtSignal(str)
    reported = pyqtSignal(object)

    def __init__(
        self,
        show: Callable[[UserMessage], None] | None = None,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self._parent = parent
        self.show: Callable[[UserMessage], None] = show or (lambda m: message_box(parent, m))
        self.history: list[UserMessage] = []
        self._showing = False

    def error(self, exc: BaseException, context: str = "") -> UserMessage:
        """Report an exception in a dialog (and the log)."""
        msg = describe(exc, context)
        if isinstance(exc, GlobeviewError):
            log.warning("%s", msg.text)
        else:
            log.error("%s\n%s", msg.text, msg.details)
        self._record(msg)
        if not self._showing:  # never stack dialogs when one error triggers another
            self._showing = True
            try:
                self.show(msg)
            finally:
                self._showing = False
        return msg

    def notify(self, text: str) -> None:
        """A non-modal notice: one line in the status bar and the log."""
        log.warning("%s", text)
        msg = UserMessage("globeview", text)
        self._record(msg)
        self.notified.emit(text)

    def _record(self, msg: UserMessage) -> None:
        self.history.append(msg)
        del self.history[:-100]
        self.reported.emit(msg)


ExceptHook = Callable[[type[BaseException], BaseException, TracebackType | None], None]


def install_excepthook(reporter: ErrorReporter) -> ExceptHook:
    """Route uncaught exceptions (e.g. from Qt slots) to ``reporter`` instead of aborting.

    Returns the previous hook so a caller (or a test) can restore it. KeyboardInterrupt and
    SystemExit keep their default handling.
    """
    previous = sys.excepthook

    def hook(etype: type[BaseException], value: BaseException, tb: TracebackType | None) -> None:
        if issubclass(etype, KeyboardInterrupt | SystemExit):
            previous(etype, value, tb)
            return
        if value.__traceback__ is None and tb is not None:
            value = value.with_traceback(tb)
        try:
            reporter.error(value)
        except Exception:  # the reporter itself failed: fall back to the log, never abort
            log.exception("error while reporting an error")

    sys.excepthook = hook
    return previous
