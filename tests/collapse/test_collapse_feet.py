"""The collapse's CPU twin, made cheaper for the LOD: foot points from the trimmed closed form
agree with the geodesy module's round trip, frames of one A-B pair share their memo of feet
(the animation changes only the ratio) and moving points through the memo gives the same
result as moving them afresh."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.geodesy import ecef_foot_points as foot_points
from globeview.geodesy import ecef_to_lonlat, lonlat_to_ecef
from globeview.plugins.builtin.collapse.geometry import CollapseFrame, FootMemo


def test_foot_points_match_the_geodesy_round_trip() -> None:
    rng = np.random.default_rng(5)
    n = 4000
    lon = rng.uniform(-180.0, 180.0, n)
    lat = np.concatenate([rng.uniform(-90.0, 90.0, n - 4), [90.0, -90.0, 0.0, 89.9999999]])
    h = rng.uniform(-1.2e4, 2.0e6, n)
    p = lonlat_to_ecef(lon, lat, h)
    foot, hh = foot_points(p)
    lo, la, h_ref = ecef_to_lonlat(p)
    ref = lonlat_to_ecef(lo, la, 0.0)
    assert np.max(np.abs(hh - h_ref)) < 1e-6
    assert np.max(np.linalg.norm(foot - ref, axis=1)) < 1e-6
    # Deep inside the Earth (inside the evolute) the general way is taken: still a foot point.
    inner = np.array([[1.0e3, 2.0e3, 5.0e2], [0.0, 0.0, 0.0]])
    f_in, h_in = foot_points(inner)
    assert np.isfinite(f_in).all() and np.isfinite(h_in).all()


def test_frames_of_one_pair_share_feet_and_agree_with_fresh_ones() -> None:
    a_b = (-122.1, 43.0, -122.6, 48.05)
    f1 = CollapseFrame.from_lonlat(*a_b, 0.5)
    f2 = f1.with_ratio(0.2)
    assert f2.feet is f1.feet
    assert CollapseFrame.from_lonlat(*a_b, 0.2).feet is not f1.feet
    rng = np.random.default_rng(9)
    pts = lonlat_to_ecef(
        rng.uniform(-125.0, -119.0, 500), rng.uniform(41.0, 50.0, 500), rng.uniform(0, 4e3, 500)
    )
    first = f1.forward(pts)
    again = f1.forward(pts)  # from the memo
    fresh = CollapseFrame.from_lonlat(*a_b, 0.5, FootMemo()).forward(pts)
    assert np.array_equal(first, again) and np.array_equal(first, fresh)
    assert np.array_equal(f2.forward(pts), CollapseFrame.from_lonlat(*a_b, 0.2).forward(pts))
    assert np.max(np.linalg.norm(f2.inverse(f2.forward(pts)) - pts, axis=1)) <= 1e-3


def test_the_tool_keeps_its_feet_while_animating() -> None:
    from globeview.plugins.builtin.collapse.tool import CollapseTool

    tool = CollapseTool()
    tool.set_points(-122.1, 43.0, -122.6, 48.05, 0.1, animate=True)
    tool.animate(0.0)
    first = tool.frame()
    tool.animate(0.2)
    second = tool.frame()
    assert first is not None and second is not None
    assert second.ratio != first.ratio and second.feet is first.feet
    tool.set_points(-120.0, 44.0, -118.0, 46.0, 0.1)  # another pair: a new memo
    third = tool.frame()
    assert third is not None and third.feet is not first.feet


def test_the_overlay_is_made_once_per_frame() -> None:
    """A still collapse hands the same primitives to every redraw; a new ratio makes new ones."""
    from globeview.plugins.builtin.collapse.tool import CollapseTool

    tool = CollapseTool()
    tool.set_points(-122.1, 43.0, -122.6, 48.05, 0.1)
    first, second = tool.overlay(None), tool.overlay(None)
    assert len(first) == 5 and all(a is b for a, b in zip(first, second, strict=True))
    tool.set_points(-122.1, 43.0, -122.6, 48.05, 0.2)
    third = tool.overlay(None)
    # Made again (the lines are in true coordinates: the same places at any ratio).
    assert len(third) == 5 and third[2] is not first[2]
    assert np.allclose(third[2].points, first[2].points)
    tool.cancel()
    assert tool.overlay(None) == []


@pytest.mark.slow
def test_the_bend_grows_with_the_collapse() -> None:
    """What the animation's bend relies on: for random tiles (levels 1-12, straddling the folds
    too) and random pairs, the exact bend at any ratio between r and 1 is at most the bound
    at r; and the tool's answer while animating is the bound at a ratio between the final one
    and the effective one."""
    from globeview.geodesy import ecef_to_lonlat
    from globeview.lod.culling import displacement_chord_error_m, tile_bounding_points
    from globeview.plugins.builtin.collapse.tool import CollapseTool

    rng = np.random.default_rng(21)
    for _ in range(4):
        lon_a, lat_a = rng.uniform(-180.0, 180.0), rng.uniform(-60.0, 60.0)
        span = rng.uniform(0.1, 40.0)
        lon_b, lat_b = lon_a + span * rng.uniform(-1, 1), lat_a + span * rng.uniform(-0.5, 0.5)
        f = CollapseFrame.from_lonlat(lon_a, lat_a, lon_b, lat_b, float(rng.choice([0.05, 0.3])))
        for level in (1, 3, 6, 9, 12):
            size = 180.0 / 2**level
            edge = np.concatenate([f.edge_line(sg * f.psi0, 0.05, 60) for sg in (-1.0, 1.0)])
            lon, lat, _ = ecef_to_lonlat(edge)
            w = np.concatenate([lon, rng.uniform(-180.0, 180.0, 60)]) - 0.5 * size
            # Tiles end at the pole: past it is no latitude (lonlat_to_ecef gives NaN).
            top = min(80.0, 90.0 - size)
            s = np.clip(np.concatenate([lat, rng.uniform(-80.0, 80.0, 60)]), -85.0, top)
            n = len(w)
            pts, _ = tile_bounding_points(
                w, s, w + size, s + size, np.zeros(n), rng.uniform(0.0, 4000.0, n)
            )
            bound = f.bend_bound_m(pts)
            for r in np.linspace(f.ratio, 1.0, 6)[1:-1]:
                exact = displacement_chord_error_m(f.with_ratio(float(r)).forward, pts)
                assert np.all(exact <= bound + 1e-6), (level, r)
    tool = CollapseTool()
    tool.set_points(-123.0, 48.5, -118.0, 44.0, 0.1, animate=True)
    tool.animate(0.0)
    tool.animate(0.2)
    r_eff = tool.effective_ratio
    assert tool.state == "collapsing" and 0.1 < r_eff < 1.0
    # The bound of the effective ratio rounded toward 0.1 to a quarter step of (1 - 0.1).
    step = np.ceil((1.0 - r_eff) / 0.9 * 4.0) / 4.0
    r_step = 1.0 - 0.9 * step
    assert 0.1 <= r_step <= r_eff
    frame = CollapseFrame.from_lonlat(-123.0, 48.5, -118.0, 44.0, r_step)
    size = 180.0 / 2**7
    pts, _ = tile_bounding_points(
        np.array([-121.0]), np.array([46.0]), np.array([-121.0 + size]),
        np.array([46.0 + size]), np.zeros(1), np.full(1, 1000.0),
    )  # fmt: skip
    np.testing.assert_allclose(tool.displacement_bend_m(pts), frame.bend_bound_m(pts))
    np.testing.assert_allclose(tool.displacement_bend_m(pts), frame.bend_bound_m(pts))  # memo
