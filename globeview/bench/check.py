"""`bench check`: the standard flight against the performance budgets.

Targets (from the issue):

1. median frame time <= 33 ms at tau = 2 px, 1280x720, over the large benchmark DEM;
2. median lod_ms <= 2 ms for the default provider (chunked-sse);
3. >= 30x fewer milliseconds than a full-resolution render of the same view;
4. measured max screen-space error <= tau over the whole flight.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from globeview.bench.experiments import full_resolution, standard_view
from globeview.bench.flight import Flight, shipped_flights_dir
from globeview.bench.harness import Bench, fly, load_terrain, machine, summary, write_csv

STANDARD_FLIGHT = "big_dem.json"
QUICK_FLIGHT = "canyon_run.json"
FRAME_MS = 33.0
LOD_MS = 2.0
SPEEDUP = 30.0


@dataclass
class Verdict:
    name: str
    holds: bool
    measured: str
    target: str

    def line(self) -> str:
        verdict = "PASS" if self.holds else "FAIL"
        return f"{verdict}  {self.name}: {self.measured} (target {self.target})"


def run_check(
    size: tuple[int, int] = (1280, 720),
    frames: int = 30,
    tau: float = 2.0,
    lod: str = "chunked-sse",
    quick: bool = False,
    csv: str | Path | None = None,
    log: Callable[[str], object] = print,
) -> list[Verdict]:
    """Fly the standard flight and return one verdict per target. ``quick``: the embedded
    canyon run, 160x90, 3 frames (a smoke run; its figures are not the targets' setting)."""
    flight_file = QUICK_FLIGHT if quick else STANDARD_FLIGHT
    if quick:
        size, frames = (160, 90), min(frames, 3)
    flight = Flight.load(shipped_flights_dir() / flight_file)
    bench = Bench(load_terrain(flight.terrain), size, lod=lod)
    try:
        log(f"machine: {machine(bench.gl_renderer)}")
        log(
            f"flight {flight.name!r} ({flight_file}, terrain {flight.terrain}), {frames} frames, "
            f"{size[0]}x{size[1]}, {lod}, tau {tau:g} px"
        )
        bench.use(lod, tau)
        rows = fly(bench, flight, flight.times(frames=frames))
        if csv:
            write_csv(rows, csv)
        s = summary(rows)
        log(
            f"frame_ms median {s['frame_ms_median']:.1f} (p95 {s['frame_ms_p95']:.1f}), "
            f"lod_ms median {s['lod_ms_median']:.2f}, draw_ms median {s['draw_ms_median']:.1f}, "
            f"triangles median {s['triangles_median']:.0f}, max SSE {s['max_sse_px']:.2f} px"
        )
        pose = standard_view(flight)
        bench.use(lod, tau)
        from globeview.bench.experiments import measure

        lod_m, _ = measure(bench, pose, 1 if quick else 3)
        ref, _ = full_resolution(bench, pose, 1 if quick else 3)
        log(
            f"mid-flight view: LOD {lod_m['frame_ms']:.1f} ms ({lod_m['triangles']} tris) vs "
            f"full resolution {ref['frame_ms']:.1f} ms ({ref['triangles']} tris)"
            + (", tile budget reached" if ref["budget_limited"] else "")
        )
    finally:
        bench.release()
    setting = "" if not quick else " [quick: not the target setting]"
    speed = ref["frame_ms"] / max(lod_m["frame_ms"], 1e-9)
    return [
        Verdict(
            "median frame time" + setting,
            s["frame_ms_median"] <= FRAME_MS,
            f"{s['frame_ms_median']:.1f} ms",
            f"<= {FRAME_MS:g} ms at tau 2 px, 1280x720, large DEM",
        ),
        Verdict(
            f"median lod_ms ({lod})" + setting,
            s["lod_ms_median"] <= LOD_MS,
            f"{s['lod_ms_median']:.2f} ms",
            f"<= {LOD_MS:g} ms",
        ),
        Verdict(
            "speed-up over full resolution" + setting,
            speed >= SPEEDUP,
            f"{speed:.1f}x ({lod_m['frame_ms']:.1f} vs {ref['frame_ms']:.1f} ms)",
            f">= {SPEEDUP:g}x",
        ),
        Verdict(
            "max screen-space error" + setting,
            s["max_sse_px"] <= tau + 1e-6,
            f"{s['max_sse_px']:.2f} px",
            f"<= tau = {tau:g} px",
        ),
    ]
