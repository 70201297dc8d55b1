"""File > Open URL... (issue #18): the dialog checks the URL's form as it is typed, URLs the
remote reader cannot read are one line in a dialog (never a traceback, nothing opened), and
store URLs are remembered in Open Recent like files."""

from __future__ import annotations

import pytest
from PyQt6.QtWidgets import QDialogButtonBox

pytestmark = pytest.mark.gui


def test_dialog_says_what_is_wrong_and_enables_ok_only_for_a_store_url(qtbot):
    from globeview.ui.open_url import UrlDialog

    dialog = UrlDialog(None, "")
    qtbot.addWidget(dialog)
    ok = dialog.buttons.button(QDialogButtonBox.StandardButton.Ok)
    assert not ok.isEnabled() and dialog.problem.text() == ""  # empty: nothing to say yet
    for text, needle in [
        ("ftp://example.org/store", "ftp:// URLs are not supported"),
        ("file:///tmp/store", "folder path"),
        ("https://my host/store", "no valid host"),
        ("https://example.org:99999/store", "bad port"),
        ("example.org/store", "not a URL"),
    ]:
        dialog.edit.setText(text)
        assert needle in dialog.problem.text(), (text, dialog.problem.text())
        assert "\n" not in dialog.problem.text()
        assert not ok.isEnabled()
        dialog.accept()  # Return pressed anyway: stays open, no URL
        assert dialog.url is None and dialog.result() == 0
    dialog.edit.setText("  https://example.org/globe data/store/ ")
    assert ok.isEnabled() and dialog.problem.text() == ""
    dialog.accept()
    assert dialog.url == "https://example.org/globe%20data/store"  # a space is sent encoded


@pytest.mark.parametrize(
    ("url", "needle"),
    [
        ("file:///tmp/store", "file://"),
        ("ftp://127.0.0.1/store", "ftp://"),
        ("https://my host/store", "host"),
        ("https://127.0.0.1:0/store", "port"),
        ("https://user:secret@127.0.0.1/store", "passwords"),
    ],
)
def test_unreadable_urls_are_one_line_and_open_nothing(reused_window, errors_shown, url, needle):
    win = reused_window
    layers = [ly.name for ly in win.terrain.layers]
    n = len(win.errors.history)
    assert win.files.open_url(url) is False
    new = win.errors.history[n:]
    assert len(new) == 1 and errors_shown == new, [m.text for m in new]
    assert needle in new[0].text and "\n" not in new[0].text
    assert "Unexpected error" not in new[0].text and not new[0].details
    assert not win.files.loader.busy
    assert [ly.name for ly in win.terrain.layers] == layers
    assert not any(f == url for f in win.files.recent_files())


def test_menu_asks_for_the_url_with_the_last_one_filled_in(reused_window, monkeypatch):
    win = reused_window
    asked: list[str] = []
    opened: list[str] = []
    # The user cancels the dialog:
    monkeypatch.setattr(win.files, "ask_url", lambda _parent, initial: asked.append(initial))
    monkeypatch.setattr(win.files, "open_url", opened.append)
    win.files.open_url_action.trigger()
    assert asked == [""] and opened == []
    win.files.add_recent("https://example.org/a/store")
    win.files.add_recent(__file__)  # a file since: the URL is still the one offered
    offer = "https://example.org/b"
    monkeypatch.setattr(win.files, "ask_url", lambda _p, initial: asked.append(initial) or offer)
    win.files.open_url_action.trigger()
    assert asked[-1] == "https://example.org/a/store"
    assert opened == ["https://example.org/b"]


def test_recent_urls_are_kept_as_urls_and_reopen_by_url(reused_window, monkeypatch):
    win = reused_window
    url = "https://example.org/globe%20data/store"
    win.files.add_recent(url)
    assert win.files.recent_files()[0] == url  # not made into a local path
    action = next(a for a in win.files.recent_menu.actions() if a.text() == url)
    opened: list[str] = []
    monkeypatch.setattr(win.files, "open_url", opened.append)
    action.trigger()
    assert opened == [url]


def test_source_names():
    from globeview.ui.file_opening import source_name

    assert source_name("https://example.org/data/globe%20store") == "globe store"
    assert source_name("https://example.org/data/store/") == "store"
    assert source_name("https://example.org") == "example.org"
    assert source_name("/tmp/x/hill.tif") == "hill"
    assert source_name("/tmp/x/hill.tif", stem=False) == "hill.tif"
