"""Per-tile height ranges from the nodes a store holds (globeview.terrain.ingest.stored_ranges).

A tile's last row and column are stored by the chunks south and east of it (computed from
their own windows); its hmin / hmax must bound what a reader gets for the tile, so they come
from the stored nodes, not from the window of the chunk the tile is in (2 of the 89 tiles of
the 512^2 benchmark DEM's store did not bound their heights when they did).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from globeview.terrain.ingest.driver import ingest
from globeview.terrain.ingest.stored_ranges import EdgeFacts, stored_part_facts, tile_ranges
from globeview.terrain.quadtree import TileKey
from globeview.terrain.store.tile_store import TileStore

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"


def _big_dem_512() -> Path:
    """The ingest benchmark's 512^2 DEM (N44W072 resampled, with fractal detail; made once
    under benchmarks/cache by benchmarks/make_big_dem.py, as the benchmark does)."""
    spec = importlib.util.spec_from_file_location(
        "make_big_dem", ROOT / "benchmarks/make_big_dem.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    path: Path = module.make(512, quiet=True)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("source", ["N44W072.hgt", "big_dem_512"])
def test_every_tile_range_is_its_stored_heights_range(source: str, tmp_path: Path) -> None:
    """A whole real store, every tile of every level: hmin and hmax are exactly the least and
    greatest of the heights the store gives for the tile (float32 nodes: the shards' outward
    rounding keeps them), NaN exactly where it gives none."""
    src = DATA / source if source.endswith(".hgt") else _big_dem_512()
    out = tmp_path / "store"
    ingest([src], out)
    tiles = 0
    with TileStore.open(out) as st:
        k = st.manifest.chunk_tiles
        for lv, cy, cx, facts in st.iter_chunks():
            kty, ktx = facts.hmin.shape
            for j in range(kty):
                for i in range(ktx):
                    h = st.heights(TileKey(lv, cx * k + i, cy * k + j))
                    lo, hi = facts.hmin[j, i], facts.hmax[j, i]
                    finite = h[np.isfinite(h)]
                    where = (source, lv, cx * k + i, cy * k + j)
                    if finite.size == 0:
                        assert np.isnan(lo) and np.isnan(hi), where
                        continue
                    tiles += 1
                    assert (lo, hi) == (finite.min(), finite.max()), where
    assert tiles > 80


def _facts(window: np.ndarray, rows: int, cols: int) -> tuple[np.ndarray, ...]:
    return stored_part_facts(window.astype(np.float32), rows, cols, 2)


def test_a_tiles_range_takes_its_closing_nodes_from_the_chunks_that_store_them() -> None:
    """Four chunks of 2 x 2 tiles (s_n = 2, windows of 5 x 5 nodes). Chunk (0, 0)'s window
    says its closing row and column are 0 m; the chunks south, east and south-east store them
    as 100 m, -50 m and 900 m: its last tiles' ranges are those of the stored nodes."""
    base = np.full((5, 5), 10.0)
    a = base.copy()
    a[-1, :] = a[:, -1] = 0.0  # what chunk (0, 0)'s own window had there
    south, east, south_east = base.copy(), base.copy(), base.copy()
    south[0, :] = 100.0
    east[:, 0] = -50.0
    south_east[0, 0] = 900.0
    own = {
        (3, 0, 0): _facts(a, 4, 4),
        (3, 1, 0): _facts(south, 4, 4),
        (3, 0, 1): _facts(east, 4, 4),
        (3, 1, 1): _facts(south_east, 4, 4),
    }
    lo, hi = tile_ranges(own, lambda lv, cy, cx: cx + 1 if cx < 1 else None)[(3, 0, 0)]
    np.testing.assert_array_equal(lo, [[10.0, -50.0], [10.0, -50.0]])
    np.testing.assert_array_equal(hi, [[10.0, 10.0], [100.0, 900.0]])
    # Alone (nothing stored beyond it), a chunk storing only its half-open part: its ranges
    # leave its window's closing row and column out.
    alone, _ = tile_ranges({(3, 0, 0): own[(3, 0, 0)]}, lambda *_: None)[(3, 0, 0)]
    np.testing.assert_array_equal(alone, np.full((2, 2), 10.0))


def test_a_chunk_storing_its_closing_row_and_the_wrap_round_the_antimeridian() -> None:
    """A chunk that stores its closing row (nothing south of it) counts it; the last chunk
    of a row that goes all the way round closes on the row's first chunk (east_of wraps)."""
    w = np.full((5, 5), 1.0)
    w[-1, :2] = -7.0
    first = np.full((5, 5), 3.0)
    first[:, 0] = 42.0
    own = {(2, 0, 1): _facts(w, 5, 4), (2, 0, 0): _facts(first, 5, 4)}
    ranges = tile_ranges(own, lambda lv, cy, cx: (cx + 1) % 2)
    lo, hi = ranges[(2, 0, 1)]
    np.testing.assert_array_equal(lo, [[1.0, 1.0], [-7.0, 1.0]])
    np.testing.assert_array_equal(hi, [[1.0, 42.0], [1.0, 42.0]])


def test_edge_facts_pack_and_unpack() -> None:
    """The packed form (ChunkResult.stored, the build facts) gives the same facts back."""
    window = np.arange(25, dtype=np.float32).reshape(5, 5)
    window[0, 3] = np.nan
    _, _, packed = stored_part_facts(window, 4, 4, 2)
    e = EdgeFacts.unpack(packed, 2, 2)
    np.testing.assert_array_equal(e.north, [[0.0, 2.0], [2.0, 2.0]])  # cols 0..2, 2..3
    np.testing.assert_array_equal(e.west, [[0.0, 10.0], [10.0, 15.0]])  # rows 0..2, 2..3
    assert e.corner == 0.0
