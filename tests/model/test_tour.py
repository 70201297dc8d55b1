"""Tours (issue #26 item 5): keyframes flown over the globe (great circle, geometric height,
shorter-way heading, no jump at the antimeridian), and their versioned JSON/TOML files."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from globeview.errors import GlobeviewError
from globeview.model.tour import (
    TOUR_VERSION,
    Keyframe,
    Tour,
    TourError,
    load_tour,
    save_tour,
    tour_from_dict,
    tour_to_dict,
)


def _angle_deg(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    """Great-circle angle (degrees) between two (lon, lat, ...) poses on the sphere."""
    la1, la2 = math.radians(a[1]), math.radians(b[1])
    dlon = math.radians(b[0] - a[0])
    c = math.sin(la1) * math.sin(la2) + math.cos(la1) * math.cos(la2) * math.cos(dlon)
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _tour(*frames: tuple[float, ...]) -> Tour:
    return Tour([Keyframe(*f[:-1], seconds=f[-1]) for f in frames])


def test_the_keyframes_are_reached_exactly_and_legs_add_up() -> None:
    tour = _tour((-71.3, 44.2, 9000.0, 10.0, -30.0, 0.0, 1.0), (-71.0, 44.3, 3000.0, 40, -20, 0, 3))
    assert tour.duration == 4.0
    assert tour.times().tolist() == [1.0, 4.0]
    assert tour.pose_at(0.0) == tour.keyframes[0].pose  # the first keyframe's hold
    assert tour.pose_at(1.0) == tour.keyframes[0].pose
    assert tour.pose_at(4.0) == pytest.approx(tour.keyframes[1].pose)
    assert tour.pose_at(99.0) == tour.keyframes[1].pose  # clamped


def test_position_follows_the_great_circle_across_the_antimeridian() -> None:
    tour = _tour((-100.0, 40.0, 1e6, 0, -90, 0, 0), (100.0, 40.0, 1e6, 0, -90, 0, 10))
    mid = tour.pose_at(5.0)
    # The short way from 100 W to 100 E crosses 180; the great circle bulges poleward to
    # atan(tan 40 / cos 80) there.
    assert abs(abs(mid[0]) - 180.0) < 1e-9
    assert mid[1] == pytest.approx(
        math.degrees(math.atan(math.tan(math.radians(40)) / math.cos(math.radians(80))))
    )
    lons = [tour.pose_at(t)[0] for t in np.linspace(0, 10, 101)]
    assert all(abs(lon) >= 100.0 - 1e-9 for lon in lons), "went the long way through 0"


def test_height_is_geometric_and_heading_turns_the_short_way() -> None:
    tour = _tour((7.0, 46.0, 1.0e7, 350.0, -90.0, 0.0, 0), (7.0, 46.0, 1.0e3, 10.0, -30.0, 0.0, 2))
    mid = tour.pose_at(1.0)  # the eased halfway point is s = 0.5
    assert mid[2] == pytest.approx(1.0e5)  # sqrt(1e7 * 1e3)
    assert mid[3] == pytest.approx(0.0, abs=1e-9) or mid[3] == pytest.approx(360.0)
    assert mid[4] == pytest.approx(-60.0)
    headings = [tour.pose_at(t)[3] for t in np.linspace(0, 2, 41)]
    assert all(h >= 350.0 - 1e-9 or h <= 10.0 + 1e-9 for h in headings)


def test_over_the_pole_and_between_antipodes_no_nan() -> None:
    polar = _tour((0.0, 80.0, 5e5, 0, -90, 0, 0), (180.0, 80.0, 5e5, 0, -90, 0, 1))
    assert polar.pose_at(0.5)[1] == pytest.approx(90.0, abs=1e-6)
    antipodes = _tour((30.0, 10.0, 5e5, 0, -90, 0, 0), (-150.0, -10.0, 5e5, 0, -90, 0, 1))
    poses = [antipodes.pose_at(t) for t in np.linspace(0, 1, 21)]
    assert all(math.isfinite(v) for p in poses for v in p)
    assert poses[-1][:2] == pytest.approx((-150.0, -10.0))


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(-180, 180),
            st.floats(-89, 89),
            st.floats(10.0, 1e7),
            st.floats(0, 359),
            st.floats(0.5, 5),
        ),
        min_size=2,
        max_size=5,
    )
)
def test_no_jumps_anywhere(frames: list[tuple[float, float, float, float, float]]) -> None:
    """Sampled finely, consecutive poses are close: no jump in position (antimeridian, pole),
    height or heading. A leg of angle A eased by smoothstep moves at most 1.5 A / leg s."""
    tour = Tour([Keyframe(lon, lat, h, hd, -45.0, seconds=s) for lon, lat, h, hd, s in frames])
    ts = np.linspace(0.0, tour.duration, 300)
    dt = ts[1] - ts[0]
    poses = [tour.pose_at(t) for t in ts]
    kf = tour.keyframes
    max_rate = max(1.5 * _angle_deg(a.pose, b.pose) / b.seconds for a, b in itertools.pairwise(kf))
    for p, q in itertools.pairwise(poses):
        assert _angle_deg(p, q) <= max_rate * dt * 1.01 + 1e-6
        assert abs((q[3] - p[3] + 180.0) % 360.0 - 180.0) <= 1.5 * 180.0 / 0.5 * dt + 1e-6
        assert abs(math.log(q[2] / p[2])) <= 1.5 * math.log(1e6) / 0.5 * dt + 1e-9


def test_frame_times_start_and_end_on_keyframes() -> None:
    tour = _tour((0.0, 0.0, 1e6, 0, -90, 0, 0), (10.0, 0.0, 1e6, 0, -90, 0, 2))
    times = tour.frame_times(12)
    assert len(times) == 24 and times[0] == 0.0 and times[-1] == 2.0
    still = _tour((0.0, 0.0, 1e6, 0, -90, 0, 0))
    assert still.frame_times(30).tolist() == [0.0]


@pytest.mark.parametrize(
    ("values", "word"),
    [
        ({"lon": math.nan}, "longitude"),
        ({"lat": 91.0}, "latitude"),
        ({"height": math.inf}, "height"),
        ({"pitch": -91.0}, "pitch"),
        ({"seconds": -1.0}, "seconds"),
        ({"seconds": math.nan}, "seconds"),
    ],
)
def test_bad_keyframes_are_refused_in_one_line(values: dict, word: str) -> None:
    base = {"lon": 0.0, "lat": 0.0, "height": 1000.0, **values}
    with pytest.raises(ValueError, match=word) as info:
        Keyframe(**base)
    assert "\n" not in str(info.value)


def test_dict_json_and_toml_round_trip(tmp_path: Path) -> None:
    tour = _tour(
        (179.5, -20.0, 2.5e4, 12.5, -35.0, 3.0, 0.5), (-179.5, -21.0, 1.2e3, 300, -10, 0, 7)
    )
    tour.name = 'Fiji "east" flight'
    data = tour_to_dict(tour)
    assert data["format"] == "globeview-tour" and data["version"] == TOUR_VERSION
    embedded = json.loads(json.dumps({"bookmarks": [], "tour": data}))["tour"]
    assert tour_from_dict(embedded) == tour
    for suffix in (".json", ".toml"):
        path = save_tour(tour, tmp_path / f"t{suffix}")
        assert load_tour(path) == tour
    assert (tmp_path / "t.toml").read_text().count("[[keyframes]]") == 2


@pytest.mark.parametrize(
    ("text", "word"),
    [
        ("[1, 2, 3]", "not a globeview tour"),
        ('{"format": "globeview-project", "version": 1}', "not a globeview tour"),
        ('{"format": "globeview-tour", "version": 99, "keyframes": []}', "newer"),
        ('{"format": "globeview-tour", "version": 1, "keyframes": []}', "non-empty"),
        (
            '{"format": "globeview-tour", "version": 1, "keyframes": '
            '[{"lon": 1, "lat": 2, "height": 3, "hieght": 4}]}',
            "keyframe 1: unknown key 'hieght'",
        ),
        (
            '{"format": "globeview-tour", "version": 1, "keyframes": '
            '[{"lon": 1, "lat": 2, "height": 3}, {"lon": NaN, "lat": 2, "height": 3}]}',
            "keyframe 2: longitude",
        ),
        (
            '{"format": "globeview-tour", "version": 1, "keyframes": '
            '[{"lon": 1, "lat": true, "height": 3}]}',
            "lat must be a number",
        ),
        ("\x89PNG\r\n\x1a\n\x00\x00", "not a globeview tour"),
    ],
)
def test_files_that_are_not_tours_are_one_line(tmp_path: Path, text: str, word: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text, encoding="utf-8", errors="surrogateescape")
    with pytest.raises(TourError, match=word) as info:
        load_tour(path)
    assert "\n" not in str(info.value)


def test_missing_file_and_bad_output_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(TourError, match="cannot read"):
        load_tour(tmp_path / "none.json")
    tour = _tour((0.0, 0.0, 1e6, 0, -90, 0, 0))
    with pytest.raises(GlobeviewError, match=r"\.json or \.toml"):
        save_tour(tour, tmp_path / "t.txt")
    with pytest.raises(GlobeviewError, match="does not exist"):
        save_tour(tour, tmp_path / "no" / "t.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
