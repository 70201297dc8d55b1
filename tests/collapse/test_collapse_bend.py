"""The collapse's cheap bend bound (`CollapseFrame.bend_bound_m`, the `Tool.displacement_bend_m`
hook LOD providers use through `culling.displacement_bend_m`) against the exact measure."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.lod.culling import displacement_chord_error_m, tile_bounding_points
from globeview.plugins.builtin.collapse.geometry import BEND_PSI_MARGIN, CollapseFrame


def _random_tiles(
    rng: np.random.Generator, n: int, size_deg: float, box: tuple[float, float, float, float]
) -> np.ndarray:
    """Bounding lattices (n, K, 3) of random tiles of ``size_deg`` inside a lon/lat box."""
    w = rng.uniform(box[0], box[2] - size_deg, n)
    s = rng.uniform(box[1], box[3] - size_deg, n)
    hmin = rng.uniform(-400.0, 3000.0, n)
    hmax = hmin + rng.uniform(0.0, 5000.0, n)
    pts, _ = tile_bounding_points(w, s, w + size_deg, s + size_deg, hmin, hmax, 2.0)
    return pts


def _random_frame(rng: np.random.Generator) -> CollapseFrame:
    while True:
        lon_a, lat_a = rng.uniform(-180.0, 180.0), rng.uniform(-70.0, 70.0)
        span = rng.uniform(0.05, 60.0)
        lon_b = lon_a + span * rng.uniform(-1.0, 1.0)
        lat_b = float(np.clip(lat_a + span * rng.uniform(-1.0, 1.0), -85.0, 85.0))
        try:
            return CollapseFrame.from_lonlat(
                lon_a, lat_a, lon_b, lat_b, float(rng.choice([0.02, 0.1, 0.5, 0.9]))
            )
        except ValueError:
            continue


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6))
def test_bound_covers_the_exact_bend_everywhere(seed: int) -> None:
    rng = np.random.default_rng(seed)
    frame = _random_frame(rng)
    for level in (1, 2, 3, 4, 6, 8, 10, 12, 14):
        size = 180.0 / 2**level
        pts = _random_tiles(rng, 400, size, (-180.0, -90.0, 180.0, 90.0))
        exact = displacement_chord_error_m(frame.forward, pts)
        bound = frame.bend_bound_m(pts)
        assert np.all(bound >= exact - 1e-6), (level, float(np.max(exact - bound)))
        # Reusing the caller's displaced lattice changes nothing.
        again = frame.bend_bound_m(pts, frame.forward(pts.reshape(-1, 3)).reshape(pts.shape))
        np.testing.assert_allclose(again, bound, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_bound_covers_tiles_straddling_the_folds(seed: int) -> None:
    """Tiles centred on the fold lines (|psi| = psi0), where the kink bends edges the most."""
    rng = np.random.default_rng(100 + seed)
    frame = CollapseFrame.from_lonlat(-123.0, 48.5, -118.0, 44.0, 0.1)
    for level in (4, 6, 8, 10, 12):
        size = 180.0 / 2**level
        edge = np.concatenate([frame.edge_line(sgn * frame.psi0, 0.05, 200) for sgn in (-1.0, 1.0)])
        from globeview.geodesy import ecef_to_lonlat

        lon, lat, _ = ecef_to_lonlat(edge)
        w = lon - size * rng.uniform(0.05, 0.95, len(lon))
        s = lat - size * rng.uniform(0.05, 0.95, len(lat))
        n = len(w)
        pts, _ = tile_bounding_points(w, s, w + size, s + size, np.zeros(n), np.full(n, 2000.0))
        exact = displacement_chord_error_m(frame.forward, pts)
        bound = frame.bend_bound_m(pts)
        assert np.all(exact > 0.0)
        assert np.all(bound >= exact - 1e-6), level


def test_bound_is_negligible_away_from_the_folds() -> None:
    """Tiles clearly outside the zone (rigid up to the ellipsoid) bound to well under a
    centimetre at level 10 and to 0 with ratio 1; straddling tiles bound to metres."""
    frame = CollapseFrame.from_lonlat(-123.0, 48.5, -118.0, 44.0, 0.1)
    rng = np.random.default_rng(7)
    size = 180.0 / 2**10
    far = _random_tiles(rng, 500, size, (-100.0, 20.0, -60.0, 40.0))  # east of the zone
    psi, _ = frame.axis_angles(far.reshape(-1, 3))
    assert np.all(np.abs(psi) > frame.psi0 + 4 * BEND_PSI_MARGIN)
    bound = frame.bend_bound_m(far)
    assert np.all(bound < 1e-2)
    assert np.all(bound >= displacement_chord_error_m(frame.forward, far) - 1e-6)
    identity = CollapseFrame.from_lonlat(-123.0, 48.5, -118.0, 44.0, 1.0)
    assert not np.any(identity.bend_bound_m(far))


def test_session_exposes_the_hook_and_falls_back_without_one() -> None:
    """The shared helper uses the tool's bound when the view carries one, else the exact
    measure, and returns zeros with no displacement."""
    from dataclasses import replace

    from globeview.lod.culling import displacement_bend_m
    from globeview.lod.view_state import ViewState
    from globeview.model.camera import Camera

    frame = CollapseFrame.from_lonlat(-123.0, 48.5, -118.0, 44.0, 0.1)
    rng = np.random.default_rng(3)
    pts = _random_tiles(rng, 200, 180.0 / 2**6, (-130.0, 40.0, -110.0, 52.0))
    view = ViewState.from_camera(Camera.from_lonlat(-120.0, 44.0, 5.0e5), (64, 48))
    assert not displacement_bend_m(view, pts).any()
    exact = displacement_chord_error_m(frame.forward, pts)
    generic = replace(view, displace=frame.forward)
    np.testing.assert_allclose(displacement_bend_m(generic, pts), exact, rtol=1e-12)
    hooked = replace(generic, displacement_bend=frame.bend_bound_m)
    np.testing.assert_array_equal(displacement_bend_m(hooked, pts), frame.bend_bound_m(pts))
