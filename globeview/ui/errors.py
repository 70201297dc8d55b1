"""Errors never crash the window: user errors show their one-line message, bugs show one
line, "Unexpected error (...); details in <log file>", and the traceback goes to that log
file (never into a dialog, never onto stderr).

`ErrorReporter` is the one place the UI reports problems. Its ``show`` callable (a modal
message box by default) is injectable, so tests record messages instead of blocking on a
dialog. `install_excepthook` routes exceptions escaping Qt slots (which PyQt6 would otherwise
turn into an abort) to the reporter.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

from PyQt6.QtCore import QObject, pyqtSignal
from PyQt6.QtWidgets import QMessageBox, QWidget

from globeview.errors import GlobeviewError
from globeview.plugins.isolation import LOG_MAX_BYTES, failure_log_path

log = logging.getLogger("globeview.ui")


def default_log_file() -> Path:
    """Where the window writes tracebacks: the log file plugin failures go to too
    (``globeview.log`` in the cache folder, see `globeview.plugins.isolation.failure_log_path`)."""
    return failure_log_path()


@dataclass(frozen=True)
class UserMessage:
    """What a person sees about an error: a title, one line of text, optional details."""

    title: str
    text: str
    details: str = ""


def describe(exc: BaseException, context: str = "", log_file: Path | None = None) -> UserMessage:
    """The message shown for ``exc``: a `GlobeviewError`'s own one-line text, or for anything
    else (a bug) "Unexpected error (Type: message)" naming ``log_file``, where the traceback
    is written (`ErrorReporter.error` writes it). The text is always one line; the dialog
    never carries a traceback."""
    prefix = f"{context}: " if context else ""
    if isinstance(exc, GlobeviewError):
        line = " ".join(str(exc).split()) or type(exc).__name__
        return UserMessage("globeview", prefix + line)
    summary = " ".join(str(exc).split())
    text = f"{prefix}Unexpected error ({type(exc).__name__}{': ' + summary if summary else ''})"
    where = f"details in {log_file}" if log_file is not None else "details in the log"
    return UserMessage("globeview: unexpected error", f"{text}; {where}")


def write_traceback(log_file: Path, exc: BaseException, text: str) -> bool:
    """Append ``text`` and ``exc``'s traceback to ``log_file`` (moved to ``.1`` first past
    `LOG_MAX_BYTES`); returns False when the file cannot be written."""
    tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    try:
        log_file.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(OSError):  # the registry's policy: one old log is kept
            if log_file.stat().st_size > LOG_MAX_BYTES:
                os.replace(log_file, log_file.with_name(log_file.name + ".1"))
        with log_file.open("a", encoding="utf-8", errors="replace") as f:
            f.write(f"{stamp} ERROR {text}\n{tb}\n")
    except OSError:
        return False
    return True


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
        log_file: where tracebacks of unexpected errors go (default: `default_log_file`,
            decided on first use); user errors are logged there as one line too.

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
        log_file: Path | None = None,
    ) -> None:
        super().__init__(parent)
        self._parent = parent
        self.show: Callable[[UserMessage], None] = show or (lambda m: message_box(parent, m))
        self.history: list[UserMessage] = []
        self._showing = False
        self._log_file = log_file

    @property
    def log_file(self) -> Path:
        """The log file tracebacks go to."""
        if self._log_file is None:
            self._log_file = default_log_file()
        return self._log_file

    def error(self, exc: BaseException, context: str = "") -> UserMessage:
        """Report an exception in a dialog (one line) and the log; a bug's traceback goes to
        the log file only."""
        if isinstance(exc, GlobeviewError):
            msg = describe(exc, context)
            log.warning("%s", msg.text)
            self._log_line(msg.text)
        else:
            msg = describe(exc, context, self.log_file)
            if not write_traceback(self.log_file, exc, msg.text):
                # The log file cannot be written: the traceback goes to the logger instead.
                msg = describe(exc, context)
                log.error("%s", msg.text, exc_info=exc)
            else:
                log.error("%s", msg.text)
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
        self._log_line(text)
        msg = UserMessage("globeview", text)
        self._record(msg)
        self.notified.emit(text)

    def _log_line(self, text: str) -> None:
        try:
            self.log_file.parent.mkdir(parents=True, exist_ok=True)
            with self.log_file.open("a", encoding="utf-8") as f:
                f.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} WARNING {text}\n")
        except OSError:
            pass  # the logger has it; a read-only cache must not break error reporting

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
