"""The Plot dock draws every curve of a `Plot` (plugin API 1.2, issue #29 item 11): a
terrain profile and a sight line together, each in its own colour, with a legend naming
them; a series with its own x is drawn over its own span only; the export writes every
series. The single-curve plot keeps its one colour and no legend."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from globeview.plugins.api import Plot, PlotSeries, read_csv_columns

pytestmark = pytest.mark.gui


def _rgb(widget) -> np.ndarray:
    img = widget.grab().toImage()
    ptr = img.constBits()
    ptr.setsize(img.sizeInBytes())
    arr = np.frombuffer(ptr, np.uint8).reshape(img.height(), img.bytesPerLine())
    bgra = arr[:, : img.width() * 4].reshape(img.height(), img.width(), 4)
    return bgra[..., [2, 1, 0]].astype(int)


def _mask(rgb: np.ndarray, colour) -> np.ndarray:
    return np.abs(rgb - np.array(colour)).max(axis=2) < 40


@pytest.fixture
def dock(qtbot):
    from globeview.ui.plot_dock import PlotDock

    d = PlotDock()
    qtbot.addWidget(d)
    d.resize(640, 360)
    d.show()
    qtbot.waitExposed(d)
    return d


def test_every_curve_in_its_own_colour_with_a_legend(dock, tmp_path: Path) -> None:
    from globeview.ui.plot_dock import CURVE_COLOURS

    s = np.linspace(0.0, 10.0, 200)
    plot = Plot(
        "profile and sight line",
        s,
        500.0 + 300.0 * np.sin(s),
        "distance (km)",
        "terrain (m)",
        series=(
            PlotSeries("sight line (m)", np.linspace(900.0, 100.0, 200)),
            PlotSeries("summit (m)", np.array([800.0, 800.0]), x=np.array([1.0, 2.0])),
        ),
    )
    dock.set_plot(plot)
    assert dock.view.legend() == ["terrain (m)", "sight line (m)", "summit (m)"]
    rgb = _rgb(dock.view)
    first, second, third = (_mask(rgb, CURVE_COLOURS[i]) for i in range(3))
    assert first.sum() > 200 and second.sum() > 200 and third.sum() > 20
    # The short series lies over x in 1..2 only: its pixels (beyond its legend swatch) are
    # in that span of the frame.
    f = dock.view.frame_rect()
    x1, _ = dock.view.data_to_px(np.array([1.0, 2.0]), np.array([800.0, 800.0]))
    cols = np.flatnonzero(third[int(f.bottom()) - 40 : int(f.bottom())].any(axis=0))
    assert cols.size == 0 or (cols.min() >= x1[0] - 3 and cols.max() <= x1[1] + 3)
    # Export: every series.
    assert dock.export_csv(str(tmp_path / "p.csv"))
    cols_back = read_csv_columns(tmp_path / "p.csv")
    assert list(cols_back) == [
        "distance (km)",
        "terrain (m)",
        "sight line (m)",
        "summit (m) x",
        "summit (m)",
    ]


def test_single_curve_has_no_legend(dock) -> None:
    from globeview.ui.plot_dock import CURVE_COLOURS, CURVE_RGB

    assert CURVE_COLOURS[0] == CURVE_RGB
    dock.set_plot(Plot("one", [0.0, 1.0, 2.0], [1.0, 3.0, 2.0], "x (m)", "h (m)"))
    assert dock.view.legend() == []
    rgb = _rgb(dock.view)
    assert _mask(rgb, CURVE_RGB).sum() > 100
    assert not _mask(rgb, CURVE_COLOURS[1]).any()
