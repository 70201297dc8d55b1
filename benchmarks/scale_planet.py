"""The planet in globeview's pyramid: levels, tiles, chunk files and metadata shards of SRTM 1"
(60 N - 56 S, land) in store format 7, and the cost of building it from per-node figures
measured by benchmarks/bench_ingest.py (the arithmetic behind docs/scale.md; `ingest --plan`
and benchmarks/bench_plan.py plan the same from the tiles' names, exactly).

Land: the 1 x 1 degree cells between 56 S and 60 N holding any sample above 0 m in a global
DEM (default the embedded ETOPO 20', data/etopo20.tif; ``--land-dem`` another, e.g. ETOPO5);
SRTM 1" has 14 277 such tiles of 3601^2 samples (the count the script compares with). Tiles
and chunk files (store format 7's global chunk grid, `terrain/store/layout.py`: chunks only
where there is data) are counted where their footprint meets a land cell, at the finest level
and summed over every level; the metadata shards are those whose root chunk meets land (plus
the top shard); the manifest is O(levels) whatever the extent.

    python benchmarks/scale_planet.py [--level 13] [--cpu-ns-per-node 500]
        [--bytes-per-node 3.0] [--hours 8]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SRTM_TILES = 14_277  # 1 x 1 degree SRTM 1" tiles (NASA SRTMGL1), 60 N - 56 S
SRTM_SAMPLES = 3601 * 3601  # a tile's samples (pixel-is-point, shared edges)
SOUTH, NORTH = -56, 60


class BenchError(Exception):
    """A bad argument (one line, exit status 2)."""


def land_cells(dem: Path) -> np.ndarray:
    """(180, 360) bool: 1 x 1 degree cells (row 0 = 89..90 N, column 0 = 180..179 W) between
    56 S and 60 N with any sample above 0 m."""
    import rasterio

    with rasterio.open(dem) as ds:
        z = ds.read(1, masked=True).filled(-1.0).astype(np.float64)
        west, _, _, north = ds.bounds
        h, w = z.shape
        res_x, res_y = ds.res
    lat = north - (np.arange(h) + 0.5) * res_y
    lon = west + (np.arange(w) + 0.5) * res_x
    rows = np.clip(np.floor(90.0 - lat).astype(int), 0, 179)
    cols = np.floor(lon + 180.0).astype(int) % 360
    cells = np.zeros((180, 360), dtype=bool)
    yy, xx = np.nonzero(z > 0.0)
    cells[rows[yy], cols[xx]] = True
    band = np.zeros(180, dtype=bool)
    band[90 - NORTH : 90 - SOUTH] = True  # rows 30..145: 60 N .. 56 S
    return cells & band[:, None]


def _touching(cells: np.ndarray, level: int, block: int) -> tuple[int, int, int]:
    """Blocks of ``block`` x ``block`` level-``level`` tiles meeting a land cell:
    (count touching land, columns and rows of the band's bounding extent in blocks)."""
    ncols, nrows = 1 << (level + 1), 1 << level
    side = 180.0 / nrows * block  # degrees a block
    bx = math.ceil(ncols / block)
    by = math.ceil(nrows / block)
    # Cell index ranges of each block column / row (a block meets cells lo..hi).
    x0 = np.arange(bx) * side
    lo_x = np.floor(x0).astype(int)
    hi_x = np.minimum(np.ceil(x0 + side).astype(int), 360) - 1
    y0 = np.arange(by) * side
    lo_y = np.floor(y0).astype(int)
    hi_y = np.minimum(np.ceil(y0 + side).astype(int), 180) - 1
    # Prefix sums answer "any land cell in the rectangle" per block at once.
    s = np.zeros((181, 361), dtype=np.int64)
    s[1:, 1:] = cells.astype(np.int64).cumsum(0).cumsum(1)
    r0, r1 = lo_y[:, None], hi_y[:, None] + 1
    c0, c1 = lo_x[None, :], hi_x[None, :] + 1
    hit = (s[r1, c1] - s[r0, c1] - s[r1, c0] + s[r0, c0]) > 0
    rows_band = np.flatnonzero((y0 + side > 90 - NORTH) & (y0 < 90 - SOUTH))
    return int(hit.sum()), bx, int(rows_band.size)


def main(argv: list[str] | None = None) -> int:
    class Parser(argparse.ArgumentParser):
        def error(self, message: str):  # type: ignore[override]
            raise BenchError(message)

    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--level", type=int, help="finest level (default: SRTM 1\"'s natural level)")
    ap.add_argument("--tile-n", type=int, default=6, help="tiles of 2^n + 1 nodes a side")
    ap.add_argument("--land-dem", default=str(ROOT / "data" / "etopo20.tif"))
    ap.add_argument("--cpu-ns-per-node", type=float, help="measured CPU a finest-level node")
    ap.add_argument("--bytes-per-node", type=float, help="measured store bytes a finest node")
    ap.add_argument("--hours", type=float, default=8.0, help="wall-clock budget of the build")
    try:
        args = ap.parse_args(argv)
        from globeview.terrain.ingest.driver import _natural_level

        level = _natural_level(1.0 / 3600.0, args.tile_n) if args.level is None else args.level
        if not (0 <= level <= 20 and 4 <= args.tile_n <= 9):
            raise BenchError(f"--level must be 0..20 and --tile-n 4..9: {level}, {args.tile_n}")
        for name in ("cpu_ns_per_node", "bytes_per_node", "hours"):
            v = getattr(args, name)
            if v is not None and not (0 < v < 1e12):  # NaN too
                raise BenchError(f"--{name.replace('_', '-')} must be a positive number: {v}")
        if not Path(args.land_dem).is_file():
            raise BenchError(f"--land-dem {args.land_dem}: no such file")
    except BenchError as exc:
        print(f"scale_planet: error: {exc}", file=sys.stderr)
        return 2
    from globeview.terrain.store.layout import chunk_grid_shape, chunk_tiles, shard_roots

    cells = land_cells(Path(args.land_dem))
    n = 1 << args.tile_n
    k_chunk = chunk_tiles(args.tile_n)  # a chunk file: k x k tiles of the global chunk grid
    d_arcsec = 180.0 / (1 << level) / n * 3600.0
    print(
        f"land cells (1 x 1 deg, {SOUTH}..{NORTH} deg, any sample > 0 m in "
        f'{Path(args.land_dem).name}): {int(cells.sum())} (SRTM 1": {SRTM_TILES} tiles, '
        f"{SRTM_TILES * SRTM_SAMPLES:.3g} samples)"
    )
    print(f'finest level {level}: node spacing {d_arcsec:.3f}" (SRTM 1" = 1")')
    tiles_land = chunks_land = tiles_all = chunks_all = 0
    roots = set(shard_roots(level, args.tile_n))
    shards = 1  # the top shard
    for lv in range(level + 1):
        t, _, _ = _touching(cells, lv, 1)
        c, _, _ = _touching(cells, lv, k_chunk)
        tiles_all += t
        chunks_all += c
        if lv in roots:
            shards += c  # a shard for each root chunk with data below it
        if lv == level:
            tiles_land, chunks_land = t, c
    # The land mask misses SRTM tiles with little land (islands, coasts): scale the counts by
    # SRTM's tile count over the mask's cells (a tile's share of tiles is the same).
    k = SRTM_TILES / max(int(cells.sum()), 1)
    tiles_land, chunks_land = round(tiles_land * k), round(chunks_land * k)
    tiles_all, chunks_all = round(tiles_all * k), round(chunks_all * k)
    shards = round(shards * k)
    nodes = tiles_land * n * n  # nodes of the finest level over land (shared edges once)
    rows, cols = chunk_grid_shape(level, args.tile_n)
    print(f"counts over land scaled by {SRTM_TILES} / {int(cells.sum())} = {k:.3f}")
    print(
        f"finest level over land: {tiles_land:,} tiles, {chunks_land:,} chunk files "
        f"({k_chunk}x{k_chunk} tiles), {nodes:.3g} nodes"
    )
    print(
        f"finest level's global chunk grid: {rows:,} x {cols:,} = {rows * cols:,} chunks "
        f"({chunks_land / (rows * cols):.1%} with land: only those are files)"
    )
    print(f"every level over land: {tiles_all:,} tiles, {chunks_all:,} chunk files")
    print(
        f"metadata: {shards:,} shards (the top one and a shard for each root chunk with land, "
        f"roots at levels {sorted(roots)}); the manifest is O(levels)"
    )
    print(
        f"Dask graph: {chunks_all:,} chunk tasks + {chunks_all:,} error+metadata tasks "
        "(chunks with land only)"
    )
    if args.bytes_per_node:
        print(
            f"store at {args.bytes_per_node:g} bytes a finest-level node: "
            f"{nodes * args.bytes_per_node / 1e12:.2f} TB"
        )
    if args.cpu_ns_per_node:
        core_h = nodes * args.cpu_ns_per_node * 1e-9 / 3600.0
        cores = core_h / args.hours
        print(
            f"CPU at {args.cpu_ns_per_node:g} ns a finest-level node: {core_h:,.0f} core-hours; "
            f"{args.hours:g} h needs {cores:,.0f} busy cores "
            f"({math.ceil(cores / 16):,} machines of 16 cores at 100 % efficiency)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
