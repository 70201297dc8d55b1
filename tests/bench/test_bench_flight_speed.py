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
    """`Bench.measure` cuts the camera history: its view's first frame is at rest even when
    the previous frame showed another place a moment before (not a 10 km jump in 0.1 s)."""
    pose_a = (-71.3, 44.15, 9.0e3, 0.0, -30.0)
    pose_b = (-71.2, 44.25, 9.0e3, 0.0, -30.0)  # ~14 km from A
    bench.set_pose(pose_a, cut=True)
    bench.frame(100.0)
    pipeline, session = bench.session.pipeline, bench.session
    speeds = []
    select = session.select  # a spy around the real provider's selection

    def spy(view):
        speeds.append(view.speed_mps)
        return select(view)

    clock = pipeline.clock
    pipeline.clock = lambda: 100.1  # measure's frames come 0.1 s after A's: no pause
    session.select = spy
    try:
        m = bench.measure(pose_b, frames=2)
    finally:
        pipeline.clock = clock
        del session.select
    assert m["triangles"] > 0 and m["frame_ms"] > 0
    assert len(speeds) == 3  # the warm-up frame and the two measured ones
    assert speeds[0] == 0.0  # the jump from A to B is a cut, not a move
