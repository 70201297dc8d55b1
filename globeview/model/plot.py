"""A tool's plot: data a tool publishes for the host to show beside the globe.

A tool publishes a plot from ``Tool.plot(self) -> Plot | None`` (the base returns None).
The tool host asks the active tool for it (`globeview.app.tool_host.ToolHost.plot`, checked
and isolated) after every frame; the window shows it in its Plot dock
(`globeview.ui.plot_dock`), with an "Export CSV..." button, ``render --tool-csv`` writes its
table, a script reads ``session.tool_plot()``. Returning the *same* `Plot` object again means
"unchanged" (the dock redraws only for a new object); None hides the dock's content.

A `Plot` is data only: a curve (``x``, ``y``, 1-D float arrays of equal length; NaN in
``y`` leaves a gap) with a title and axis labels, optional further curves (``series``:
`PlotSeries`, API 1.2, e.g. a sight line over a terrain profile; each on the plot's ``x`` or
its own), plus the table its CSV export writes (``columns``: name -> 1-D array, all of the
curve's length, default the curve itself; then every series' columns). The host draws it
with QPainter; nothing here imports Qt. `Plot.write_csv` writes atomically
(`globeview.fileio`): a failed export leaves no partial file and raises a one-line
`globeview.fileio.OutputError`.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from globeview.errors import GlobeviewError
from globeview.fileio import atomic_write_text

__all__ = ["Plot", "PlotSeries", "read_csv_columns"]

#: Most points a plot may hold, all its curves together (a guard against a runaway tool;
#: the dock draws them all).
MAX_PLOT_POINTS = 1_000_000
#: Most curves `Plot.series` may add (the dock's legend lists each).
MAX_PLOT_SERIES = 16


def _vector(name: str, values: object) -> np.ndarray:
    """``values`` as a 1-D float64 array (a copy, read-only), or ValueError naming ``name``."""
    try:
        arr = np.array(values, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"plot {name}: not an array of numbers ({exc})") from None
    if arr.ndim != 1:
        raise ValueError(f"plot {name}: expected a 1-D array, got shape {arr.shape}")
    arr.setflags(write=False)
    return arr


def _name(text: object) -> str:
    """A label or column name as one line (runs of whitespace made one space)."""
    return " ".join(str(text).split())


@dataclass(frozen=True, eq=False)
class PlotSeries:
    """One more curve of a `Plot` (plugin API 1.2), e.g. the sight line over a terrain
    profile, in the plot's units.

    Attributes:
        label: its name in the dock's legend and its CSV column (distinct from the plot's
            other columns and series).
        y: 1-D values; NaN leaves a gap.
        x: 1-D finite values of ``y``'s length; None (the default): the plot's ``x``, and
            ``y`` then has its length.

    Checked when the `Plot` holding it is made (ValueError naming the series)."""

    label: str
    y: np.ndarray
    x: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Plot:
    """The curves a tool publishes, and the table its CSV export writes.

    Attributes:
        title: one line shown above the plot.
        x, y: the curve, 1-D arrays of equal length (>= 1); ``x`` finite, ``y`` may hold NaN
            (a gap: e.g. no terrain there). Units are the tool's, named in the labels.
        x_label, y_label: axis titles with units (e.g. "distance (km)", "height (m)"); the
            y label names the first curve in the legend.
        columns: the CSV table, name -> 1-D array of the curve's length, in column order;
            empty means ``{x_label: x, y_label: y}``. Column names must be distinct and
            non-empty; CSV values are written with full float64 precision.
        series: further curves (`PlotSeries`, at most `MAX_PLOT_SERIES`; API 1.2), drawn
            over the first in the dock's colours with a legend. Each adds its ``label``
            column to the CSV after ``columns`` (one with its own x also ``"<label> x"``
            before it); shorter columns are padded with empty fields.

    Raises ValueError on construction for malformed data (the host then fails the tool's
    plugin with that one line, as for any bad value a plugin returns).
    """

    title: str
    x: np.ndarray
    y: np.ndarray
    x_label: str = "x"
    y_label: str = "y"
    columns: Mapping[str, np.ndarray] = field(default_factory=dict)
    series: tuple[PlotSeries, ...] = ()

    def __post_init__(self) -> None:
        x, y = _vector("x", self.x), _vector("y", self.y)
        if x.size != y.size or x.size == 0:
            raise ValueError(f"plot x and y need equal non-zero lengths, got {x.size}, {y.size}")
        if x.size > MAX_PLOT_POINTS:
            raise ValueError(f"plot has {x.size} points; at most {MAX_PLOT_POINTS}")
        if not np.isfinite(x).all():
            raise ValueError("plot x values must be finite")
        cols = {}
        for name, values in dict(self.columns).items():
            name = " ".join(str(name).split())
            if not name or name in cols:
                raise ValueError(f"plot column {name!r}: empty or repeated name")
            col = _vector(f"column {name!r}", values)
            if col.size != x.size:
                raise ValueError(f"plot column {name!r} has {col.size} values, x has {x.size}")
            cols[name] = col
        object.__setattr__(self, "x", x)
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "title", _name(self.title))
        object.__setattr__(self, "x_label", _name(self.x_label))
        object.__setattr__(self, "y_label", _name(self.y_label))
        object.__setattr__(self, "columns", cols)
        object.__setattr__(self, "series", self._checked_series())

    def _checked_series(self) -> tuple[PlotSeries, ...]:
        """``series`` checked (type, lengths, finite x, distinct names against the columns
        before them), as copies holding read-only float64 arrays."""
        raw = tuple(self.series or ())
        if len(raw) > MAX_PLOT_SERIES:
            raise ValueError(f"plot has {len(raw)} series; at most {MAX_PLOT_SERIES}")
        names = set(self._own_table())
        total = self.x.size
        out = []
        for i, s in enumerate(raw):
            if not isinstance(s, PlotSeries):
                raise ValueError(f"plot series {i}: {type(s).__name__}, not a PlotSeries")
            label = _name(s.label)
            y = _vector(f"series {label!r} y", s.y)
            x = None if s.x is None else _vector(f"series {label!r} x", s.x)
            if x is None and y.size != self.x.size:
                raise ValueError(f"plot series {label!r} has {y.size} values, x has {self.x.size}")
            if x is not None and (x.size != y.size or x.size == 0):
                raise ValueError(
                    f"plot series {label!r} x and y need equal non-zero lengths, "
                    f"got {x.size}, {y.size}"
                )
            if x is not None and not np.isfinite(x).all():
                raise ValueError(f"plot series {label!r} x values must be finite")
            own = [label] if x is None else [f"{label} x", label]
            if not label or any(n in names for n in own):
                raise ValueError(f"plot series {label!r}: empty or repeated name")
            names.update(own)
            total += y.size
            out.append(PlotSeries(label, y, x))
        if total > MAX_PLOT_POINTS:
            raise ValueError(f"plot has {total} points; at most {MAX_PLOT_POINTS}")
        return tuple(out)

    def curves(self) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """Every curve as (label, x, y): the plot's own (labelled ``y_label``), then each
        series (on the plot's x unless it has its own)."""
        first = [(self.y_label, self.x, self.y)]
        return first + [(s.label, self.x if s.x is None else s.x, s.y) for s in self.series]

    def _own_table(self) -> dict[str, np.ndarray]:
        """The CSV columns of the plot's own curve (``columns``, or the curve under its
        axis labels), without the series."""
        if self.columns:
            return dict(self.columns)
        if self.x_label == self.y_label:
            return {self.x_label or "x": self.x, (self.y_label or "y") + " (y)": self.y}
        return {self.x_label or "x": self.x, self.y_label or "y": self.y}

    def table(self) -> dict[str, np.ndarray]:
        """The CSV columns in order: ``columns`` (or the curve under its axis labels), then
        each series' (``"<label> x"`` for one with its own x, then ``label``). Columns may
        differ in length when a series has its own x (`csv_text` pads them)."""
        cols = self._own_table()
        for s in self.series:
            if s.x is not None:
                cols[f"{s.label} x"] = s.x
            cols[s.label] = s.y
        return cols

    def csv_text(self) -> str:
        """The table as CSV text: a header row, then one row per point of the longest
        column; floats in their shortest exact form (``repr``), NaN and the padding of
        shorter columns as empty fields."""
        cols = self.table()
        values = [c.tolist() for c in cols.values()]  # Python floats: repr is the shortest
        n = max(len(v) for v in values)
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(list(cols))
        for i in range(n):
            w.writerow(["" if i >= len(v) or math.isnan(v[i]) else repr(v[i]) for v in values])
        return buf.getvalue()

    def write_csv(self, path: str | os.PathLike) -> Path:
        """Write the table to ``path`` atomically; returns the path. Raises a one-line
        `globeview.fileio.OutputError` (a `GlobeviewError`) when it cannot be written; the
        target is then unchanged (an existing file kept, no partial file)."""
        return atomic_write_text(path, self.csv_text())


def read_csv_columns(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a CSV written by `Plot.write_csv` back: name -> float64 array (empty field: NaN).
    Raises a one-line `GlobeviewError` for a file that is missing or not such a table."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        msg = getattr(exc, "strerror", None) or exc
        raise GlobeviewError(f"cannot read {path}: {msg}") from None
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        raise GlobeviewError(f"{path}: empty CSV file")
    header, body = rows[0], rows[1:]
    try:
        data = np.array(
            [[float(v) if v != "" else math.nan for v in r] for r in body], dtype=np.float64
        ).reshape(len(body), len(header))
    except ValueError:
        raise GlobeviewError(f"{path}: not a numeric CSV table with a header row") from None
    return {name: data[:, i].copy() for i, name in enumerate(header)}
