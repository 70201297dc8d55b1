"""The papers' experiments on one view, for every LOD provider.

1. Triangles and frame rate against the screen-space threshold tau (Wang thesis fig. 7.2).
2. Image RMS error against a full-resolution render of the same view, against frame rate
   (thesis fig. 7.4), with each provider's own measured max screen-space error.
3. Full resolution vs view-frustum culled vs adaptive LOD: triangles and frame time (TREND
   table 1).

"Full resolution" here is `chunked-sse` with tau = FULL_RES_TAU px, texel_px 0.5 and a 1400-tile
budget (soft) in a 2048-slot pool: every visible tile at the finest level the data has (its figures
are measured). It is frustum- and horizon-culled, so it is TREND's "view-frustum culled" row.
TREND's first row, the whole DEM at full resolution without culling, cannot be drawn by this
renderer (it needs more tile slots than GL allows in one texture array): its triangles are
counted exactly and its frame time is *estimated* from the culled render's milliseconds per
triangle (marked "est.").

Outputs (in ``out``): ``tau_sweep.csv``, ``table1.csv``, ``fig_tau.png``, ``fig_rms.png``,
``report.md``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from globeview.bench.flight import Flight, Pose
from globeview.bench.harness import (
    FULL_RES_CAPACITY,
    FULL_RES_POOL,
    FULL_RES_TAU,
    Bench,
    machine,
    write_csv,
)

TAUS = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)
QUICK_TAUS = (1.0, 4.0)
LOD_TAU = 2.0


@dataclass
class Point:
    """One (provider, tau) measurement."""

    provider: str
    tau_px: float
    triangles: int
    tiles: int
    frame_ms: float
    fps: float
    lod_ms: float
    draw_ms: float
    max_sse_px: float
    rms_error: float


def rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS difference of two RGB uint8 images in grey levels (0..255)."""
    d = a.astype(np.float64) - b.astype(np.float64)
    return float(np.sqrt(np.mean(d * d)))


def measure(bench: Bench, pose: Pose, frames: int) -> tuple[dict, np.ndarray]:
    """Time ``frames`` fresh selections + draws of one view (`Bench.measure`, after a
    warm-up frame that uploads the tiles) and return medians and the frame's image."""
    m = bench.measure(pose, frames, reset_lod=True)
    img = bench.target.read_rgb()
    med = m["frame_ms"]
    fps = 1e3 / med if med > 0 else math.inf
    return {"frame_ms": med, "fps": fps, **{k: v for k, v in m.items() if k != "frame_ms"}}, img


def full_resolution(bench: Bench, pose: Pose, frames: int) -> tuple[dict, np.ndarray]:
    """The reference render (module docstring), measured like any other point."""
    bench.grow_pool(FULL_RES_POOL)
    bench.use("chunked-sse", FULL_RES_TAU, texel_px=0.5, max_tiles=FULL_RES_CAPACITY)
    m, img = measure(bench, pose, frames)
    m["budget_limited"] = m["tiles"] >= FULL_RES_CAPACITY
    return m, img


