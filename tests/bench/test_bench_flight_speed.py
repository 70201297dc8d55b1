"""The harness flies through the frame pipeline with the flight's time stamps (issue #14):
the camera speed the distance-regions provider uses is the flight's own, also headless, and
sparse samples are not taken for pauses. Structure only, never timings."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.geodesy import lonlat_to_ecef

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def bench():
    from globeview.bench.harness import Bench, load_terrain
    from globeview.render.offscreen import RenderError

    try:
        b = Bench(load_terrain("embedded"), (96, 64), lod="distance-regions")
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")
    yield b
    b.release()


def test_flight_frames_carry_the_flights_speed(bench) -> None:
    from globeview.bench.flight import Flight, shipped_flights_dir
    from globeview.bench.harness import fly

    flight = Flight.load(shipped_flights_dir() / "canyon_run.json")
    times = flight.times(frames=4)  # seconds apart: sparse samples, still a flight
    speeds = []
    select = bench.session.select  # a spy around the real provider's selection

    def spy(view):
        speeds.append(view.speed_mps)
        return select(view)

    bench.session.select = spy
    try:
        rows = fly(bench, flight, times)
    finally:
        del bench.session.select
    eyes = [
        np.asarray(lonlat_to_ecef(*flight.pose(float(t)).as_tuple()[:3])).reshape(3) for t in times
    ]
    want = [0.0] + [
        float(np.linalg.norm(eyes[i] - eyes[i - 1])) / float(times[i] - times[i - 1])
        for i in range(1, len(times))
    ]
    assert rows[0].speed_mps == 0.0  # the flight starts at rest
    assert [r.speed_mps for r in rows] == pytest.approx(want, rel=1e-6)
    assert min(want[1:]) > 0.0
    assert speeds[-len(rows) :] == [r.speed_mps for r in rows]  # what the provider saw
    assert bench.session.pipeline.motion.pause_s == 0.5  # restored after the flight


def test_measure_starts_each_view_at_rest(bench) -> None:
    m = bench.measure((-71.3, 44.15, 9.0e3, 0.0, -30.0), frames=2, turn_deg=0.01)
    assert m["triangles"] > 0 and m["frame_ms"] > 0
    assert bench.session.last.view.speed_mps == 0.0  # turning in place: no speed
