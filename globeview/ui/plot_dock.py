"""The Plot dock: shows the plot the active tool publishes (`globeview.plugins.api.Plot`) and
exports its table as CSV.

Generic: any tool, built-in or installed, publishes a plot by defining ``plot()``
(`Tool.plot`, data in `globeview.model.plot`); the window knows no tool. After every frame
and tool change the dock shows what the session's tool host publishes
(`GlobeSession.tool_plot`: the active tool asked in isolation, something that is not a
`Plot` failing the tool with one line, as any bad value a plugin returns does): a new `Plot`
object is drawn and the dock shown; the same object again changes nothing; None (or no
active tool) clears and hides the dock.

Drawing is plain QPainter (no plotting library in the app): axes with "nice" ticks, each
curve (the plot's own and its `PlotSeries`, API 1.2) in its colour of `CURVE_COLOURS` broken
at NaN (gaps), a legend when there is more than one, the title and axis labels. "Export
CSV..." writes the plot's table, every series included, atomically (`Plot.write_csv`,
`globeview.fileio`); a failure is one line in a dialog and no file is written or changed.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from PyQt6.QtCore import QPointF, QRectF, Qt, QTimer
from PyQt6.QtGui import QColor, QFont, QPainter, QPainterPath, QPaintEvent, QPen
from PyQt6.QtWidgets import (
    QDockWidget,
    QFileDialog,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSizePolicy,
    QVBoxLayout,
    QWidget,
)

from globeview.errors import GlobeviewError
from globeview.plugins.api import Plot

log = logging.getLogger("globeview.ui")

#: The curve's colour (also what the window test looks for).
CURVE_RGB = (30, 144, 255)
#: The curves' colours in order: the plot's own, then its series (cycled past the last):
#: distinct hues that stay apart for the common colour-vision deficiencies.
CURVE_COLOURS: tuple[tuple[int, int, int], ...] = (
    CURVE_RGB,
    (230, 97, 1),
    (26, 152, 80),
    (152, 78, 163),
    (200, 30, 60),
    (120, 120, 120),
)
#: Plot margins in pixels: left (tick labels), right, top, bottom (tick labels + axis title).
MARGINS = (64, 14, 10, 42)


def nice_ticks(lo: float, hi: float, target: int = 6) -> np.ndarray:
    """Tick values covering [lo, hi] at a 1-2-5 x 10^k step, about ``target`` of them."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return np.array([lo]) if math.isfinite(lo) else np.array([])
    raw = (hi - lo) / max(target - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1.0, 2.0, 5.0, 10.0) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    return np.arange(first, hi + step * 1e-9, step)


def _tick_text(v: float, step: float) -> str:
    """A tick label with as many decimals as the step needs; scientific beyond 1e9 or
    below 1e-4 steps (fixed notation would print '1,000,000,000,000' or '0.000000')."""
    if step > 0:
        v = round(v / step) * step + 0.0  # no float residue at zero, and no "-0"
    if step > 0 and (step < 1e-4 or max(abs(v), step) >= 1e9):
        return f"{v:.4g}"
    digits = max(0, -math.floor(math.log10(step))) if step > 0 else 0
    return f"{v:,.{digits}f}"


def data_range(values: np.ndarray) -> tuple[float, float] | None:
    """(lo, hi) of the finite values, widened when flat; None when there are none."""
    v = values[np.isfinite(values)]
    if v.size == 0:
        return None
    lo, hi = float(v.min()), float(v.max())
    if hi - lo < 1e-9 * max(1.0, abs(lo)):
        pad = max(abs(lo) * 0.05, 1.0)
        return lo - pad, hi + pad
    return lo, hi


