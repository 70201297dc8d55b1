"""The soak flies its flights through the harness's one flight loop (`harness.fly`), so its
frames carry the flights' speed like every other benchmark's (issue #14). Structure only,
never timings."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.gl


def test_soak_frames_see_the_flights_speed(monkeypatch) -> None:
    from globeview.bench.soak import SOAK_FLIGHTS, run_soak
    from globeview.render.frame_pipeline import FramePipeline
    from globeview.render.offscreen import RenderError

    speeds: list[float] = []
    run = FramePipeline.run  # a spy around the real pipeline: every frame the soak draws

    def spy(self, *args, **kwargs):
        result = run(self, *args, **kwargs)
        speeds.append(result.view.speed_mps)
        return result

    monkeypatch.setattr(FramePipeline, "run", spy)
    per_flight = 3
    frames = per_flight * len(SOAK_FLIGHTS)  # one lap: every flight once
    try:
        res = run_soak(frames=frames, size=(64, 48), per_flight=per_flight, log=lambda _: None)
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")
    assert res["frames"] == frames and len(speeds) == frames
    # Each flight starts at rest; its later samples (seconds apart) are moves, not pauses.
    assert speeds[::per_flight] == [0.0] * len(SOAK_FLIGHTS)
    moving = [s for i, s in enumerate(speeds) if i % per_flight]
    assert all(s > 0.0 for s in moving), speeds
    assert len(res["samples"]) == len(SOAK_FLIGHTS)  # one sample per flight, as before