def uncut_full_resolution(bench: Bench, pose: Pose) -> dict:
    """TREND's 'full resolution' row: every finest-level tile of the DEM under the view (the
    topmost visible layer whose footprint holds the view point) at stride 1, without culling:
    exact triangle count (no render)."""
    from globeview.lod.tile_indices import IndexVariant
    from globeview.terrain.quadtree import tile_bounds_arrays

    layers = bench.terrain.visible_layers
    under = [
        ly
        for ly in layers
        if ly.store.bounds[0] <= pose.lon <= ly.store.bounds[2]
        and ly.store.bounds[1] <= pose.lat <= ly.store.bounds[3]
    ]
    layer = (under or layers)[-1]
    st = layer.store
    level = int(st.max_level)
    w, s, e, n = (float(v) for v in st.bounds)
    step = 180.0 / 2**level
    x = np.arange(math.floor((w + 180.0) / step), math.ceil((e + 180.0) / step))
    y = np.arange(math.floor((90.0 - n) / step), math.ceil((90.0 - s) / step))
    xx, yy = np.meshgrid(x, y)
    tw, ts, te, tn = tile_bounds_arrays(level, xx.ravel(), yy.ravel())
    tiles = int(np.count_nonzero((te > w) & (tw < e) & (tn > s) & (ts < n)))
    _, count = bench.session.renderer.indices.get(IndexVariant(stride=1))
    return {"layer": layer.name, "level": level, "tiles": tiles, "triangles": tiles * count // 3}


def plot(points: list[Point], ref: dict, out: Path, title: str) -> list[Path]:
    """fig_tau.png (triangles and fps vs tau) and fig_rms.png (RMS error vs fps / tau)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        from globeview.errors import GlobeviewError

        raise GlobeviewError(
            "plots need matplotlib: pip install 'globeview[bench]' (or matplotlib)"
        ) from None
    provs = sorted({p.provider for p in points})
    paths = []
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.4), dpi=80)
    for name in provs:
        pts = sorted((p for p in points if p.provider == name), key=lambda p: p.tau_px)
        taus = [p.tau_px for p in pts]
        a1.plot(taus, [p.triangles for p in pts], "o-", label=name, ms=3)
        a2.plot(taus, [p.fps for p in pts], "o-", label=name, ms=3)
    a1.axhline(ref["triangles"], color="k", ls=":", lw=1, label=f"full res (tau {FULL_RES_TAU})")
    a2.axhline(ref["fps"], color="k", ls=":", lw=1)
    for ax, yl in ((a1, "triangles"), (a2, "frames / s")):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("tau (px)")
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
    a1.set_yscale("log")
    a1.legend(fontsize=7)
    fig.suptitle(f"Triangles and frame rate vs tau (cf. Wang fig. 7.2) - {title}", fontsize=9)
    fig.tight_layout()
    paths.append(out / "fig_tau.png")
    fig.savefig(paths[-1])
    plt.close(fig)

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.4), dpi=80)
    for name in provs:
        pts = sorted((p for p in points if p.provider == name), key=lambda p: p.tau_px)
        a1.plot([p.fps for p in pts], [p.rms_error for p in pts], "o-", label=name, ms=3)
        a2.plot([p.tau_px for p in pts], [p.rms_error for p in pts], "o-", label=name, ms=3)
    a1.set_xlabel("frames / s")
    a2.set_xlabel("tau (px)")
    a2.set_xscale("log", base=2)
    for ax in (a1, a2):
        ax.set_ylabel("image RMS error (grey levels)")
        ax.grid(alpha=0.3)
    a1.legend(fontsize=7)
    fig.suptitle(f"Image RMS error vs full resolution (cf. Wang fig. 7.4) - {title}", fontsize=9)
    fig.tight_layout()
    paths.append(out / "fig_rms.png")
    fig.savefig(paths[-1])
    plt.close(fig)
    return paths


def run_experiments(
    bench: Bench,
    pose: Pose,
    out: Path,
    taus: tuple[float, ...] = TAUS,
    frames: int = 3,
    view_name: str = "view",
    providers: list[str] | None = None,
    log: Callable[[str], object] = print,
) -> dict:
    """Run the three experiments on one view; write CSV, PNG and Markdown into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    providers = providers or bench.providers()
    t_start = time.perf_counter()
    log(f"full-resolution reference (chunked-sse, tau {FULL_RES_TAU} px) ...")
    ref, ref_img = full_resolution(bench, pose, frames)
    log(
        f"  {ref['triangles']} triangles, {ref['tiles']} tiles, {ref['frame_ms']:.1f} ms"
        + (" (tile budget reached)" if ref["budget_limited"] else "")
    )
    points: list[Point] = []
    for name in providers:
        for tau in taus:
            bench.use(name, tau)
            m, img = measure(bench, pose, frames)
            p = Point(
                provider=name,
                tau_px=tau,
                triangles=m["triangles"],
                tiles=m["tiles"],
                frame_ms=m["frame_ms"],
                fps=m["fps"],
                lod_ms=m["lod_ms"],
                draw_ms=m["draw_ms"],
                max_sse_px=m["max_sse_px"],
                rms_error=rms(img, ref_img),
            )
            points.append(p)
            log(
                f"  {name:16s} tau {tau:5.2f}: {p.triangles:8d} tris {p.frame_ms:8.1f} ms "
                f"lod {p.lod_ms:6.2f} ms  sse {p.max_sse_px:6.2f} px  rms {p.rms_error:5.2f}"
            )
    uncut = uncut_full_resolution(bench, pose)
    ms_per_tri = ref["frame_ms"] / max(ref["triangles"], 1)
    uncut["frame_ms_est"] = uncut["triangles"] * ms_per_tri
    table1 = [
        {
            "row": f"full resolution, no culling ({uncut['layer']} level {uncut['level']})",
            "provider": "-",
            "triangles": uncut["triangles"],
            "frame_ms": round(uncut["frame_ms_est"], 1),
            "measured": "est.",
        },
        {
            "row": f"view-frustum culled, full resolution (tau {FULL_RES_TAU} px)",
            "provider": "chunked-sse",
            "triangles": ref["triangles"],
            "frame_ms": round(ref["frame_ms"], 1),
            "measured": "yes",
        },
    ]
    lod_tau = LOD_TAU if LOD_TAU in taus else taus[len(taus) // 2]
    for p in points:
        if p.tau_px == lod_tau:
            table1.append(
                {
                    "row": f"adaptive LOD (tau {lod_tau:g} px)",
                    "provider": p.provider,
                    "triangles": p.triangles,
                    "frame_ms": round(p.frame_ms, 1),
                    "measured": "yes",
                }
            )
    write_csv(points, out / "tau_sweep.csv")
    write_csv(table1, out / "table1.csv")
    title = f"{view_name}, {bench.size[0]}x{bench.size[1]}"
    pngs = plot(points, ref, out, title)
    md = report(bench, pose, view_name, ref, points, table1, lod_tau, time.perf_counter() - t_start)
    (out / "report.md").write_text(md)
    return {"points": points, "reference": ref, "table1": table1, "files": [*pngs]}


def report(
    bench: Bench,
    pose: Pose,
    view_name: str,
    ref: dict,
    points: list[Point],
    table1: list[dict],
    lod_tau: float,
    seconds: float,
) -> str:
    """The Markdown report of a run."""
    lines = [
        "# globeview bench experiments",
        "",
        f"- machine: {machine(bench.gl_renderer)}",
        f"- view: {view_name}: lon {pose.lon:.3f}, lat {pose.lat:.3f}, height {pose.height:.0f} m, "
        f"heading {pose.heading:.0f}, pitch {pose.pitch:.0f}; {bench.size[0]}x{bench.size[1]} px",
        f"- full-resolution reference: chunked-sse, tau {FULL_RES_TAU} px, texel 0.5 px: "
        f"{ref['triangles']} triangles in {ref['tiles']} tiles, {ref['frame_ms']:.1f} ms"
        + (" (tile budget reached: not quite full resolution)" if ref["budget_limited"] else ""),
        "- frame_ms: median wall time of render() (selection + upload + draw + glFinish) over "
        "frames that each select afresh, after a warm-up frame; RMS error in grey levels "
        "(0-255) of the RGB image against the reference",
        f"- run time {seconds:.0f} s",
        "",
        "## Full resolution vs view-frustum culled vs adaptive LOD (cf. TREND table 1)",
        "",
        "| configuration | provider | triangles | frame ms | fps | measured |",
        "|---|---|---:|---:|---:|---|",
    ]
    for r in table1:
        fps = 1e3 / r["frame_ms"] if r["frame_ms"] else math.inf
        lines.append(
            f"| {r['row']} | {r['provider']} | {r['triangles']:,} | {r['frame_ms']:.1f} | "
            f"{fps:.2f} | {r['measured']} |"
        )
    lines += [
        "",
        "## tau sweep (cf. Wang fig. 7.2 and 7.4)",
        "",
        "| provider | tau px | triangles | tiles | frame ms | fps | lod ms | max SSE px | "
        "RMS error |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for p in points:
        lines.append(
            f"| {p.provider} | {p.tau_px:g} | {p.triangles:,} | {p.tiles} | {p.frame_ms:.1f} | "
            f"{p.fps:.2f} | {p.lod_ms:.2f} | {p.max_sse_px:.2f} | {p.rms_error:.2f} |"
        )
    lines += [
        "",
        "Providers that do not use tau (`fixed-level`, drawing one quadtree level) give flat "
        "lines; `distance-regions` (Rishe) uses distance rings, not tau, so its reported SSE "
        "may exceed tau.",
        "",
        "![triangles and fps vs tau](fig_tau.png)",
        "",
        "![RMS error vs fps](fig_rms.png)",
        "",
    ]
    return "\n".join(lines)


def standard_view(flight: Flight, t: float | None = None) -> Pose:
    """The experiments' view: a flight's pose at ``t`` (default: the middle)."""
    return flight.pose(flight.t[0] + flight.duration / 2 if t is None else t)