def _decimate(xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A run of pixel positions thinned for drawing: where x increases and there are many
    more points than pixel columns, each column keeps its first, lowest, highest and last
    point (in order), which draws the same pixels; otherwise the run unchanged."""
    if xs.size <= 4 * max(np.ptp(xs), 1.0) or np.any(np.diff(xs) < 0):
        return xs, ys
    col = np.floor(xs).astype(np.int64)
    starts = np.flatnonzero(np.diff(np.concatenate([[col[0] - 1], col])) != 0)
    stops = np.append(starts[1:], xs.size)
    lo = np.minimum.reduceat(ys, starts)
    hi = np.maximum.reduceat(ys, starts)
    keep = [starts, stops - 1]
    for ext in (lo, hi):  # the first index in each column holding the extreme
        hit = np.flatnonzero(ys == np.repeat(ext, stops - starts))
        keep.append(hit[np.unique(np.searchsorted(stops, hit, side="right"), return_index=True)[1]])
    idx = np.unique(np.concatenate(keep))
    return xs[idx], ys[idx]


class PlotView(QWidget):
    """Draws one `Plot`, every curve of it (or a hint when there is none)."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.plot: Plot | None = None
        self.setMinimumSize(320, 180)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)

    def set_plot(self, plot: Plot | None) -> None:
        self.plot = plot
        self.update()

    def frame_rect(self) -> QRectF:
        """The plotting area (inside the axes), widget pixels."""
        left, right, top, bottom = MARGINS
        return QRectF(
            left, top, max(self.width() - left - right, 1), max(self.height() - top - bottom, 1)
        )

    def legend(self) -> list[str]:
        """The legend's entries (the curves' labels), [] for a single curve: its y axis
        title names it."""
        p = self.plot
        if p is None or not p.series:
            return []
        return [label for label, _, _ in p.curves()]

    def ranges(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """((x0, x1), (y0, y1)) the axes span (every curve), or None without a plot or
        finite y."""
        p = self.plot
        if p is None:
            return None
        curves = p.curves()
        xr = data_range(np.concatenate([x for _, x, _ in curves]))
        yr = data_range(np.concatenate([y for _, _, y in curves]))
        if xr is None or yr is None:
            return None
        pad = 0.05 * (yr[1] - yr[0])  # the curve's peaks clear the frame
        return xr, (yr[0] - pad, yr[1] + pad)

    def data_to_px(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Widget pixel positions of data points (valid after `ranges` is not None)."""
        r = self.ranges()
        assert r is not None
        (x0, x1), (y0, y1) = r
        f = self.frame_rect()
        px = f.left() + (np.asarray(x, np.float64) - x0) / (x1 - x0) * f.width()
        py = f.bottom() - (np.asarray(y, np.float64) - y0) / (y1 - y0) * f.height()
        return px, py

    def paintEvent(self, event: QPaintEvent) -> None:
        painter = QPainter(self)
        try:
            painter.setRenderHint(QPainter.RenderHint.Antialiasing)
            painter.fillRect(self.rect(), QColor(255, 255, 255))
            r = self.ranges()
            if r is None:
                painter.setPen(QColor(110, 110, 110))
                text = "No plot: the active tool has published none" if self.plot is None else (
                    "No data to plot (every value is missing)")  # fmt: skip
                painter.drawText(self.rect(), Qt.AlignmentFlag.AlignCenter, text)
                return
            self._draw_axes(painter, *r)
            assert self.plot is not None
            for i, (_, x, y) in enumerate(self.plot.curves()):
                self._draw_curve(painter, x, y, CURVE_COLOURS[i % len(CURVE_COLOURS)])
            self._draw_legend(painter)
        finally:
            painter.end()

    def _draw_axes(
        self, painter: QPainter, xr: tuple[float, float], yr: tuple[float, float]
    ) -> None:
        f = self.frame_rect()
        fm = painter.fontMetrics()
        grid, axis = QPen(QColor(225, 225, 225)), QPen(QColor(60, 60, 60))
        for vals, horizontal in ((nice_ticks(*xr), True), (nice_ticks(*yr), False)):
            step = float(vals[1] - vals[0]) if vals.size > 1 else 1.0
            for v in vals:
                if horizontal:
                    px, _ = self.data_to_px(np.array([v]), np.array([yr[0]]))
                    x = float(px[0])
                    painter.setPen(grid)
                    painter.drawLine(QPointF(x, f.top()), QPointF(x, f.bottom()))
                    painter.setPen(axis)
                    t = _tick_text(float(v), step)
                    painter.drawText(
                        QPointF(x - fm.horizontalAdvance(t) / 2, f.bottom() + fm.ascent() + 3), t
                    )
                else:
                    _, py = self.data_to_px(np.array([xr[0]]), np.array([v]))
                    y = float(py[0])
                    painter.setPen(grid)
                    painter.drawLine(QPointF(f.left(), y), QPointF(f.right(), y))
                    painter.setPen(axis)
                    t = _tick_text(float(v), step)
                    painter.drawText(
                        QPointF(f.left() - fm.horizontalAdvance(t) - 4, y + fm.ascent() / 2 - 1), t
                    )
        painter.setPen(axis)
        painter.drawRect(f)
        p = self.plot
        assert p is not None
        painter.drawText(
            QRectF(f.left(), self.height() - fm.height() - 2, f.width(), fm.height()),
            Qt.AlignmentFlag.AlignHCenter, p.x_label,
        )  # fmt: skip
        painter.save()
        painter.translate(12, f.center().y())
        painter.rotate(-90)
        painter.drawText(QRectF(-f.height() / 2, -fm.ascent(), f.height(), fm.height()),
                         Qt.AlignmentFlag.AlignHCenter, p.y_label)  # fmt: skip
        painter.restore()

    def _draw_legend(self, painter: QPainter) -> None:
        """A box in the frame's top-right corner: a swatch of each curve's colour and its
        label (only with several curves)."""
        labels = self.legend()
        if not labels:
            return
        painter.setClipping(False)
        fm = painter.fontMetrics()
        f = self.frame_rect()
        width = max(fm.horizontalAdvance(t) for t in labels) + 30
        row = fm.height() + 2
        box = QRectF(f.right() - width - 6, f.top() + 6, width, row * len(labels) + 6)
        painter.setPen(QPen(QColor(160, 160, 160)))
        painter.setBrush(QColor(255, 255, 255, 230))
        painter.drawRect(box)
        for i, text in enumerate(labels):
            y = box.top() + 3 + i * row + row / 2
            colour = QColor(*CURVE_COLOURS[i % len(CURVE_COLOURS)])
            painter.setPen(QPen(colour, 3.0))
            painter.drawLine(QPointF(box.left() + 5, y), QPointF(box.left() + 21, y))
            painter.setPen(QColor(40, 40, 40))
            painter.drawText(QPointF(box.left() + 26, y + fm.ascent() / 2 - 1), text)

    def _draw_curve(
        self, painter: QPainter, x: np.ndarray, y: np.ndarray, rgb: tuple[int, int, int]
    ) -> None:
        """One curve as runs of finite values (NaN breaks it); a run that draws no length
        (one point, or all its points on one pixel) is a dot, so no value goes unseen."""
        px, py = self.data_to_px(x, y)
        ok = np.isfinite(py)
        painter.setClipRect(self.frame_rect().adjusted(-4, -4, 4, 4))
        painter.setPen(QPen(QColor(*rgb), 2.0))
        painter.setBrush(QColor(*rgb))
        # Runs of consecutive finite values: [start, stop) index pairs.
        edges = np.diff(np.concatenate([[0], ok.astype(np.int8), [0]]))
        for start, stop in zip(
            np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True
        ):
            xs, ys = px[start:stop], py[start:stop]
            if np.ptp(xs) < 1.0 and np.ptp(ys) < 1.0:
                painter.drawEllipse(QPointF(float(xs[0]), float(ys[0])), 2.5, 2.5)
                continue
            xs, ys = _decimate(xs, ys)
            path = QPainterPath(QPointF(float(xs[0]), float(ys[0])))
            for x, y in zip(xs[1:].tolist(), ys[1:].tolist(), strict=True):
                path.lineTo(x, y)
            painter.setBrush(Qt.BrushStyle.NoBrush)
            painter.drawPath(path)
            painter.setBrush(QColor(*rgb))


class PlotDock(QDockWidget):
    """A dock showing the active tool's plot, with "Export CSV...".

    Args:
        parent: the main window.
        report: called with an exception when an export fails (the window's
            ``ErrorReporter.error``: a one-line dialog).
        notice: called with a one-line text after a successful export (the status bar).
    """

    def __init__(
        self,
        parent: QWidget | None = None,
        report: Callable[[BaseException], Any] | None = None,
        notice: Callable[[str], Any] | None = None,
    ) -> None:
        super().__init__("Plot", parent)
        self.setObjectName("dock-plot")
        self._report = report or (lambda exc: log.warning("%s", exc))
        self._notice = notice or (lambda text: None)
        self.view = PlotView()
        self.title = QLabel()
        self.title.setWordWrap(True)
        bold = QFont(self.title.font())
        bold.setBold(True)
        self.title.setFont(bold)
        self.export_button = QPushButton("Export CSV\N{HORIZONTAL ELLIPSIS}")
        self.export_button.setObjectName("plot-export")
        self.export_button.setToolTip("Write the plotted table to a CSV file")
        self.export_button.clicked.connect(self.export_dialog)
        row = QHBoxLayout()
        row.addWidget(self.title, 1)
        row.addWidget(self.export_button)
        box = QWidget()
        lay = QVBoxLayout(box)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addLayout(row)
        lay.addWidget(self.view, 1)
        self.setWidget(box)
        self.set_plot(None)

    @property
    def plot(self) -> Plot | None:
        return self.view.plot

    def set_plot(self, plot: Plot | None) -> None:
        """Show ``plot`` (None: nothing; the export button is disabled)."""
        self.view.set_plot(plot)
        self.title.setText(plot.title if plot is not None else "")
        self.export_button.setEnabled(plot is not None)

    # -- the host side: the plot the active tool publishes ------------------------------------
    def show_published(self, plot: Plot | None) -> None:
        """Show ``plot``, what the session's tool host publishes now
        (`GlobeSession.tool_plot`, already checked). A new plot shows the dock; the same one
        changes nothing; None clears and hides it."""
        if plot is self.plot:
            return
        self.set_plot(plot)
        if plot is not None:
            self.show()
            self.raise_()
        else:
            self.hide()

    # -- export ------------------------------------------------------------------------------
    def export_dialog(self) -> None:
        """Ask for a file name and export there."""
        if self.plot is None:
            return
        path, _ = QFileDialog.getSaveFileName(
            self, "Export plot as CSV", "profile.csv", "CSV files (*.csv);;All files (*)"
        )
        if path:
            self.export_csv(path)

    def export_csv(self, path: str) -> bool:
        """Write the shown plot's table to ``path`` (atomically); a failure is reported as
        one line and nothing is written. Returns whether the file was written."""
        plot = self.plot
        if plot is None:
            return False
        try:
            plot.write_csv(path)
        except GlobeviewError as exc:
            self._report(exc)
            return False
        except Exception as exc:  # a plugin's Plot subclass whose table raises: its bug
            log.warning("exporting the plot failed", exc_info=True)
            first = (str(exc).splitlines() or [""])[0][:200]
            self._report(GlobeviewError(f"the tool's plot cannot be exported: {first}"))
            return False
        self._notice(f"wrote {path}")
        return True


def install_plot_dock(window: Any) -> PlotDock:
    """Add a (hidden) Plot dock to the main window showing the plot the session publishes
    after every frame and tool change. ``window`` has ``globe`` (the `GlobeWidget`),
    ``model`` (the `Globe`), ``subscriptions`` (its model subscriptions), ``errors``
    (`ErrorReporter`) and ``status`` (`StatusBar`)."""
    dock = PlotDock(window, window.errors.error, window.status.notice)
    window.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, dock)
    dock.hide()
    globe = window.globe
    pending = [False]

    def poll() -> None:
        pending[0] = False
        scene = globe.scene
        dock.show_published(None if scene is None else scene.tool_plot())

    def after_frame(*_: Any) -> None:
        # frameRendered is emitted inside paintGL: showing the dock there would resize the
        # GL widget in the middle of its paint (a crash in the driver). Poll once the event
        # loop is back, at most once per turn of it.
        if not pending[0]:
            pending[0] = True
            QTimer.singleShot(0, poll)

    globe.frameRendered.connect(after_frame)
    # A tool switched anywhere (toolbar, Escape, code, its plugin failing): the model says.
    window.subscriptions.connect(window.model.events.tool, after_frame)
    return dock
