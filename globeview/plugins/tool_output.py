"""Tool output: data a tool publishes for the host to show beside the globe (a plot).

A tool publishes a plot by defining a method ``plot(self) -> Plot | None`` (optional; the
base `Tool` has none). The window asks the active tool for it after every frame and shows
the plot in its Plot dock (`globeview.ui.plot_dock`), with an "Export CSV..." button; a
headless caller reads ``tool.plot()`` itself. Returning the *same* `Plot` object again means
"unchanged" (the dock redraws only for a new object); None hides the dock's content.

A `Plot` is data only: one curve (``x``, ``y``, 1-D float arrays of equal length; NaN in
``y`` leaves a gap) with a title and axis labels, plus the table its CSV export writes
(``columns``: name -> 1-D array, all of the curve's length; default the curve itself). The
host draws it with QPainter; nothing here imports Qt. `Plot.write_csv` writes atomically
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

__all__ = ["Plot", "read_csv_columns"]

#: Most points a plot may hold (a guard against a runaway tool; the dock draws them all).
MAX_PLOT_POINTS = 1_000_000


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


@dataclass(frozen=True, eq=False)
class Plot:
    """One curve a tool publishes, and the table its CSV export writes.

    Attributes:
        title: one line shown above the plot.
        x, y: the curve, 1-D arrays of equal length (>= 1); ``x`` finite, ``y`` may hold NaN
            (a gap: e.g. no terrain there). Units are the tool's, named in the labels.
        x_label, y_label: axis titles with units (e.g. "distance (km)", "height (m)").
        columns: the CSV table, name -> 1-D array of the curve's length, in column order;
            empty means ``{x_label: x, y_label: y}``. Column names must be distinct and
            non-empty; CSV values are written with full float64 precision.

    Raises ValueError on construction for malformed data (the host then fails the tool's
    plugin with that one line, as for any bad value a plugin returns).
    """

    title: str
    x: np.ndarray
    y: np.ndarray
    x_label: str = "x"
    y_label: str = "y"
    columns: Mapping[str, np.ndarray] = field(default_factory=dict)

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
        object.__setattr__(self, "title", " ".join(str(self.title).split()))
        object.__setattr__(self, "x_label", " ".join(str(self.x_label).split()))
        object.__setattr__(self, "y_label", " ".join(str(self.y_label).split()))
        object.__setattr__(self, "columns", cols)

    def table(self) -> dict[str, np.ndarray]:
        """The CSV columns in order (``columns``, or the curve under its axis labels)."""
        if self.columns:
            return dict(self.columns)
        if self.x_label == self.y_label:
            return {self.x_label or "x": self.x, (self.y_label or "y") + " (y)": self.y}
        return {self.x_label or "x": self.x, self.y_label or "y": self.y}

    def csv_text(self) -> str:
        """The table as CSV text: a header row, then one row per point; floats in their
        shortest exact form (``repr``), NaN as an empty field."""
        cols = self.table()
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(list(cols))
        for row in zip(*cols.values(), strict=True):
            w.writerow(["" if math.isnan(v) else repr(float(v)) for v in row])
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
