"""The one benchmark harness: a headless session, its frames through the `FramePipeline`
(`GlobeSession.render`, as the window draws them) and their figures. `globeview bench`, the
benchmarks/ scripts and the soak all measure through here.

Time stamps: `fly` hands each frame its flight time (``now_s``), so the pipeline derives the
camera speed from the flight (the distance-regions provider uses it); `Bench.set_pose` moves
the camera in place (a move), ``cut=True`` starts a new shot (speed 0).
"""

from __future__ import annotations

import csv
import math
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from globeview.bench.flight import Flight, Pose
from globeview.errors import GlobeviewError

if TYPE_CHECKING:
    import moderngl

    from globeview.render.frame_pipeline import FrameResult
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.store.tile_store import TileStore

ROOT = Path(__file__).resolve().parents[2]
BIG_DEM_SIZE = 8192
#: "Full resolution" reference: chunked-sse with this tau (px) and the largest tile budget.
FULL_RES_TAU = 0.05
FULL_RES_CAPACITY = 1400  # chunked-sse's budget is soft (overshoots ~50%); the pool holds 2048
FULL_RES_POOL = 2048  # GL_MAX_ARRAY_TEXTURE_LAYERS on Mesa
PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_mb() -> float:
    """Resident set size of this process in MB (/proc/self/statm, no psutil)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * PAGE / 1e6
    except OSError:
        return float("nan")


def big_dem_store(size: int = BIG_DEM_SIZE, progress: bool = True) -> TileStore:
    """The tile store of the synthetic-detail benchmark DEM (benchmarks/make_big_dem.py),
    generating and ingesting it under benchmarks/cache/ the first time."""
    from globeview.terrain.store.identify import identify
    from globeview.terrain.store.tile_store import TileStore

    cache = ROOT / "benchmarks" / "cache"
    store = cache / f"store_{size}"
    if identify(store).is_current:  # a store of an older format is rebuilt below
        return TileStore.open(store)
    script = ROOT / "benchmarks" / "make_big_dem.py"
    if not script.exists():
        raise GlobeviewError(
            "the benchmark DEM needs benchmarks/make_big_dem.py (run from a source checkout)"
        )
    sys.path.insert(0, str(script.parent))
    try:
        from make_big_dem import make  # type: ignore[import-not-found]
    finally:
        sys.path.pop(0)
    from globeview.terrain.ingest.driver import ingest

    if progress:
        print(f"generating the {size}x{size} benchmark DEM (synthetic detail) ...", flush=True)
    src = make(size, quiet=not progress)
    ingest([src], store, progress=progress, force=True)  # the bench's own cache
    return TileStore.open(store)


def load_terrain(kind: str = "embedded", big_size: int = BIG_DEM_SIZE) -> TerrainStack:
    """The TerrainStack of a flight: the embedded DEMs, plus the big DEM for ``big-dem``."""
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores

    stores = embedded_stores()
    if kind == "big-dem":
        stores = [*stores, big_dem_store(big_size)]
    return TerrainStack.from_stores(stores)


class Bench:
    """A headless GL context, an offscreen target and a plugin session on some terrain.

    The registry uses in-memory settings: every provider starts from its defaults and the
    user's saved plugin settings are neither read nor written.
    """

    def __init__(
        self,
        terrain: TerrainStack,
        size: tuple[int, int],
        lod: str = "chunked-sse",
        ctx: moderngl.Context | None = None,
    ) -> None:
        from globeview.app.session import GlobeSession
        from globeview.plugins.registry import PluginRegistry
        from globeview.plugins.settings import MemorySettings
        from globeview.render.offscreen import OffscreenTarget, create_headless_context

        self._own_ctx = ctx is None  # a context handed in is the caller's to release
        self.ctx = create_headless_context() if ctx is None else ctx
        self.size = (int(size[0]), int(size[1]))
        self.target = OffscreenTarget(self.ctx, self.size)
        registry = PluginRegistry(MemorySettings())
        registry.discover()
        self.session = GlobeSession(self.ctx, terrain, registry=registry, lod=lod)
        self.terrain = terrain

    @property
    def gl_renderer(self) -> str:
        return str(self.ctx.info.get("GL_RENDERER", "?"))

    def providers(self) -> list[str]:
        return sorted(self.session.lod_providers())

    def use(self, lod: str, tau: float, **settings: object) -> None:
        """Make ``lod`` active with threshold ``tau`` and the given settings (others default)."""
        s = self.session
        s.set_lod(lod)
        s.tau_px = float(tau)
        prov = s.lod_providers()[lod]
        values = {st.name: st.default for st in prov.settings}
        values.update({k: v for k, v in settings.items() if k in values})
        s.registry.invoke(prov, "configure", values)
        s.reset_lod()

    def set_pose(self, pose: Pose | tuple, cut: bool = False) -> None:
        """Move the camera to ``pose`` (lon, lat, height, heading, pitch) in place: the next
        frame's speed is the move over the time between the frames' stamps. ``cut``: a new
        shot instead, the next frame's speed is 0."""
        p = pose.as_tuple() if isinstance(pose, Pose) else tuple(pose)
        self.session.camera.set_lonlat(*p)
        if cut:
            self.session.pipeline.motion.reset()

    def frame(self, now_s: float | None = None) -> tuple[FrameResult, float]:
        """Render one frame at time ``now_s`` (seconds; default the monotonic clock);
        returns (FrameResult, wall milliseconds around render())."""
        t0 = time.perf_counter()
        r = self.session.render(self.target.fbo, self.size, now_s)
        return r, (time.perf_counter() - t0) * 1e3

    def measure(
        self, pose: Pose | tuple, frames: int, turn_deg: float = 0.0, reset_lod: bool = False
    ) -> dict[str, float]:
        """Medians of ``frames`` timed frames of one view, after a warm-up frame that
        uploads its tiles. ``turn_deg``: a yaw this small, alternating, before each frame so
        every frame really selects and draws; ``reset_lod``: the provider forgets its
        per-view cache before each frame (a fresh selection). Keys: frame_ms (wall time of
        render(): selection, upload, draw, overlays, glFinish), lod_ms, draw_ms, triangles,
        tiles (medians) and max_sse_px (the worst)."""
        self.set_pose(pose, cut=True)
        if reset_lod:
            self.session.reset_lod()
        self.frame()  # uploads the tiles
        rows = []
        for i in range(max(int(frames), 1)):
            if turn_deg:
                self.session.camera.fly_yaw(turn_deg * (-1) ** i)
            if reset_lod:
                self.session.reset_lod()
            r, ms = self.frame()
            st = r.stats
            rows.append((ms, st.lod_ms, st.draw_ms, st.triangles, st.tiles_drawn, st.max_sse_px))
        med = statistics.median
        cols = list(zip(*rows, strict=True))
        return {
            "frame_ms": med(cols[0]),
            "lod_ms": med(cols[1]),
            "draw_ms": med(cols[2]),
            "triangles": int(med(cols[3])),
            "tiles": int(med(cols[4])),
            "max_sse_px": max(cols[5]),
        }

    def grow_pool(self, capacity: int) -> None:
        """Replace the renderer by one with ``capacity`` tile slots (for full-resolution
        references that draw more tiles than the interactive pool holds)."""
        from globeview.render.renderer import GlobeRenderer

        s = self.session
        if s.renderer.pool.capacity >= capacity:
            return
        old = s.renderer
        settings = old.settings
        s.renderer = GlobeRenderer(self.ctx, self.terrain, capacity=capacity)
        s.renderer.settings = settings
        old.release()  # its tile pool (~100 MB of GPU memory) would outlive it otherwise

    def gl_objects(self) -> dict[str, int]:
        """The GL objects alive in the bench's context, by kind, as the one tracker counts
        them (`globeview.render.gpu_objects`: everything the renderer, pools, overlays and
        targets made and did not release), plus the resident tile count."""
        from globeview.render.gpu_objects import gpu_objects

        by_kind = gpu_objects(self.ctx).counts()
        groups = {
            "buffers": ("buffer",),
            "textures": ("texture", "texture_array", "depth_texture"),
            "vaos": ("vertex_array",),
            "programs": ("program",),
            "framebuffers": ("framebuffer", "renderbuffer"),
        }
        counts = {name: sum(by_kind.get(k, 0) for k in kinds) for name, kinds in groups.items()}
        counts["resident_tiles"] = self.session.renderer.pool.resident_count
        return counts

    def release(self) -> None:
        """Release the session's GL objects, the target and (when the bench made it) the
        context."""
        self.session.release_gl()
        self.target.release()
        if self._own_ctx:
            self.ctx.release()


