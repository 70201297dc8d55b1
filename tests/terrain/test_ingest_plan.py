"""Chunk sets from footprints (issue #25, `terrain/ingest/plan.py`): every level's planned
chunks are exactly the chunks whose window the build's own test (`tasks.fill_reads_source`)
says a source reaches, plus the parents of the finer level's; the CSR lists those sources in
fill order; the SRTM-named planet layout counts on a small case; the limit is one line."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from globeview.errors import StoreError
from globeview.terrain.ingest import driver, plan
from globeview.terrain.ingest.footprints import FootprintTable, footprints_from_names
from globeview.terrain.ingest.plan import clamp_levels, plan_chunks
from globeview.terrain.ingest.tasks import fill_reads_source
from globeview.terrain.quadtree import node_spacing
from globeview.terrain.store.layout import (
    chunk_code,
    chunk_grid_shape,
    chunk_levels_c0,
    chunk_nodes,
    decode_chunk_code,
)


def table(rows: list[tuple[float, float, float, float, float]], wraps=None) -> FootprintTable:
    """A FootprintTable of (west, south, east, north, res) rows (res = reach)."""
    a = np.array(rows, dtype=np.float64).reshape(len(rows), 5)
    n = len(rows)
    width = (a[:, 2] - a[:, 0]) % 360.0
    return FootprintTable(
        paths=tuple(f"s{i}" for i in range(n)),
        west=a[:, 0],
        south=a[:, 1],
        east=a[:, 2],
        north=a[:, 3],
        res=a[:, 4],
        reach=a[:, 4],
        extent=np.minimum(np.where(width == 0, 360.0, width), a[:, 3] - a[:, 1]),
        wraps=np.zeros(n, bool) if wraps is None else np.asarray(wraps),
        datum=np.ones(n, np.int8),
        how=np.ones(n, np.int8),
        datum_why=("assumed",) * n,
    )


def brute_force(t: FootprintTable, rows: list[int], level: int, tile_n: int) -> set[int]:
    """Chunks of ``level`` whose closed window fill_reads_source says a source in ``rows``
    reaches, chunk by chunk."""
    c = chunk_nodes(tile_n)
    grid = SimpleNamespace(d=node_spacing(level, tile_n))
    nrows, ncols = chunk_grid_shape(level, tile_n)
    found = set()
    for cy in range(nrows):
        for cx in range(ncols):
            for i in rows:
                b = (t.west[i], t.south[i], t.east[i], t.north[i])
                if fill_reads_source(
                    grid, cy * c, cx * c, c + 1, c + 1, b, bool(t.wraps[i]), t.reach[i]
                ):
                    found.add(int(chunk_code(cy, cx)))
                    break
    return found


def random_footprints(rng: np.random.Generator, n: int) -> list[tuple]:
    rows = []
    for _ in range(n):
        w = float(rng.uniform(-180, 180))
        width = float(rng.choice([0.3, 2.0, 11.0, 47.0]))
        s = float(rng.uniform(-90, 89))
        height = float(min(rng.choice([0.3, 2.0, 11.0, 33.0]), 90 - s))
        e = w + width
        if e >= 180:  # across the antimeridian: west > east
            e -= 360
        rows.append((w, s, e, s + height, float(rng.choice([0.001, 0.01, 0.1, 0.5]))))
    return rows


@pytest.mark.parametrize("tile_n", [8, 10])
def test_chunk_sets_equal_the_builds_own_test_chunk_by_chunk(tile_n: int) -> None:
    """Random footprints (antimeridian and poles included) of several levels: each level's
    set is the brute-force set of the sources of that level or finer plus the finer level's
    parents."""
    rng = np.random.default_rng(25)
    rows = random_footprints(rng, 12)
    rows.append((170.0, -89.5, -175.0, -80.0, 0.1))  # south pole, across the antimeridian
    rows.append((-10.0, 85.0, 10.0, 90.0, 0.1))  # north pole
    t = table(rows)
    max_level = 5
    p = plan_chunks(t, tile_n, max_level)
    assert p.max_level == max_level
    levels, _ = clamp_levels(t.levels(tile_n), max_level)
    assert len(set(levels.tolist())) > 2  # several levels, some below max_level
    finer: set[int] = set()
    for lv in range(max_level, -1, -1):
        want = brute_force(t, np.flatnonzero(levels >= lv).tolist(), lv, tile_n)
        if lv < max_level:
            cy, cx = decode_chunk_code(np.array(sorted(finer), dtype=np.int64))
            if lv < chunk_levels_c0(tile_n):
                want.add(0)
            else:
                want |= {int(v) for v in chunk_code(cy >> 1, cx >> 1)}
        got = p.levels[lv].codes
        assert np.all(np.diff(got) > 0)  # sorted, unique
        assert set(got.tolist()) == want, lv
        finer = set(got.tolist())


def test_coarser_sources_fill_but_add_no_chunks_and_the_csr_is_in_fill_order() -> None:
    """A global base (coarse) under two detail footprints: the fine levels hold only the
    detail's chunks; each lists the base after the finer detail; the base's own level is
    the whole globe."""
    tile_n = 8  # k = 4 tiles, C = 1024 nodes
    base = (-180.0, -90.0, 180.0, 90.0, 0.088)  # level 3
    t = table([base, (10.0, 40.0, 10.5, 40.5, 0.001), (10.2, 40.1, 10.9, 40.6, 0.0005)])
    t = FootprintTable(**{**t.__dict__, "wraps": np.array([True, False, False])})
    p = plan_chunks(t, tile_n)
    levels = t.levels(tile_n)
    assert p.max_level == int(levels.max())
    base_level = int(levels[0])
    assert base_level == 3
    fine = p.levels[p.max_level]
    assert fine.chunks == len(brute_force(t, [2], p.max_level, tile_n))
    for j, code in enumerate(fine.codes.tolist()):
        cy, cx = decode_chunk_code(code)
        srcs = fine.sources_of(int(cy), int(cx)).tolist()
        assert srcs == fine.src_idx[fine.src_ptr[j] : fine.src_ptr[j + 1]].tolist()
        assert srcs[-1] == 0  # the base fills last
        assert srcs == sorted(srcs, key=lambda i: (t.res[i], i))
    whole = chunk_grid_shape(base_level, tile_n)
    assert p.levels[base_level].chunks == whole[0] * whole[1]
    # Below the base's level, nothing reads a source: chunks come from the wavelet.
    assert p.levels[base_level - 1].source_reads == 0
    assert fine.sources_of(10**6, 0).size == 0


def test_levels_are_clamped_as_the_build_clamps_them() -> None:
    natural = np.array([12, 9, 12, 3])
    for max_level in (None, 7, 12, 15):
        got, l_max = clamp_levels(natural, max_level)
        srcs = [SimpleNamespace(level=int(v)) for v in natural]
        assert l_max == driver._clamp_levels(srcs, max_level)
        assert got.tolist() == [s.level for s in srcs]


def srtm_names(cells: list[tuple[int, int]]) -> list[str]:
    return [
        f"{'N' if lat >= 0 else 'S'}{abs(lat):02d}{'E' if lon >= 0 else 'W'}{abs(lon):03d}.hgt"
        for lat, lon in cells
    ]


def test_srtm_named_planet_layout_counts_on_a_small_case() -> None:
    """Four SRTM 1" names (two adjacent cells, one across the antimeridian, one alone): level
    13's chunk count equals the brute force over their name footprints, level 12 holds
    their parents, and the plan's counts agree with the arrays."""
    names = srtm_names([(44, -72), (44, -71), (-17, 179), (-17, -180)])
    t = footprints_from_names(names)
    p = plan_chunks(t, 6)
    assert p.max_level == 13
    assert p.levels[13].chunks == len(brute_force_fast(t, 13, 6))
    assert p.levels[13].source_reads >= p.levels[13].chunks
    cy, cx = decode_chunk_code(p.levels[13].codes)
    assert p.levels[12].codes.tolist() == np.unique(chunk_code(cy >> 1, cx >> 1)).tolist()
    assert p.chunks == sum(lp.chunks for lp in p.levels)
    assert p.levels[0].chunks == 1


