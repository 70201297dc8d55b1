"""The Tour dock: record a tour (the current view or a bookmark's as a keyframe, the seconds
to reach it), play it back in the window, open and save it, and export it as a movie with a
progress dialog (ETA, Cancel). An opened project's tour is shown here and Save Project saves
this one (`globeview.ui.project_actions`).

The tour is the Qt-free `globeview.model.tour.Tour`; playback moves the window's camera in
place along `Tour.pose_at` on a timer (the tiles stream in as in any flight). Export films
the window's own model headless through `globeview.Globe.on_model(...).movie` (the same
function as ``globeview movie`` and the API: every frame with all its tiles, the file written
all-or-nothing); the dialog is driven by its ``progress`` callback, whose False cancels."""

from __future__ import annotations

import time
from collections.abc import Callable

from PyQt6.QtCore import Qt, QTimer, pyqtSignal
from PyQt6.QtWidgets import (
    QAbstractItemView,
    QApplication,
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QMenu,
    QProgressDialog,
    QPushButton,
    QSpinBox,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from globeview.app.overlay_host import OverlayHost
from globeview.errors import GlobeviewError
from globeview.model.globe import Globe
from globeview.model.tour import Keyframe, Tour, load_tour, save_tour
from globeview.plugins.registry import PluginRegistry
from globeview.ui.errors import ErrorReporter

#: Playback timer interval (ms).
TICK_MS = 16
#: Movie sizes offered (width, height); "view" is the globe view's own size.
MOVIE_SIZES = ("1280x720", "1920x1080", "640x360", "view")
COLUMNS = ("lon", "lat", "height m", "heading", "pitch", "seconds")


class TourPanel(QWidget):
    """Keyframes in a table (seconds editable), buttons to add the current view, remove,
    play/stop, open, save and export.

    Signals: ``played`` when playback reaches the end; ``exportProgress(done, total)`` after
    each movie frame (tests cancel through it); ``notice(str)`` a one-line status message.
    """

    played = pyqtSignal()
    exportProgress = pyqtSignal(int, int)
    notice = pyqtSignal(str)

    def __init__(
        self,
        model: Globe,
        registry: PluginRegistry,
        overlay_host: OverlayHost,
        errors: ErrorReporter,
        view_size: QWidget | None = None,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self.model, self.registry, self.overlay_host = model, registry, overlay_host
        self.errors = errors
        self._view = view_size
        self.tour = Tour()
        self.progress_dialog: QProgressDialog | None = None
        self._timer = QTimer(self)
        self._timer.setInterval(TICK_MS)
        self._timer.timeout.connect(self._tick)
        self._t0 = 0.0
        self._build()

    # -- widgets -----------------------------------------------------------------------------
    def _build(self) -> None:
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.itemChanged.connect(self._item_changed)
        self.seconds = QDoubleSpinBox()
        self.seconds.setDecimals(1)
        self.seconds.setRange(0.1, 3600.0)
        self.seconds.setValue(4.0)
        self.seconds.setSuffix(" s")
        self.seconds.setToolTip("Seconds the flight to a new keyframe takes")
        self.add_button = self._button(
            "Add View", "The current view as the next keyframe", self.add_view
        )
        self.bookmark_button = QPushButton("Add Bookmark")
        self.bookmark_button.setToolTip("A bookmark's view as the next keyframe")
        self.bookmark_menu = QMenu(self.bookmark_button)
        self.bookmark_menu.aboutToShow.connect(self._fill_bookmarks)
        self.bookmark_button.setMenu(self.bookmark_menu)
        self._fill_bookmarks()
        self.remove_button = self._button(
            "Remove", "Remove the selected keyframes", self.remove_selected
        )
        self.play_button = self._button("Play", "Fly the tour in the window", self.toggle_play)
        self.size_box = QComboBox()
        self.size_box.addItems(MOVIE_SIZES)
        self.fps_box = QSpinBox()
        self.fps_box.setRange(1, 240)
        self.fps_box.setValue(30)
        self.fps_box.setSuffix(" fps")
        rows: list[list[QWidget]] = [
            [QLabel("Reach in"), self.seconds, self.add_button, self.bookmark_button,
             self.remove_button],
            [self.play_button, self._button("Open…", "Open a tour file", self.open_dialog),
             self._button("Save…", "Save the tour as JSON or TOML", self.save_dialog)],
            [self.size_box, self.fps_box,
             self._button("Export Movie…", "Write the tour as MP4 or GIF", self.export_dialog)],
        ]  # fmt: skip
        layout = QVBoxLayout(self)
        layout.addWidget(self.table)
        for row in rows:
            line = QHBoxLayout()
            for w in row:
                line.addWidget(w)
            layout.addLayout(line)

    def _button(self, text: str, tip: str, slot: Callable[[], object]) -> QPushButton:
        b = QPushButton(text)
        b.setToolTip(tip)
        b.clicked.connect(lambda _checked=False: slot())
        return b

    def refresh(self) -> None:
        """Show `tour` again after it was changed in place (an opened project's)."""
        self.stop()
        self._show()

    def _show(self) -> None:
        """The table from `tour` (signals held: this is not the user's edit)."""
        self.table.blockSignals(True)
        self.table.setRowCount(len(self.tour.keyframes))
        for row, k in enumerate(self.tour.keyframes):
            values = (k.lon, k.lat, k.height, k.heading, k.pitch, k.seconds)
            for col, v in enumerate(values):
                item = QTableWidgetItem(f"{v:.6g}" if col != 2 else f"{v:.0f}")
                if col != len(COLUMNS) - 1:
                    item.setFlags(item.flags() & ~Qt.ItemFlag.ItemIsEditable)
                self.table.setItem(row, col, item)
        self.table.blockSignals(False)

    def _item_changed(self, item: QTableWidgetItem) -> None:
        """The user edited a keyframe's seconds: checked, or put back with one line."""
        from globeview.validate import parse_float

        try:
            self.tour.set_seconds(item.row(), parse_float(item.text()))
        except ValueError as exc:
            why = (
                str(exc)
                if "seconds" in str(exc)
                else f"seconds must be a number, not {item.text()!r:.40}"
            )
            self.errors.error(GlobeviewError(f"keyframe {item.row() + 1}: {why}"))
        self._show()

    # -- recording ---------------------------------------------------------------------------
    def add_view(self) -> Keyframe:
        """Append the current camera, reached in the seconds shown (the first: at once)."""
        lon, lat, h, heading, pitch, roll = self.model.camera.lonlat_hpr()
        seconds = self.seconds.value() if self.tour.keyframes else 0.0
        key = self.tour.add(Keyframe(lon, lat, h, heading, pitch, roll, seconds))
        self._show()
        return key

    def add_bookmark(self, name: str) -> Keyframe | None:
        """Append the bookmark ``name``'s view, reached in the seconds shown (the first: at
        once); one dialog line (None) if there is no such bookmark."""
        if name not in self.model.bookmarks:
            self.errors.error(GlobeviewError(f"no bookmark named {name!r:.60}"), "Add Bookmark")
            return None
        seconds = self.seconds.value() if self.tour.keyframes else 0.0
        key = self.tour.add(Keyframe.from_pose(self.model.bookmarks[name].pose, seconds))
        self._show()
        return key

    def _fill_bookmarks(self) -> None:
        """The Add Bookmark menu: one entry per bookmark (filled as it opens)."""
        self.bookmark_menu.clear()
        names = self.model.bookmarks.names
        for name in names:
            action = self.bookmark_menu.addAction(name)
            if action is not None:
                action.triggered.connect(lambda _=False, n=name: self.add_bookmark(n))
        if not names:
            none = self.bookmark_menu.addAction("(no bookmarks: Bookmarks > Add Bookmark…)")
            if none is not None:
                none.setEnabled(False)

    def remove_selected(self) -> None:
        rows = sorted({i.row() for i in self.table.selectedIndexes()}, reverse=True)
        for row in rows:
            del self.tour.keyframes[row]
        if self.tour.keyframes:
            self.tour.set_seconds(0, 0.0)
        self._show()

    # -- playback ----------------------------------------------------------------------------
    @property
    def playing(self) -> bool:
        return self._timer.isActive()

    def toggle_play(self) -> None:
        if self.playing:
            self.stop()
        else:
            self.play()

    def play(self) -> None:
        """Fly the tour from its start in real time (needs two keyframes)."""
        if len(self.tour.keyframes) < 2:
            self.notice.emit("a tour needs two keyframes to play")
            return
        self._t0 = time.perf_counter()
        self.play_button.setText("Stop")
        self._timer.start()
        self._tick()

    def stop(self) -> None:
        self._timer.stop()
        self.play_button.setText("Play")

    def _tick(self) -> None:
        t = time.perf_counter() - self._t0
        self.model.camera.set_lonlat(*self.tour.pose_at(t))
        self.model.camera_moved()
        if t >= self.tour.duration:
            self.stop()
            self.played.emit()

    # -- files ---------------------------------------------------------------------------------
    def open_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open Tour", "", "Tours (*.json *.toml)")
        if path:
            self.open_tour(path)

    def open_tour(self, path: str) -> bool:
        try:
            self.tour = load_tour(path)
        except GlobeviewError as exc:
            self.errors.error(exc)
            return False
        self._show()
        return True

    def save_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(
            self, "Save Tour", "tour.toml", "Tours (*.toml *.json)"
        )
        if path:
            self.save_tour(path)

    def save_tour(self, path: str) -> bool:
        try:
            save_tour(self.tour, path)
        except GlobeviewError as exc:
            self.errors.error(exc)
            return False
        self.notice.emit(f"wrote {path}")
        return True

    # -- export ----------------------------------------------------------------------------------
    def movie_size(self) -> tuple[int, int]:
        """The size chosen (the view's own rounded down to even sides for "view")."""
        text = self.size_box.currentText()
        if text == "view":
            w, h = (self._view.width(), self._view.height()) if self._view else (1280, 720)
            return max(16, w - w % 2), max(16, h - h % 2)
        w, h = (int(v) for v in text.split("x"))
        return w, h

    def export_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(
            self, "Export Movie", "tour.mp4", "Movies (*.mp4 *.gif)"
        )
        if path:
            self.export_movie(path, self.movie_size(), float(self.fps_box.value()))

    def export_movie(self, path: str, size: tuple[int, int], fps: float) -> bool:
        """Film the tour into ``path`` with a modal progress dialog (frames, ETA, Cancel).
        True when written; a cancel leaves nothing and says so; an error is one dialog."""
        from globeview.app.globe import Globe as ApiGlobe

        if not self.tour.keyframes:
            self.errors.error(GlobeviewError("the tour has no keyframes: add a view first"))
            return False
        self.stop()
        dialog = QProgressDialog("Rendering the first frame…", "Cancel", 0, 1, self)
        dialog.setWindowTitle("Export Movie")
        dialog.setWindowModality(Qt.WindowModality.WindowModal)
        dialog.setMinimumDuration(0)
        self.progress_dialog = dialog
        started = time.perf_counter()

        def progress(done: int, total: int) -> bool:
            dialog.setMaximum(total)
            dialog.setValue(done)  # a modal dialog processes events here: Cancel is seen
            dialog.setLabelText(eta_text(done, total, time.perf_counter() - started))
            self.exportProgress.emit(done, total)
            QApplication.processEvents()
            return not dialog.wasCanceled()

        films = ApiGlobe.on_model(self.model, self.registry, self.overlay_host)
        try:
            films.movie(self.tour, path, size=size, fps=fps, progress=progress)
        except Exception as exc:  # noqa: BLE001  one line in a dialog (a bug's traceback: the log), the window keeps working
            cancelled = dialog.wasCanceled()
            dialog.close()
            if cancelled:
                self.notice.emit(f"movie cancelled; nothing written to {path}")
            else:
                self.errors.error(exc, "exporting the movie")
            return False
        finally:
            films.close()
            self.progress_dialog = None
        dialog.close()
        self.notice.emit(f"wrote {path}")
        return True


def eta_text(done: int, total: int, elapsed_s: float) -> str:
    """'Frame 12 of 90, about 1 min 5 s left' (no estimate before the first frame)."""
    if done == 0:
        return f"Rendering frame 1 of {total}…"
    left = elapsed_s / done * (total - done)
    mins, secs = divmod(round(left), 60)
    when = f"{mins} min {secs} s" if mins else f"{secs} s"
    return f"Frame {done} of {total}, about {when} left"
