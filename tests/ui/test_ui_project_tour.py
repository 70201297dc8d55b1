"""The Tour dock and projects together (issue #26 items 4 and 5), in a real window under
Xvfb: Save Project writes the dock's tour, Open Project shows the project's tour in the dock
(a tour with a bad keyframe is one dialog line while the rest opens), and the dock's Add
Bookmark menu adds a bookmark's view as a keyframe."""

from __future__ import annotations

import tomllib

import pytest

from globeview.model.camera import Camera
from globeview.model.tour import Tour

pytestmark = pytest.mark.gui

A = (-71.6, 44.0, 400_000.0, 0.0, -90.0)
B = (-71.3, 44.3, 150_000.0, 30.0, -50.0)


def _menu_names(panel) -> list[str]:
    panel.bookmark_menu.aboutToShow.emit()
    return [a.text() for a in panel.bookmark_menu.actions()]


def test_add_bookmark_menu_adds_the_bookmarks_view(make_window, errors_shown) -> None:
    win = make_window()
    panel = win.tour_panel
    assert _menu_names(panel) == ["(no bookmarks: Bookmarks > Add Bookmark…)"]
    win.model.camera = Camera.from_lonlat(*B)
    assert win.projects.add_bookmark("b")
    win.model.camera = Camera.from_lonlat(*A)
    panel.add_view()
    panel.seconds.setValue(2.0)
    assert _menu_names(panel) == ["b"]
    panel.bookmark_menu.actions()[0].trigger()
    assert panel.table.rowCount() == 2
    key = panel.tour.keyframes[1]
    assert key.pose[:5] == pytest.approx(B, abs=1e-6) and key.seconds == 2.0
    assert win.model.camera.lonlat_hpr()[:3] == pytest.approx(A[:3], abs=1e-6)  # not moved
    assert panel.add_bookmark("gone") is None
    assert len(errors_shown) == 1 and "no bookmark named 'gone'" in errors_shown[0].text
    assert len(panel.tour.keyframes) == 2


def test_save_project_keeps_the_tour_and_open_shows_it(make_window, tmp_path, errors_shown) -> None:
    win = make_window()
    panel = win.tour_panel
    win.model.camera = Camera.from_lonlat(*A)
    panel.add_view()
    panel.seconds.setValue(1.5)
    win.model.camera = Camera.from_lonlat(*B)
    panel.add_view()
    panel.tour.name = "over the notches"
    tour = Tour(list(panel.tour.keyframes), panel.tour.name)
    path = tmp_path / "p.toml"
    assert win.projects.save(path)
    assert [t["name"] for t in tomllib.loads(path.read_text())["tours"]] == [tour.name]

    panel.tour = Tour()
    panel.refresh()
    assert panel.table.rowCount() == 0
    assert win.projects.open(path)
    assert errors_shown == []
    assert panel.tour == tour and panel.table.rowCount() == 2
    assert panel.table.item(1, 5).text() == "1.5"

    # A project whose tour has a bad keyframe: one dialog line naming it, the rest opens.
    text = path.read_text().replace("seconds = 1.5", "seconds = -1.0")
    assert "seconds = -1.0" in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    win.model.camera = Camera.from_lonlat(0.0, 0.0, 2.0e7)
    assert win.projects.open(bad)
    assert len(errors_shown) == 1
    line = errors_shown[0].text
    assert "tour 'over the notches': keyframe 2: seconds" in line and "\n" not in line
    assert panel.tour == Tour() and panel.table.rowCount() == 0
    assert win.model.camera.lonlat_hpr()[:2] == pytest.approx(B[:2], abs=1e-6)  # the rest