def brute_force_fast(t: FootprintTable, level: int, tile_n: int) -> set[int]:
    """brute_force restricted to chunks near each footprint (a level-13 grid is 1024 x 512
    chunks: too many to walk in Python)."""
    c = chunk_nodes(tile_n)
    d = node_spacing(level, tile_n)
    grid = SimpleNamespace(d=d)
    nrows, ncols = chunk_grid_shape(level, tile_n)
    side = c * d
    found = set()
    for i in range(len(t)):
        b = (t.west[i], t.south[i], t.east[i], t.north[i])
        cy_c = int((90 - (t.south[i] + t.north[i]) / 2) / side)
        cx_c = int((t.west[i] + 180) / side)
        for cy in range(max(0, cy_c - 4), min(nrows, cy_c + 5)):
            for dx in range(-4, 8):
                cx = (cx_c + dx) % ncols
                if fill_reads_source(grid, cy * c, cx * c, c + 1, c + 1, b, False, t.reach[i]):
                    found.add(int(chunk_code(cy, cx)))
    return found


def test_a_plan_over_the_limit_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(plan, "PLAN_MAX_CHUNKS", 100)
    t = footprints_from_names(srtm_names([(44, -72)]))
    with pytest.raises(StoreError, match=r"over the limit of 100; use a smaller --max-level"):
        plan_chunks(t, 6, 16)


# ---------------------------------------------------------------------------------------------
# The build plans with plan.py (one planner): the same chunks as the builder's own planner had


