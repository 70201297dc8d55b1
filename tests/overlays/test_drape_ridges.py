"""Draped lines over ridges between their vertices (issue #26 review): a straight line with
1 km vertices across Mount Washington's summit ridge stays continuous from above and from an
oblique view (the chord between two draped vertices passes under the ridge; the shader pulls
the segment's depth by the terrain's rise over it), and a line behind the mountain stays
hidden. The reference is the same line densified to 50 m (chords within a metre or so of the
mesh), drawn with the same renderer."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_overlay_render import SIZE, draw, opened
from test_overlay_render import clean as clean
from test_overlay_render import session as session

from globeview.model.camera import Camera

MAGENTA = (1.0, 0.0, 1.0, 1.0)
#: Mount Washington's summit (lon, lat degrees).
SUMMIT = (-71.3033, 44.2706)


def line_file(tmp_path, coords: list[tuple[float, float]]) -> str:
    path = tmp_path / "line.geojson"
    geom = {"type": "LineString", "coordinates": [list(c) for c in coords]}
    doc = {"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": geom}]}
    path.write_text(json.dumps(doc))
    return str(path)


def line_mask(session, path: str, densify_m: float, cam: Camera) -> np.ndarray:
    """(H, W) bool: the magenta line's pixels with only that line shown."""
    from globeview.plugins.builtin.layers.types import VectorLayerType

    layer = opened(VectorLayerType().open(path, densify_m=densify_m, color=MAGENTA, width_px=3.0))
    session.globe.add_overlay(layer)
    try:
        rgb, result = draw(session, cam)
        assert result.stats.extra["vector_segments"] > 0
    finally:
        session.remove_overlay(layer)
    return (rgb[..., 0] > 230) & (rgb[..., 1] < 30) & (rgb[..., 2] > 230)


def columns_or_rows(mask: np.ndarray) -> np.ndarray:
    """Per screen column (or row, whichever the line spans more of): whether it has a pixel."""
    cols, rows = mask.any(axis=0), mask.any(axis=1)
    return cols if cols.sum() >= rows.sum() else rows


def screen_path(cam: Camera, lon: np.ndarray, lat: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(N, 2) integer (column, row) pixels of points (degrees, metres) seen by ``cam``."""
    from globeview.geodesy import lonlat_to_ecef

    rel = (lonlat_to_ecef(lon, lat, h) - cam.eye) @ cam.rotation.T  # right, up, back
    t = np.tan(np.radians(cam.fovy_deg) / 2.0)
    w, hh = SIZE
    x = rel[:, 0] / -rel[:, 2] / (t * w / hh)
    y = rel[:, 1] / -rel[:, 2] / t
    return np.stack([(x + 1.0) / 2.0 * w, (1.0 - y) / 2.0 * hh], axis=1).astype(int)


CROSSING = [(SUMMIT[0] - 0.045, SUMMIT[1] + 0.004), (SUMMIT[0] + 0.045, SUMMIT[1] - 0.004)]


@pytest.mark.slow
@pytest.mark.parametrize(
    "cam",
    [
        Camera.from_lonlat(SUMMIT[0], SUMMIT[1], 9000.0),
        Camera.from_lonlat(SUMMIT[0], SUMMIT[1] - 0.09, 6000.0, 0.0, -40.0),
    ],
    ids=["nadir", "oblique"],
)
def test_line_across_the_summit_ridge_has_no_gaps(clean, tmp_path, cam) -> None:
    path = line_file(tmp_path, CROSSING)
    dense = columns_or_rows(line_mask(clean, path, 50.0, cam))
    coarse = columns_or_rows(line_mask(clean, path, 1000.0, cam))
    assert dense.sum() > 0.25 * max(SIZE), dense.sum()
    missing = dense & ~coarse
    assert missing.sum() <= 2, (int(missing.sum()), int(dense.sum()))


@pytest.mark.slow
def test_line_behind_the_mountain_stays_hidden(clean, tmp_path) -> None:
    """From the west, a north-south line 4 km east of the summit (the Great Gulf and Pinkham
    Notch side) is mostly behind the Presidential Range: where the dense line is hidden, so is
    the 1 km one (no more than a few pixels show through)."""
    lon = SUMMIT[0] + 0.05
    path = line_file(tmp_path, [(lon, SUMMIT[1] - 0.05), (lon, SUMMIT[1] + 0.05)])
    cam = Camera.from_lonlat(SUMMIT[0] - 0.12, SUMMIT[1], 4000.0, 90.0, -14.0)
    dense = line_mask(clean, path, 50.0, cam)
    coarse = line_mask(clean, path, 1000.0, cam)
    grown = dense.copy()
    for dy in (-2, -1, 1, 2):
        grown |= np.roll(dense, dy, axis=0)
    for dx in (-2, -1, 1, 2):
        grown |= np.roll(grown, dx, axis=1)
    # The line is partly behind the massif: of its in-frame path (heights from the DEM),
    # many pixels show no dense line nearby.
    lats = np.linspace(SUMMIT[1] - 0.05, SUMMIT[1] + 0.05, 200)
    lons = np.full_like(lats, lon)
    heights = np.array([clean.terrain.height_at(x, y) for x, y in zip(lons, lats)])
    px = screen_path(cam, lons, lats, heights)
    inside = (px[:, 0] >= 0) & (px[:, 0] < SIZE[0]) & (px[:, 1] >= 0) & (px[:, 1] < SIZE[1])
    seen = grown[px[inside, 1], px[inside, 0]]
    assert inside.sum() > 50 and 0.15 < seen.mean() < 0.7, (int(inside.sum()), seen.mean())
    through = coarse & ~grown
    assert through.sum() <= 10, (int(through.sum()), int(coarse.sum()), int(dense.sum()))


def test_chord_sag_is_the_meshs_rise_over_the_chord() -> None:
    """A 1 000 m ridge along one node column of a tile: a segment across it carries 1 000 m,
    one on flat ground or across a trench 0, one with an undrawn end's samples 0."""
    from globeview.render.overlay_vectors import chord_sag
    from globeview.terrain.vectors import Polylines

    grid = np.zeros((65, 65))
    grid[:, 32] = 1000.0  # lon 11.25 in tile (3, 8, 3): lon 0..22.5, lat 0..22.5
    trench = -grid

    lines = Polylines(
        np.array([5.0, 17.5, 1.0, 4.0]), np.array([10.0, 10.0, 10.0, 10.0]), np.array([0, 2, 4])
    )
    a, b = np.array([0, 2]), np.array([1, 3])
    keys, strides = np.array([[3, 8, 3]]), np.array([1])
    zero = np.zeros(2)
    sag = chord_sag(lambda k: grid, keys, strides, lines, a, b, zero, zero)
    np.testing.assert_allclose(sag, [1000.0, 0.0])
    sag = chord_sag(lambda k: trench, keys, strides, lines, a, b, zero, zero)
    np.testing.assert_allclose(sag, [0.0, 0.0])
    # Ends at 400 and 1 000 m: the chord is at 700 m mid-way, the ridge 300 m above it.
    sag = chord_sag(
        lambda k: grid, keys, strides, lines, a, b, np.array([400.0, 0]), np.array([1000.0, 0])
    )
    np.testing.assert_allclose(sag, [300.0, 0.0])
