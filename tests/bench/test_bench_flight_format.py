"""The camera path format: parsing, validation and interpolation (pure, no GL)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from globeview.bench.flight import Flight, FlightError, shipped_flights_dir


def _kf(t, lon, lat, h, heading=0.0, pitch=-30.0):
    return {"t": t, "lon": lon, "lat": lat, "height": h, "heading": heading, "pitch": pitch}


def test_interpolates_linearly_and_log_height():
    fl = Flight.from_dict(
        {"keyframes": [_kf(0, 10, 20, 1e3, 0, -90), _kf(2, 12, 22, 1e5, 40, -30)]}
    )
    p = fl.pose(1.0)
    assert p.lon == pytest.approx(11.0)
    assert p.lat == pytest.approx(21.0)
    assert p.height == pytest.approx(1e4)  # geometric mean: log-height interpolation
    assert p.heading == pytest.approx(20.0)
    assert p.pitch == pytest.approx(-60.0)
    assert fl.pose(-5.0).as_tuple() == fl.pose(0.0).as_tuple()  # clamped
    assert fl.pose(9.0).height == pytest.approx(1e5)


def test_angles_take_the_short_way_round():
    fl = Flight.from_dict(
        {"keyframes": [_kf(0, 179.0, 0, 1e4, 350.0), _kf(1, -179.0, 0, 1e4, 10.0)]}
    )
    p = fl.pose(0.5)
    assert abs(abs(p.lon) - 180.0) < 1e-9
    assert p.heading == pytest.approx(0.0, abs=1e-9) or p.heading == pytest.approx(360.0)


def test_times_by_frames_and_fps():
    fl = Flight.from_dict({"keyframes": [_kf(0, 0, 0, 1e4), _kf(4, 1, 0, 1e4)]})
    assert np.allclose(fl.times(frames=5), [0, 1, 2, 3, 4])
    assert len(fl.times(fps=2.0)) == 9
    assert len(fl.times(frames=1)) == 1
    with pytest.raises(ValueError, match="not both"):
        fl.times(frames=2, fps=1.0)


@pytest.mark.parametrize(
    ("data", "msg"),
    [
        ({}, "keyframes"),
        ({"keyframes": [_kf(0, 0, 0, 1)]}, "at least 2"),
        ({"keyframes": [_kf(1, 0, 0, 1), _kf(1, 0, 0, 1)]}, "increase"),
        ({"keyframes": [_kf(0, 0, 0, 1), _kf(1, 0, 0, 0)]}, "heights"),
        ({"keyframes": [_kf(0, 0, 0, 1), {"t": 1}]}, "lacks"),
        ({"keyframes": [_kf(0, 0, 0, 1), _kf(1, 0, 0, "x")]}, "not a number"),
        ({"keyframes": [_kf(0, 0, 0, 1), _kf(1, 0, 0, 1)], "terrain": "moon"}, "terrain"),
    ],
)
def test_rejects_malformed_paths(data, msg):
    with pytest.raises(FlightError, match=msg):
        Flight.from_dict(data)


def test_load_reports_bad_json(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text("{nope")
    with pytest.raises(FlightError, match="not valid JSON"):
        Flight.load(p)


def test_shipped_flights_parse():
    files = sorted(shipped_flights_dir().glob("*.json"))
    assert len(files) >= 5
    for f in files:
        fl = Flight.load(f)
        assert fl.duration > 0
        json.loads(f.read_text())  # plain JSON
        for t in fl.times(frames=7):
            p = fl.pose(float(t))
            assert all(math.isfinite(v) for v in p.as_tuple())
    assert any(Flight.load(f).terrain == "big-dem" for f in files)
