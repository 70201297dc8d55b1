"""Incremental update of a store when source files change: rebuild only what they touch.

When a store is re-ingested with the same source paths and parameters but some sources'
content changed (size or sha256), only these tasks of the ingest graph run again:

- a chunk whose window reads a changed source, with its old or its new footprint and level
  (the same test `tasks.fill_from_sources` uses to decide whether to read a source:
  footprint within a node spacing and a pixel of the window; the bilinear reprojection and
  the ring a data edge is continued over reach no further), or whose pole row takes a pole
  height that changed;
- every task that depends on a rebuilt chunk (the coarser chunks whose wavelet halo reads it,
  the last chunk of its row on a level that goes all the way round, the error windows that
  read it): the graph's own dependencies, followed transitively up the pyramid.

Every other chunk file is hard-linked (copied where links fail) from the old store into the
building folder, after its sha256 is checked against the old manifest, and its per-tile
statistics, and the per-tile maxima of its error window, come from its sidecar
``facts/LL/<cy>/<cx>.npz`` (exact float64, which the manifest's rounded values are not) in
the store's generation's facts folder (`layout.facts_root`). The tasks are deterministic, so
the result equals a full rebuild bit for bit. The building folder is then committed as the
store's next generation, beside the files readers of this one have open
(`terrain.store.generations.commit_generation`).

A change the update cannot follow (other levels or extents, another chunk size, a source
whose level changed, a missing or damaged sidecar or chunk) falls back to a full build.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from globeview.terrain.ingest.schedule import Graph
from globeview.terrain.ingest.tasks import (
    STRIDES,
    BuildPlan,
    ChunkResult,
    SourceSpec,
    fill_reads_source,
)
from globeview.terrain.store.layout import (
    chunk_file_name,
    chunk_tiles,
    facts_file_name,
    facts_root,
)
from globeview.terrain.store.schema import StoreManifest

__all__ = ["Update", "facts_name", "plan_update", "write_facts"]

# Sidecar format (a pickle-free npz): bump when its arrays change meaning.
_FACTS_VERSION = 3  # 2: store format 7 (global chunk grid, the chunk file's size); 3: the
# ranges over the stored nodes (`ChunkResult.stored`)


def facts_name(lv: int, cy: int, cx: int) -> str:
    """The sidecar of chunk (cy, cx) of level lv (`layout.facts_file_name`)."""
    return facts_file_name(lv, cy, cx)


def write_facts(
    folder: Path,
    chunk: ChunkResult,
    errors: Sequence[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
    source_levels: Sequence[int],
) -> None:
    """Write a chunk's build facts: its ChunkResult, its error window's per-tile maxima
    (empty for level 0) and the level of every source (in the order given)."""
    lvs = [np.full(len(iy), lv, dtype=np.int64) for lv, iy, _, _ in errors]
    cat = lambda parts, dt: np.concatenate(parts).astype(dt) if parts else np.zeros(0, dt)  # noqa: E731
    arrays = {
        "version": np.array(_FACTS_VERSION),
        "hmin": chunk.hmin,
        "hmax": chunk.hmax,
        "stride_delta": chunk.stride_delta,
        "sha256": np.array(chunk.sha256 or ""),
        "bytes": np.array(chunk.bytes, dtype=np.int64),
        "flags": np.array(chunk.flags, dtype=np.int64),
        "first_col": chunk.first_col if chunk.first_col is not None else np.zeros(0, np.float32),
        "has_first": np.array(chunk.first_col is not None),
        "has_stored": np.array(chunk.stored is not None),
        **_stored_arrays(chunk),
        "err_level": cat(lvs, np.int64),
        "err_iy": cat([e[1] for e in errors], np.int64),
        "err_ix": cat([e[2] for e in errors], np.int64),
        "err_max": cat([e[3] for e in errors], np.float64),
        "source_levels": np.array(list(source_levels), dtype=np.int64),
    }
    path = folder / facts_name(chunk.level, chunk.cy, chunk.cx)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)  # a new inode (never write into a linked old sidecar)
    # np.savez stamps each member with the time; fixed stamps make the same facts the same
    # bytes (a rebuilt store equals an updated one file for file).
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        for name, a in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(a), allow_pickle=False)


def _stored_arrays(chunk: ChunkResult) -> dict[str, np.ndarray]:
    """The facts' arrays of ``chunk.stored`` (empty when None)."""
    empty = np.zeros(0, np.float32)
    lo, hi, edges = chunk.stored if chunk.stored is not None else (empty, empty, empty)
    return {"stored_hmin": lo, "stored_hmax": hi, "stored_edges": edges}


