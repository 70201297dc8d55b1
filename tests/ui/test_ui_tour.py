"""The Tour dock (issue #26 item 5): record the current view as keyframes, edit their seconds,
play the tour in the window, save and open it, export it as a movie with the progress dialog
(ETA) and cancel it from the dialog. A real window under Xvfb, as the other window tests."""

from __future__ import annotations

import imageio_ffmpeg
import pytest

from globeview.model.camera import Camera
from globeview.model.tour import Tour

pytestmark = pytest.mark.gui

A = (-71.6, 44.0, 400_000.0, 0.0, -90.0)
B = (-71.3, 44.3, 150_000.0, 30.0, -50.0)


def frame_count(path) -> tuple[tuple[int, int], int]:
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    return tuple(meta["size"]), sum(1 for _ in reader)


@pytest.fixture
def recorded(reused_window):
    """(window, panel) with two keyframes recorded: A, then B reached in 1 s."""
    win = reused_window
    panel = win.tour_panel
    win.model.camera = Camera.from_lonlat(*A)
    panel.add_view()
    panel.seconds.setValue(1.0)
    win.model.camera = Camera.from_lonlat(*B)
    panel.add_view()
    return win, panel


def test_record_and_edit_seconds(recorded, errors_shown) -> None:
    win, panel = recorded
    assert panel.table.rowCount() == 2
    assert [k.seconds for k in panel.tour.keyframes] == [0.0, 1.0]
    assert panel.tour.keyframes[1].pose[:3] == pytest.approx(B[:3])
    panel.table.item(1, 5).setText("-2")  # refused in one dialog, put back
    assert len(errors_shown) == 1 and "seconds" in errors_shown[0].text
    assert panel.table.item(1, 5).text() == "1" and panel.tour.keyframes[1].seconds == 1.0
    panel.table.item(1, 5).setText("soon")
    assert len(errors_shown) == 2 and "seconds must be a number" in errors_shown[1].text
    panel.table.item(1, 5).setText("0.5")
    assert panel.tour.keyframes[1].seconds == 0.5
    assert "Export &Movie…" in [a.text() for a in win.menuBar().actions()[0].menu().actions()]


def test_play_flies_the_tour_in_the_window(recorded, qtbot) -> None:
    win, panel = recorded
    win.model.camera = Camera.from_lonlat(0.0, 0.0, 2.0e7)
    frames = win.globe.frames
    with qtbot.waitSignal(panel.played, timeout=10000):
        panel.play()
    assert not panel.playing
    lon, lat, h, heading, pitch, _ = win.model.camera.lonlat_hpr()
    assert (lon, lat, h, heading, pitch) == pytest.approx(B, abs=1e-6)
    assert win.globe.frames > frames + 2  # drawn on the way


def test_save_and_open(recorded, tmp_path, errors_shown) -> None:
    _, panel = recorded
    tour = panel.tour
    assert panel.save_tour(str(tmp_path / "t.toml"))
    panel.tour = Tour()
    assert panel.open_tour(str(tmp_path / "t.toml"))
    assert panel.tour == tour and panel.table.rowCount() == 2
    (tmp_path / "bad.json").write_text("{}")
    assert not panel.open_tour(str(tmp_path / "bad.json"))
    assert len(errors_shown) == 1 and "not a globeview tour" in errors_shown[0].text
    assert panel.tour == tour


def test_export_with_progress_then_cancel(recorded, tmp_path, errors_shown) -> None:
    win, panel = recorded
    camera = win.model.camera
    labels: list[str] = []

    def seen(done: int, total: int) -> None:
        assert panel.progress_dialog is not None
        labels.append(panel.progress_dialog.labelText())

    panel.exportProgress.connect(seen)
    out = tmp_path / "t.mp4"
    assert panel.export_movie(str(out), (64, 48), 8.0)
    assert frame_count(out) == ((64, 48), 8)  # 1 s at 8 fps
    assert labels[0] == "Rendering frame 1 of 8…"
    assert labels[3].startswith("Frame 3 of 8, about ") and labels[3].endswith(" left")
    assert win.model.camera is camera  # put back
    panel.exportProgress.disconnect(seen)

    def cancel(done: int, total: int) -> None:
        if done == 2 and panel.progress_dialog is not None:
            panel.progress_dialog.cancel()  # the user's click on Cancel

    panel.exportProgress.connect(cancel)
    assert not panel.export_movie(str(tmp_path / "c.gif"), (64, 48), 8.0)
    # (cache/ is the window fixture's GLOBEVIEW_CACHE_DIR: the saved blend tables live there)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "cache") == ["t.mp4"]
    assert errors_shown == []  # a cancel is not an error
    assert "cancelled" in win.statusBar().currentMessage()


def test_export_to_a_missing_folder_is_one_dialog(recorded, tmp_path, errors_shown) -> None:
    win, panel = recorded
    assert not panel.export_movie(str(tmp_path / "no" / "t.mp4"), (64, 48), 8.0)
    assert len(errors_shown) == 1 and "does not exist" in errors_shown[0].text
    assert "\n" not in errors_shown[0].text
    assert panel.progress_dialog is None and list(tmp_path.glob("**/*.mp4")) == []
    assert win.isVisible()  # the window keeps running