@dataclass
class FrameRecord:
    """Figures of one flight frame (one CSV row)."""

    frame: int
    t: float
    lon: float
    lat: float
    height: float
    heading: float
    pitch: float
    speed_mps: float
    frame_ms: float
    lod_ms: float
    draw_ms: float
    triangles: int
    tiles_drawn: int
    tiles_culled_frustum: int
    tiles_culled_horizon: int
    tiles_loading: int
    tiles_uploaded: int
    max_sse_px: float
    resident_tiles: int
    rss_mb: float


CSV_COLUMNS = [f.name for f in fields(FrameRecord)]


def fly(bench: Bench, flight: Flight, times: np.ndarray, warm: bool = True) -> list[FrameRecord]:
    """Render the flight at ``times`` (seconds of flight time, each frame's time stamp: the
    pipeline derives the camera speed from them); with ``warm`` the first pose is rendered
    once before (uploads its tiles) so frame 0 measures drawing, not the first load."""
    out: list[FrameRecord] = []
    if warm and len(times):
        bench.set_pose(flight.pose(float(times[0])), cut=True)
        bench.frame(float(times[0]))
        bench.session.reset_lod()
    motion = bench.session.pipeline.motion
    motion.reset()  # the flight starts at rest
    # Sparse samples of a flight are not pauses: the camera flies on between them.
    pause_s, motion.pause_s = motion.pause_s, math.inf
    try:
        return _fly(bench, flight, times, out)
    finally:
        motion.pause_s = pause_s


