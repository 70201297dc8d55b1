"""The ingest's per-chunk passes on the box of a window that holds data (issue #25 item 6):
tile statistics, error windows, the wavelet and the geoid's undulation skip the all-NaN part
of a chunk window, and a build gives the same store, file for file, as one that runs every
pass on whole windows.

Real sources: the Vancouver topobathy grid (regional, 2') over ETOPO 20' (global), so the
finest chunks meet the regional DEM's edges, the coarse ones hold a small island of data,
and the error windows of the global grid's finest level have blocks judged against the
regional one's (ownership masks). Two builds, ~3 CPU-s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from globeview.terrain.ingest import stored_ranges, tasks, tile_errors, wavelet
from globeview.terrain.ingest.driver import ingest

DATA = Path(__file__).resolve().parents[2] / "data"
SOURCES = [DATA / "etopo20.tif", DATA / "topobathy_vancouver.tif"]


def _files(store: Path) -> dict[str, bytes]:
    return {
        p.relative_to(store).as_posix(): p.read_bytes()
        for p in sorted(store.rglob("*"))
        if p.is_file()
    }


def _whole(arr: np.ndarray, b: int) -> tuple[slice, slice] | None:
    """The box of every block of a window (None without a finite node, as data_blocks)."""
    if not np.isfinite(arr).any():
        return None
    return slice(0, max(1, -(-(arr.shape[0] - 1) // b))), slice(
        0, max(1, -(-(arr.shape[1] - 1) // b))
    )


def test_boxed_passes_give_the_whole_window_store(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    boxes: list[tuple[int, int]] = []  # (nodes in the box, in the window)
    error_box = tasks._error_box

    def spy(fine: np.ndarray, block: int, owned: np.ndarray | None):  # type: ignore[no-untyped-def]
        box = error_box(fine, block, owned)
        if box is not None:
            side = [(b.stop - b.start) * block + 1 for b in box]
            boxes.append((side[0] * side[1], fine.size))
        return box

    monkeypatch.setattr(tasks, "_error_box", spy)
    geoid_boxes: list[tuple[int, int]] = []
    finite_box = tasks._finite_box

    def geoid_spy(*parts: np.ndarray):  # type: ignore[no-untyped-def]
        box = finite_box(*parts)
        if box is not None:
            geoid_boxes.append(
                ((box[0].stop - box[0].start) * (box[1].stop - box[1].start), parts[0].size)
            )
        return box

    monkeypatch.setattr(tasks, "_finite_box", geoid_spy)
    ingest(SOURCES, tmp_path / "boxed", workers=1)
    # Some error windows and undulations did run on a part of their window.
    assert any(part < whole for part, whole in boxes)
    assert any(part < whole for part, whole in geoid_boxes)
    with monkeypatch.context() as mp:
        mp.setattr(tasks, "_error_box", lambda fine, block, owned: _whole(fine, block))
        for module in (tile_errors, stored_ranges):
            mp.setattr(module, "data_blocks", _whole)
        mp.setattr(wavelet, "_valid_box", lambda c: ((0, c.shape[0]), (0, c.shape[1])))
        mp.setattr(
            tasks, "_finite_box", lambda *p: (slice(0, p[0].shape[0]), slice(0, p[0].shape[1]))
        )
        ingest(SOURCES, tmp_path / "whole", workers=1)
    boxed, whole = _files(tmp_path / "boxed"), _files(tmp_path / "whole")
    assert boxed.keys() == whole.keys()
    assert [k for k in boxed if boxed[k] != whole[k]] == []
    assert any(k.startswith("facts/") for k in boxed)
