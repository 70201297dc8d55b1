"""File > Save Project… / Open Project… and the Bookmarks menu in a real window under Xvfb
(issue #26 item 4): a saved project reopens the layers, their visibility and style, the
camera and the bookmarks; a bookmark's menu entry moves the camera; a bad project is one
dialog and the window keeps its globe; missing layers are one dialog while the rest opens;
a save that cannot be written is one dialog and leaves no file."""

from __future__ import annotations

import tomllib

import pytest

pytestmark = pytest.mark.gui


@pytest.fixture
def window(make_window, embedded, monkeypatch):
    """A window on the embedded data, with the cache the embedded stores are in (so a
    project naming them opens them without ingesting them again)."""
    win = make_window(embedded_overlays=True)
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(embedded[0].path.parent.parent))
    return win


def _pose(win):
    return win.model.camera.lonlat_hpr()


def _menu_names(win) -> list[str]:
    return [a.text() for a in win.projects.bookmarks_menu.actions() if a.text()]


def test_save_and_open_project_restore_layers_view_and_bookmarks(
    window, tmp_path, errors_shown, qtbot
):
    win = window
    from globeview.model.camera import Camera

    win.model.camera = Camera.from_lonlat(-71.3, 44.27, 30000.0, 20.0, -50.0)
    assert win.projects.add_bookmark("washington")
    assert _menu_names(win) == ["&Add Bookmark…", "washington"]
    borders = win.model.overlays[-1]
    borders.set_style(width_px=4.0)
    dems = [ly.name for ly in win.model.terrain.layers]
    path = tmp_path / "proj" / "p.toml"
    path.parent.mkdir()
    assert win.projects.save(path)
    assert errors_shown == []
    assert win.windowTitle() == "p.toml — globeview"
    doc = tomllib.loads(path.read_text())
    assert [d["name"] for d in doc["dems"]] == dems
    assert all("embedded" in d for d in doc["dems"])
    assert doc["bookmarks"][0]["name"] == "washington"

    # Change everything the project holds, then open it again.
    win.model.camera = Camera.from_lonlat(10.0, 46.0, 2.0e6)
    borders.set_visible(False)
    win.model.bookmarks.remove("washington")
    win.model.terrain.set_visible(dems[-1], False)
    frames = win.globe.frames
    assert win.projects.open(path)
    assert errors_shown == []
    assert _pose(win)[:5] == pytest.approx((-71.3, 44.27, 30000.0, 20.0, -50.0), abs=1e-6)
    assert [ly.name for ly in win.model.terrain.layers] == dems
    assert all(ly.visible for ly in win.model.terrain.layers)
    reopened = win.model.overlays[-1]
    assert reopened.visible and reopened.width_px == 4.0
    assert _menu_names(win) == ["&Add Bookmark…", "washington"]
    qtbot.waitUntil(lambda: win.globe.frames > frames, timeout=20000)

    # The bookmark's menu entry moves the camera there.
    win.model.camera = Camera.from_lonlat(0.0, 0.0, 2.0e7)
    next(a for a in win.projects.bookmarks_menu.actions() if a.text() == "washington").trigger()
    assert _pose(win)[:2] == pytest.approx((-71.3, 44.27), abs=1e-6)


def test_a_bad_project_is_one_dialog_and_nothing_changes(window, tmp_path, errors_shown):
    win = window
    before = _pose(win)
    layers = [ly.name for ly in win.model.terrain.layers]
    for text in ("schema = 2\n", "garbage {", "schema = 1\n[camera]\nlon = nan\n"):
        errors_shown.clear()
        path = tmp_path / "bad.toml"
        path.write_text(text)
        assert not win.projects.open(path)
        assert len(errors_shown) == 1, errors_shown
        assert "\n" not in errors_shown[0].text
    assert _pose(win) == before
    assert [ly.name for ly in win.model.terrain.layers] == layers


def test_missing_layers_are_one_dialog_and_the_rest_opens(window, tmp_path, errors_shown):
    win = window
    path = tmp_path / "p.toml"
    path.write_text(
        "schema = 1\n[camera]\nlon = -71.3\nlat = 44.27\nheight = 40000.0\n"
        '[[dems]]\nname = "etopo20"\nembedded = "etopo20.tif"\n'
        '[[dems]]\nname = "gone"\npath = "gone.tif"\n'
        '[[overlays]]\nname = "abs"\npath = "/etc/hostname"\n'
    )
    assert win.projects.open(path)
    assert [ly.name for ly in win.model.terrain.layers] == ["etopo20"]
    assert win.model.overlays == []
    assert len(errors_shown) == 1
    text = errors_shown[0].text
    assert "2 layer(s) of p.toml not opened" in text
    assert "DEM layer 'gone'" in text and "overlay 'abs'" in text and "absolute path" in text


def test_a_save_that_cannot_be_written_is_one_dialog_and_no_file(
    window, tmp_path, errors_shown, monkeypatch
):
    monkeypatch.setenv("GLOBEVIEW_FAULT_WRITE", "enospc")
    assert not window.projects.save(tmp_path / "p.toml")
    assert len(errors_shown) == 1
    assert list(tmp_path.glob("p.toml*")) == [] and list(tmp_path.glob(".p.toml*")) == []


def test_the_window_keeps_running_while_a_projects_dem_is_ingested(
    make_window, tmp_path, errors_shown, qtbot
):
    """The DEM (data/N44W072.hgt, not in this test's fresh cache) is ingested on a worker
    thread: a 10 ms timer on the UI thread keeps firing meanwhile, and the layer arrives."""
    import shutil

    from PyQt6.QtCore import QTimer

    from globeview.terrain.dem.data import EMBEDDED_DATA_DIR

    win = make_window()
    shutil.copy(EMBEDDED_DATA_DIR / "N44W072.hgt", tmp_path / "N44W072.hgt")
    path = tmp_path / "p.toml"
    path.write_text(
        "schema = 1\n[camera]\nlon = -71.3\nlat = 44.27\nheight = 40000.0\n"
        '[[dems]]\nname = "wm"\npath = "N44W072.hgt"\n'
    )
    ticks = []
    timer = QTimer()
    timer.setInterval(10)
    timer.timeout.connect(lambda: ticks.append(1))
    timer.start()
    try:
        assert win.projects.open(path)
    finally:
        timer.stop()
    assert errors_shown == []
    assert [ly.name for ly in win.model.terrain.layers] == ["wm"]
    assert len(ticks) >= 3, "the UI thread waited for the ingest"
    assert win.projects.open_action.isEnabled() and win.projects.save_action.isEnabled()