def _read_facts(
    folder: Path, lv: int, cy: int, cx: int, plan: BuildPlan | None = None
) -> tuple[ChunkResult, list[tuple[int, np.ndarray, np.ndarray, np.ndarray]], np.ndarray | None]:
    """A chunk's facts; with ``plan``, a chunk without a facts file is one without data or
    error maxima (none is written for those: a store over a large extent holds few), its
    levels unknown (None)."""
    path = folder / facts_name(lv, cy, cx)
    if plan is not None and not path.exists():
        _, _, kty, ktx = plan.window(lv, cy, cx)
        nan = np.full((kty, ktx), np.nan)
        empty = ChunkResult(lv, cy, cx, nan, nan.copy(), np.zeros((kty, ktx, len(STRIDES))), None)
        return empty, [], None
    with np.load(path, allow_pickle=False) as z:
        if int(z["version"]) != _FACTS_VERSION:
            raise ValueError("sidecar of another version")
        sha = str(z["sha256"])
        chunk = ChunkResult(
            lv,
            cy,
            cx,
            z["hmin"],
            z["hmax"],
            z["stride_delta"],
            sha or None,
            z["first_col"] if bool(z["has_first"]) else None,
            int(z["bytes"]),
            int(z["flags"]),
            (z["stored_hmin"], z["stored_hmax"], z["stored_edges"])
            if bool(z["has_stored"])
            else None,
        )
        levels, iy, ix, red = z["err_level"], z["err_iy"], z["err_ix"], z["err_max"]
        errors = [
            (int(v), iy[levels == v], ix[levels == v], red[levels == v]) for v in np.unique(levels)
        ]
        return chunk, errors, z["source_levels"]


@dataclass
class Update:
    """An incremental update: the results kept (by graph key), how many chunks are rebuilt."""

    known: dict[str, Any]
    rebuilt: int
    total: int


@dataclass(frozen=True)
class _Footprint:
    level: int
    bounds: tuple[float, float, float, float]
    wraps: bool
    res: float  # pixel size, degrees (the larger axis)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _link(src: Path, dst: Path) -> None:
    """Hard link (the files of a store are never modified in place), else a copy."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def plan_update(
    old: Path,
    manifest: StoreManifest,
    plan: BuildPlan,
    specs: Sequence[SourceSpec],
    input_order: Sequence[int],
    changed: Sequence[int],
    graph: Graph,
    pole: dict[str, float | None],
) -> Update | None:
    """Decide what to rebuild and hard-link the rest into the building folder; None when
    the change cannot be followed (then build everything).

    ``specs`` are in the build's order (finest first); ``input_order[i]`` is the index in
    ``specs`` of the i-th source as given; ``changed``: indices (as given) of the sources
    whose content changed; ``pole``: the new pole heights.
    """
    if not _same_layout(manifest, plan):
        return None
    facts_dir = old / facts_root(manifest.generation)  # this generation's facts
    read = _old_facts(facts_dir, graph, input_order, plan)
    if read is None:
        return None
    facts, old_levels = read
    new_levels = [specs[j].level for j in input_order]
    changed_set = set(changed)
    if any(
        int(old_levels[i]) != new_levels[i] for i in range(len(new_levels)) if i not in changed_set
    ):
        return None  # an unchanged source now fills other levels: the plan is not the same
    feet = _changed_footprints(manifest, specs, input_order, changed, old_levels)
    old_pole = manifest.pole_heights.as_dict() if manifest.pole_heights else {}
    pole_changed = any(old_pole.get(k) != pole.get(k) for k in ("north", "south"))
    dirty = _dirty_keys(plan, graph, feet, pole_changed)
    kept = _keep_clean(old, facts_dir, Path(plan.folder), graph, facts, dirty)
    if kept is None:
        return None  # the old store is damaged (or cannot be linked): build everything
    known: dict[str, Any] = {"pole": pole, **kept}
    for key in graph.error_keys:
        if key not in dirty:
            known[key] = facts[key.replace("error-", "chunk-", 1)][1]
    n_chunks = len(graph.chunk_keys)
    return Update(known, sum(1 for k in dirty if k.startswith("chunk-")), n_chunks)


def _same_layout(manifest: StoreManifest, plan: BuildPlan) -> bool:
    """Whether the old store has the new plan's levels and chunk size (format 7's chunk grid
    is global: the same chunk is the same place; which chunks exist is the facts' business)."""
    return (
        len(manifest.levels) == plan.max_level + 1
        and manifest.tile_n == plan.tile_n
        and manifest.chunk_tiles == chunk_tiles(plan.tile_n)
    )