def _footprint_chunks_v1(
    lv: int, tile_n: int, bounds: tuple[float, float, float, float], wraps: bool, res: float
) -> set[tuple[int, int]]:
    """The builder's former planner (driver._footprint_chunks, before it used plan.py): the
    chunks of level lv whose closed node windows come within a node spacing and a pixel of a
    footprint, columns folded across the antimeridian."""
    d = node_spacing(lv, tile_n)
    reach = d + res
    c = chunk_nodes(tile_n)
    rows, cols = chunk_grid_shape(lv, tile_n)
    r_nodes = 1 << (lv + tile_n)
    w, s, e, n = bounds
    gr_lo = max(0, math.floor((90.0 - n - reach) / d))
    gr_hi = min(r_nodes, math.ceil((90.0 - s + reach) / d))
    if gr_lo > gr_hi:
        return set()
    cy_lo = max(0, -(-(gr_lo - c) // c))
    cy_hi = min(rows - 1, gr_hi // c)
    width = 360.0 if wraps else ((e - w) % 360.0 or (360.0 if e != w else 0.0))
    gc_lo = math.floor((w + 180.0 - reach) / d)
    gc_hi = math.ceil((w + 180.0 + width + reach) / d)
    if wraps or gc_hi - gc_lo >= (1 << (lv + 1 + tile_n)):
        cxs: set[int] = set(range(cols))
    else:
        cxs = {cx % cols for cx in range(-(-(gc_lo - c) // c), gc_hi // c + 1)}
    return {(cy, cx) for cy in range(cy_lo, cy_hi + 1) for cx in cxs}


def _plan_v1(srcs: list, tile_n: int, max_level: int) -> list[set[tuple[int, int]]]:
    """driver._Builder._plan_chunks as it was: each level's chunks a source of that level or
    finer reaches, plus the parents of the finer level's."""
    planned: list[set[tuple[int, int]]] = [set() for _ in range(max_level + 1)]
    for lv in range(max_level, -1, -1):
        for s in srcs:
            if s.level >= lv:
                planned[lv] |= _footprint_chunks_v1(lv, tile_n, s.bounds, s.wraps, s.res)
        if lv < max_level:
            for cy, cx in planned[lv + 1]:
                planned[lv].add((0, 0) if lv < chunk_levels_c0(tile_n) else (cy >> 1, cx >> 1))
    return planned


def _sources(rows: list[tuple], wraps: list[bool], tile_n: int) -> list[SimpleNamespace]:
    out = []
    for i, (w, s, e, n, res) in enumerate(rows):
        width = 360.0 if wraps[i] else (e - w) % 360.0 or 360.0
        level = driver._natural_level(res, tile_n, min(width, n - s))
        out.append(
            SimpleNamespace(
                path=f"s{i}",
                bounds=(w, s, e, n),
                res=res,
                wraps=wraps[i],
                datum="egm96",
                level=level,
            )
        )
    return out


@pytest.mark.parametrize(("tile_n", "max_level"), [(6, None), (6, 9), (8, None), (10, 4)])
def test_the_builds_plan_is_its_former_planners(tile_n: int, max_level: int | None) -> None:
    """plan_chunks of the table a build makes of its opened sources (driver._footprint_table)
    gives each level the chunks the builder's own planner gave: random footprints (across
    the antimeridian, at the poles), a global source, several levels."""
    rng = np.random.default_rng(7)
    rows = random_footprints(rng, 10)
    rows += [(-180.0, -90.0, 180.0, 90.0, 1 / 3), (170.0, -89.5, -175.0, -80.0, 0.01)]
    wraps = [False] * (len(rows) - 2) + [True, False]
    srcs = _sources(rows, wraps, tile_n)
    got = plan_chunks(driver._footprint_table(srcs), tile_n, max_level).chunk_sets()
    l_max = driver._clamp_levels(srcs, max_level)
    assert got == _plan_v1(srcs, tile_n, l_max)


def test_a_store_built_with_plan_py_is_the_former_planners_bit_for_bit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A global coarse DEM under a regional finer one (levels 0..7, chunks across the
    antimeridian): the store ingest writes with plan.py's chunks is, file by file, the one
    written with the builder's former planner's."""
    data = Path(__file__).resolve().parents[2] / "data"
    srcs = [data / "etopo20.tif", data / "topobathy_vancouver.tif"]
    a = tmp_path / "plan_py"
    driver.ingest(srcs, a, workers=1)

    real = driver.plan_chunks

    def v1_plan(t, tile_n, max_level):
        p = real(t, tile_n, max_level)
        opened = [
            SimpleNamespace(
                bounds=(t.west[i], t.south[i], t.east[i], t.north[i]),
                res=float(t.res[i]),
                wraps=bool(t.wraps[i]),
                level=int(lv),
            )
            for i, lv in enumerate(p.source_levels)
        ]
        sets = _plan_v1(opened, tile_n, p.max_level)
        assert sets == p.chunk_sets()  # the two planners agree here too
        return SimpleNamespace(
            max_level=p.max_level, chunks=p.chunks, level_nodes=p.level_nodes, levels=p.levels,
            chunk_sets=lambda: sets,
        )  # fmt: skip

    monkeypatch.setattr(driver, "plan_chunks", v1_plan)
    b = tmp_path / "v1"
    driver.ingest(srcs, b, workers=1)

    def files(store: Path) -> dict[str, bytes]:
        return {
            p.relative_to(store).as_posix(): p.read_bytes()
            for p in sorted(store.rglob("*"))
            if p.is_file()
        }

    fa, fb = files(a), files(b)
    assert sum(k.startswith("chunks/") for k in fa) > 2
    assert fa == fb
