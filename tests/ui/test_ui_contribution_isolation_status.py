"""A plugin's ``context.renderer.set_status(text)`` in the window (issue #15 item 11): the
text shows in the status bar and is logged at INFO — it is a status line, not a warning, so
it neither reaches a terminal at WARNING nor the error history. A real window."""

from __future__ import annotations

import logging

import pytest

pytestmark = pytest.mark.gui


def test_plugin_status_text_is_shown_not_warned(make_window, caplog) -> None:
    win = make_window()
    context = win.plugins.registry.context("collapse")  # what the collapse tool gets
    text = "collapse: click two places"
    with caplog.at_level(logging.DEBUG):
        context.renderer.set_status(text)
    assert win.status.currentMessage() == text
    mine = [r for r in caplog.records if text in r.getMessage()]
    assert mine and all(r.levelno < logging.WARNING for r in mine), [
        (r.levelname, r.getMessage()) for r in mine
    ]
    assert any(r.levelno == logging.INFO for r in mine)
    assert not any(text in m.text for m in win.errors.history)