def _old_facts(
    old: Path, graph: Graph, input_order: Sequence[int], plan: BuildPlan
) -> tuple[dict[str, tuple[ChunkResult, list]], np.ndarray] | None:
    """The facts of every chunk of the old store (small), and the levels its sources had;
    None when a sidecar is damaged, none is readable, or the sources were not as many."""
    facts: dict[str, tuple[ChunkResult, list]] = {}
    old_levels: np.ndarray | None = None
    try:
        for key in graph.chunk_keys:
            chunk, errors, levels = _read_facts(old, *_indices(key), plan)
            facts[key] = (chunk, errors)
            old_levels = levels if levels is not None else old_levels
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):
        return None
    if old_levels is None or len(old_levels) != len(input_order):
        return None
    return facts, old_levels


def _changed_footprints(
    manifest: StoreManifest,
    specs: Sequence[SourceSpec],
    input_order: Sequence[int],
    changed: Sequence[int],
    old_levels: np.ndarray,
) -> list[_Footprint]:
    """Where each changed source was (the old manifest's record) and is now: a chunk that
    read either place is dirty."""
    feet: list[_Footprint] = []
    for i in changed:
        spec = specs[input_order[i]]
        west, south, east, north = (float(v) for v in manifest.sources[i].bounds)
        old_wraps = spec.wraps or (east - west) >= 360.0 - 1e-9
        old_res = float(max(manifest.sources[i].res_deg))
        feet.append(_Footprint(int(old_levels[i]), (west, south, east, north), old_wraps, old_res))
        feet.append(_Footprint(spec.level, spec.bounds, spec.wraps, spec.res))
    return feet


def _dirty_keys(
    plan: BuildPlan, graph: Graph, feet: Sequence[_Footprint], pole_changed: bool
) -> set[str]:
    """The graph's tasks to run again: chunks that read a changed source, or depend on a
    dirty chunk (or on the pole heights, when they changed); error windows over dirty
    chunks."""
    dirty: set[str] = set()
    for key in graph.chunk_keys:  # finest first: a chunk's dependencies come before it
        deps = graph.deps[key]
        if (
            any(d in dirty for d in deps if d != "pole")
            or (pole_changed and "pole" in deps)
            or _reads_a_changed_source(plan, *_indices(key), feet)
        ):
            dirty.add(key)
    for key in graph.error_keys:
        if any(d in dirty for d in graph.deps[key]):
            dirty.add(key)
    return dirty


def _keep_clean(
    old: Path,
    facts_dir: Path,
    folder: Path,
    graph: Graph,
    facts: dict[str, tuple[ChunkResult, list]],
    dirty: set[str],
) -> dict[str, Any] | None:
    """Keep the chunks that are not dirty: check each kept chunk file against the old
    manifest, then link it and its sidecar (from ``facts_dir``, the store's generation's
    facts folder) into the building folder (a rebuilt chunk's
    tasks read its neighbours); their results by graph key. None when a kept file does not
    match (the old store is damaged) or cannot be linked."""
    known: dict[str, Any] = {}
    try:
        for key in graph.chunk_keys:
            if key in dirty:
                continue
            kept = facts[key][0]
            at = (kept.level, kept.cy, kept.cx)
            if kept.sha256 is not None:
                name = chunk_file_name(*at, kept.sha256)
                if _sha256(old / name) != kept.sha256:
                    return None
                _link(old / name, folder / name)
            if (facts_dir / facts_name(*at)).exists():
                _link(facts_dir / facts_name(*at), folder / facts_name(*at))
            known[key] = kept
    except OSError:
        return None
    return known


def _indices(key: str) -> tuple[int, int, int]:
    """(level, cy, cx) of a graph key "chunk-L-CY-CX" / "error-L-CY-CX"."""
    _, lv, cy, cx = key.split("-")
    return int(lv), int(cy), int(cx)


def _reads_a_changed_source(
    plan: BuildPlan, lv: int, cy: int, cx: int, feet: Sequence[_Footprint]
) -> bool:
    grid = plan.grids[lv]
    s_n = grid.tile_nodes
    by, bx, kty, ktx = plan.window(lv, cy, cx)
    h, w = kty * s_n + 1, ktx * s_n + 1
    gr0, gc0 = grid.gr0 + by * s_n, grid.gc0 + bx * s_n
    return any(
        f.level <= lv and fill_reads_source(grid, gr0, gc0, h, w, f.bounds, f.wraps, f.res)
        for f in feet
    )
