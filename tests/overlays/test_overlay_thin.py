"""Dense line layers drawn from far away (issue #26 item 3: a 1 M-vertex layer keeps the frame
rate): `thin` keeps each polyline's ends and a vertex per spacing, every dropped vertex within
that spacing of the thinned line; a `VectorLayer` of dense lines gets thinned levels below its
``segment_m`` whose vertex counts halve level by level (what a far view draws)."""

from __future__ import annotations

import numpy as np

from globeview.model.drawables import Lines
from globeview.model.overlay_layers import vector_layer
from globeview.terrain.vectors import Polylines, segment_lengths_m, thin


def _walks(n_lines: int, per: int, step_deg: float = 1.5e-4, seed: int = 3) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_lines):
        start = rng.uniform([-71.9, 43.7], [-70.7, 44.8])
        out.append(start + rng.normal(0.0, step_deg, (per, 2)).cumsum(axis=0))
    return out


def _polylines(paths: list[np.ndarray]) -> Polylines:
    xy = np.concatenate(paths)
    starts = np.concatenate([[0], np.cumsum([len(p) for p in paths])]).astype(np.int64)
    return Polylines(xy[:, 0].copy(), xy[:, 1].copy(), starts)


def test_thin_keeps_ends_and_a_vertex_per_spacing():
    paths = _walks(20, 500)
    pl = _polylines(paths)
    out = thin(pl, 200.0)
    assert len(out) == len(pl)
    for i, p in enumerate(paths):
        q = np.c_[out.lon, out.lat][out.starts[i] : out.starts[i + 1]]
        assert (q[0] == p[0]).all() and (q[-1] == p[-1]).all()
        assert 2 <= len(q) < len(p) / 5
    # Every kept segment but each polyline's last spans at least the spacing along the line
    # (its chord may be shorter), and the count is about the length over the spacing.
    total = segment_lengths_m(pl).sum()
    assert abs(len(out.lon) - (total / 200.0 + len(paths))) < 0.1 * len(out.lon)


def test_dense_lines_get_thinned_levels_for_far_views():
    layer = vector_layer(Lines(_walks(50, 2_000), segment_m=1_000.0), "walks")
    n_fine = len(layer.lines.lon)
    assert n_fine == 100_000  # 15 m steps: nothing to densify at 1 km
    spacings = [m for m, _ in layer.coarser]
    counts = [len(pl.lon) for _, pl in layer.coarser]
    below = [m for m in spacings if m < 1_000.0]
    assert len(below) >= 2 and below[0] < 100.0
    assert counts == sorted(counts, reverse=True)
    # The first thinned level halves the vertices (thinned to half its spacing), each next
    # one about halves the one before.
    assert counts[0] < 0.6 * n_fine and counts[1] < counts[0] / 1.6


def test_sparse_lines_keep_their_levels():
    layer = vector_layer(Lines([np.array([[0.0, 0.0], [10.0, 10.0]])]), "one")
    assert [m for m, _ in layer.coarser] == [80_000.0, 320_000.0, 1_280_000.0]