def _fly(bench: Bench, flight: Flight, times: np.ndarray, out: list) -> list[FrameRecord]:
    for i, t in enumerate(times):
        pose = flight.pose(float(t))
        bench.set_pose(pose)
        r, wall = bench.frame(float(t))
        out.append(FrameRecord(**frame_fields(bench, i, float(t), pose, r, wall)))
    return out


def frame_fields(
    bench: Bench, i: int, t: float, pose: Pose, result: FrameResult, frame_ms: float
) -> dict[str, Any]:
    """`FrameRecord`'s fields for frame ``i`` at ``t`` seconds of a flight (``pose``: where the
    camera was; ``frame_ms``: the frame's wall time), for it and the records that extend it."""
    st = result.stats
    return dict(
        frame=i,
        t=round(t, 4),
        lon=pose.lon,
        lat=pose.lat,
        height=pose.height,
        heading=pose.heading,
        pitch=pose.pitch,
        speed_mps=result.view.speed_mps,
        frame_ms=frame_ms,
        lod_ms=st.lod_ms,
        draw_ms=st.draw_ms,
        triangles=st.triangles,
        tiles_drawn=st.tiles_drawn,
        tiles_culled_frustum=st.tiles_culled_frustum,
        tiles_culled_horizon=st.tiles_culled_horizon,
        tiles_loading=st.tiles_loading,
        tiles_uploaded=st.tiles_uploaded,
        max_sse_px=st.max_sse_px,
        resident_tiles=bench.session.renderer.pool.resident_count,
        rss_mb=rss_mb(),
    )


def write_csv(rows: list, path: str | Path, columns: list[str] | None = None) -> Path:
    """Write dataclass rows (or dicts) as CSV with a header; returns the path."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    dicts = [asdict(r) if hasattr(r, "__dataclass_fields__") else dict(r) for r in rows]
    cols = columns or (list(dicts[0]) if dicts else CSV_COLUMNS)
    with p.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for d in dicts:
            w.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in d.items()})
    return p


def summary(rows: list[FrameRecord]) -> dict[str, float]:
    """Medians (and worst cases) of a flight."""
    if not rows:
        return {}
    fm = [r.frame_ms for r in rows]
    return {
        "frames": len(rows),
        "frame_ms_median": statistics.median(fm),
        "frame_ms_p95": float(np.percentile(fm, 95)),
        "fps_median": 1e3 / statistics.median(fm),
        "lod_ms_median": statistics.median(r.lod_ms for r in rows),
        "draw_ms_median": statistics.median(r.draw_ms for r in rows),
        "triangles_median": statistics.median(r.triangles for r in rows),
        "tiles_median": statistics.median(r.tiles_drawn for r in rows),
        "max_sse_px": max(r.max_sse_px for r in rows),
        "rss_mb_last": rows[-1].rss_mb,
    }


def machine(gl_renderer: str) -> str:
    """One line describing the machine: CPU, cores usable, GL renderer, Python, date."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return (
        f"{cpu}, {cores} cores usable, GL renderer {gl_renderer}, Python "
        f"{platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M %Z')}"
    )


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise GlobeviewError(f"--size must look like 1280x720, not {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise GlobeviewError(f"--size {text} is out of range (16..8192 pixels a side)")
    return w, h
