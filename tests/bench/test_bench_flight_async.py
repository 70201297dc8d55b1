"""`bench flight --async` (issue #27, item 2): a flight in wall time with background loading.
Counts, never timings: the clock here is a fake one that only the driver's sleeps advance,
so which frames are moving and which settle does not depend on the machine's speed."""

from __future__ import annotations

import argparse
import csv
import json
import math
import threading
import time

import pytest

pytestmark = pytest.mark.gl

SHORT = {  # 1 s up the White Mountains at 20 km, looking down (a few dozen tiles at 64x48)
    "name": "short",
    "keyframes": [
        {"t": 0.0, "lon": -71.45, "lat": 44.10, "height": 20000, "heading": 0, "pitch": -60},
        {"t": 1.0, "lon": -71.25, "lat": 44.25, "height": 9000, "heading": 30, "pitch": -40},
    ],
}


class FakeClock:
    """Seconds that advance only when the driver sleeps (each sleep also yields the CPU
    to the loader for a few real milliseconds)."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds
        time.sleep(0.005)


@pytest.fixture
def bench():
    from globeview.bench.harness import Bench, load_terrain
    from globeview.render.offscreen import RenderError

    try:
        b = Bench(load_terrain("embedded"), (64, 48))
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")
    b.use("chunked-sse", 2.0)
    yield b
    b.release()


def _slow_builds(renderer, seconds: float, gate: threading.Event | None = None) -> None:
    """Make every background build of ``renderer`` take ``seconds`` longer a tile, or wait
    for ``gate`` (builds on the test's own thread, the synchronous start, as they are)."""
    one, many = renderer.build_mesh, renderer.build_meshes

    def wait(n: int) -> None:
        if threading.current_thread() is threading.main_thread():
            return
        if gate is not None:
            assert gate.wait(30.0)
        time.sleep(seconds * n)

    def build_mesh(key):
        wait(1)
        return one(key)

    def build_meshes(keys):
        wait(len(keys))
        return many(keys)

    renderer.build_mesh, renderer.build_meshes = build_mesh, build_meshes


def test_a_slow_loader_shows_stand_ins_and_a_finite_detail_lag(bench) -> None:
    from globeview.bench.flight import Flight
    from globeview.bench.flight_async import async_summary, fly_async

    renderer = bench.session.renderer
    _slow_builds(renderer, 0.01)
    clock = FakeClock()
    run = fly_async(
        bench, Flight.from_dict(SHORT), fps=4.0, timeout_s=1e4, clock=clock, sleep=clock.sleep
    )
    moving = [r for r in run.rows if r.phase == "flight"]
    settle = [r for r in run.rows if r.phase == "settle"]
    assert len(moving) == 4  # t = 0, 0.25, 0.5, 0.75 s; the path ends at 1 s
    assert [r.wall_s for r in moving] == [0.0, 0.25, 0.5, 0.75]
    assert settle and all(r.wall_s >= 1.0 for r in settle)
    s = async_summary(run)
    assert s["standin_share"] > 0 and s["missing_share"] > 0
    assert sum(r.tiles_standin for r in moving) > 0
    # The last frame is complete; the lag is its end (= its start: frames take no fake time)
    # minus the path's end.
    last = run.rows[-1]
    assert last.tiles_missing == last.tiles_standin == last.tiles_building == 0
    assert math.isfinite(run.detail_lag_s) and run.detail_lag_s == pytest.approx(last.wall_s - 1.0)
    assert not any(r.tiles_missing == r.tiles_standin == r.tiles_building == 0 for r in settle[:-1])
    assert run.tiles_built > 0 and s["tiles_built"] == run.tiles_built
    assert sum(r.tiles_uploaded for r in run.rows) > 0
    assert not renderer.async_loading  # restored


def test_a_still_camera_draws_no_stand_in_and_completes_at_once(bench) -> None:
    from globeview.bench.flight import Flight
    from globeview.bench.flight_async import async_summary, fly_async

    still = json.loads(json.dumps(SHORT))
    still["keyframes"][1].update({k: v for k, v in SHORT["keyframes"][0].items() if k != "t"})
    clock = FakeClock()
    run = fly_async(bench, Flight.from_dict(still), fps=4.0, clock=clock, sleep=clock.sleep)
    s = async_summary(run)
    assert s["standin_share"] == 0.0 and s["missing_share"] == 0.0
    assert s["frames"] == 4 and s["settle_frames"] == 1  # the first still frame is complete
    assert run.detail_lag_s == 0.0
    assert s["missed"] == 0  # frames take no fake time


def test_a_loader_that_never_finishes_times_out(bench) -> None:
    from globeview.bench.flight import Flight
    from globeview.bench.flight_async import fly_async, lag_text

    gate = threading.Event()
    _slow_builds(bench.session.renderer, 0.0, gate)
    clock = FakeClock()
    try:
        run = fly_async(
            bench, Flight.from_dict(SHORT), fps=2.0, timeout_s=2.0, clock=clock, sleep=clock.sleep
        )
    finally:
        gate.set()
    assert run.detail_lag_s == math.inf and lag_text(run.detail_lag_s) == "> 10 s"
    assert lag_text(run.detail_lag_s, 2.0) == "> 2 s"
    assert 2.0 < run.rows[-1].wall_s - 1.0 <= 2.5  # the first frame past the timeout


def test_unpaced_frames_are_never_missed(bench) -> None:
    from globeview.bench.flight import Flight
    from globeview.bench.flight_async import fly_async

    ticks = iter(i * 0.3 for i in range(10_000))  # each clock read 0.3 s later
    run = fly_async(bench, Flight.from_dict(SHORT), fps=0.0, clock=lambda: next(ticks))
    assert run.rows and not any(r.missed for r in run.rows)
    with pytest.raises(ValueError, match="fps must be"):
        fly_async(bench, Flight.from_dict(SHORT), fps=-1.0)


def _bench(argv: list[str]) -> int:
    from globeview.cli import bench

    parser = argparse.ArgumentParser(prog="globeview bench")
    bench.add_arguments(parser)
    return bench.run(parser.parse_args(argv))


def test_cli_async_flight_writes_its_csv_and_summary(tmp_path, capsys) -> None:
    from globeview.bench.flight_async import ASYNC_CSV_COLUMNS, MARKDOWN_HEADER

    path = tmp_path / "short.json"
    path.write_text(json.dumps(SHORT))
    out = tmp_path / "f.csv"
    argv = ["flight", str(path), "--async", "--size", "64x48", "--fps", "30", "--csv", str(out)]
    assert _bench(argv) == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ASYNC_CSV_COLUMNS
    assert {r["phase"] for r in rows} <= {"flight", "settle"} and rows[0]["phase"] == "flight"
    text = capsys.readouterr().out
    assert "frame_ms p50" in text and "detail lag" in text
    assert MARKDOWN_HEADER.splitlines()[0] in text
    assert "| short | 64x48 | thread x1 | 30 |" in text


def test_cli_async_flight_with_worker_processes(tmp_path, capsys) -> None:
    """`--loader process --workers 2`: the tiles are built in two worker processes (started
    before the clock) and the flight completes its view; their CPU is counted."""
    path = tmp_path / "short.json"
    path.write_text(json.dumps(SHORT))
    argv = ["flight", str(path), "--async", "--size", "64x48", "--fps", "30"]
    assert _bench([*argv, "--loader", "process", "--workers", "2", "--timeout", "60"]) == 0
    text = capsys.readouterr().out
    row = next(line for line in text.splitlines() if line.startswith("| short |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2] == "process x2"
    assert cells[11] != "> 60 s"  # the view completed
    assert int(cells[12]) > 0 and float(cells[13]) > 0.0  # tiles built, CPU per tile


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--frames", "3", "--async"], "--frames samples a synchronous flight"),
        (["--fps", "0"], "--fps 0"),
        (["--loader", "process"], "--loader and --workers are for --async"),
        (["--workers", "2"], "--loader and --workers are for --async"),
    ],
)
def test_cli_refuses_what_the_mode_cannot_do(argv, needle) -> None:
    from globeview.errors import GlobeviewError

    with pytest.raises(GlobeviewError, match=needle):
        _bench(["flight", "canyon_run", "--size", "64x48", *argv])
