"""The collapse's bend bound per lattice span, scaled by `lod.candidates.bend_fractions`,
against brute force: how far the straight edges of triangles spanning 1 and 2 lattice spans
(the whole tile's side and diagonal, stride 64 at 65 nodes) stray from the collapsed surface,
on tiles a fold line crosses, including folds through a lattice node (where the midpoint
measure of single spans reads about 0)."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.geodesy import ecef_to_lonlat
from globeview.lod.candidates import bend_fractions
from globeview.lod.culling import LATTICE, tile_bounding_points
from globeview.plugins.builtin.collapse.geometry import CollapseFrame

#: Samples along each straight edge (the kink's worst spot is found within 1/SAMPLES).
SAMPLES = 65


def _stray_m(frame: CollapseFrame, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) the farthest (m) the collapsed straight edges a-b (N, 3) stray from the straight
    edges between their collapsed ends (true ECEF in, sampled at SAMPLES points)."""
    t = np.linspace(0.0, 1.0, SAMPLES)[None, :, None]
    seg = a[:, None] + t * (b - a)[:, None]
    moved = frame.forward(seg.reshape(-1, 3)).reshape(seg.shape)
    da, db = frame.forward(a), frame.forward(b)
    chord = da[:, None] + t * (db - da)[:, None]
    return np.max(np.linalg.norm(moved - chord, axis=2), axis=1)


def _edges(low: np.ndarray, spans: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Straight edges of ``spans`` lattice spans (axis-aligned and diagonal) of lattices
    ``low`` (N, L, L, 3)."""
    s = spans
    out = []
    for i in range(LATTICE - s):
        for j in range(LATTICE - s):
            out += [
                (low[:, i, j], low[:, i + s, j]),
                (low[:, i, j], low[:, i, j + s]),
                (low[:, i, j], low[:, i + s, j + s]),
                (low[:, i + s, j], low[:, i, j + s]),
            ]
    return out


def _fold_tiles(
    frame: CollapseFrame, size: float, where: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Lattices (N, K, 3) of tiles of ``size`` degrees placed so the fold lines cross them at
    fraction ``where`` (N, 2) of their width and height (0.5: through the centre node)."""
    line = np.concatenate([frame.edge_line(sgn * frame.psi0, 0.05, 40) for sgn in (-1.0, 1.0)])
    lon, lat, _ = ecef_to_lonlat(line)
    w, s = lon - size * where[:, 0], lat - size * where[:, 1]
    n = len(w)
    pts, _ = tile_bounding_points(w, s, w + size, s + size, np.zeros(n), np.full(n, 1500.0))
    return pts, lon


def test_bend_fractions_count_the_lattice_spans_of_each_stride() -> None:
    """Stride 64 at 65 nodes spans the whole side: LATTICE - 1 spans, not capped at one."""
    frac = bend_fractions(65)
    np.testing.assert_allclose(frac, 2.0 ** np.arange(len(frac)) * (LATTICE - 1) / 64)
    assert frac[-1] == LATTICE - 1


@pytest.mark.parametrize("ratio", [0.1, 0.5])
@pytest.mark.parametrize("level", [5, 8, 11])
def test_scaled_bound_covers_edges_of_one_and_two_spans(ratio: float, level: int) -> None:
    frame = CollapseFrame.from_lonlat(-123.0, 48.5, -118.0, 44.0, ratio)
    size = 180.0 / 2**level
    rng = np.random.default_rng(level)
    n = 80
    where = np.concatenate([np.full((n // 2, 2), 0.5), rng.uniform(0.02, 0.98, (n // 2, 2))])
    pts, _ = _fold_tiles(frame, size, np.resize(where, (n, 2)))
    bound = frame.bend_bound_m(pts)
    low = pts[:, : LATTICE * LATTICE].reshape(-1, LATTICE, LATTICE, 3)
    frac = bend_fractions(65)
    for spans in (1, 2):
        stray = np.max([_stray_m(frame, a, b) for a, b in _edges(low, spans)], axis=0)
        # bend_fractions gives `spans` for the stride whose edge spans that many.
        f = float(frac[np.flatnonzero(frac == spans)[0]])
        assert np.all(bound * f >= stray), (spans, float(np.max(stray - bound * f)))
    # Through the centre node too the fold is seen (the single-span midpoints read ~0 there).
    assert np.all(bound > 0.0)
