"""TileStore: opening, vectorised metadata, cached and prefetched tile reads."""

from __future__ import annotations

import json
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import rasterio

from globeview.errors import StoreError
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.quadtree import TileKey
from globeview.terrain.store.schema import FORMAT_VERSION
from globeview.terrain.store.tile_store import TileStore

DATA = Path(__file__).resolve().parents[2] / "data"


def _etopo() -> Path:
    p = DATA / "etopo20.tif"
    return p if p.exists() else Path("/work/shared/data/etopo20.tif")


@pytest.fixture(scope="module")
def store_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("st") / "store"
    ingest([_etopo()], out)
    return out


def test_open_fast_and_attributes(store_path: Path) -> None:
    t = time.perf_counter()
    st = TileStore.open(store_path)
    assert time.perf_counter() - t < 0.5
    assert st.tile_n == 6 and st.tile_size == 65
    assert st.max_level >= 2
    assert st.bounds == (-180.0, -90.0, 180.0, 90.0)
    assert set(st.pole_heights) == {"north", "south"}
    st.verify()


def test_vectorised_metadata(store_path: Path) -> None:
    st = TileStore.open(store_path)
    lv = 2
    xs, ys = np.meshgrid(np.arange(-1, 9), np.arange(-1, 5))
    has = st.has_data(lv, xs, ys)
    inside = (xs >= 0) & (xs < 8) & (ys >= 0) & (ys < 4)
    assert np.array_equal(has, inside)
    err = st.tile_error(lv, xs, ys)
    assert err.dtype == np.float32 and np.isnan(err[~inside]).all() and (err[inside] > 0).all()
    hmin, hmax = st.tile_hrange(lv, xs, ys)
    for x, y in [(0, 0), (5, 3), (7, 1)]:
        h = st.heights(TileKey(lv, x, y))
        assert hmin[y + 1, x + 1] <= h.min() and hmax[y + 1, x + 1] >= h.max()
        assert hmax[y + 1, x + 1] - h.max() < 1e-2 * max(1.0, abs(h.max()))
    se = st.tile_stride_error(lv, xs, ys)
    assert se.shape == (*xs.shape, 7)
    np.testing.assert_array_equal(se[..., 0][inside], err[inside])
    assert (np.diff(se[inside], axis=-1) >= -1e-3).all()  # coarser strides never look better
    assert not st.has_data(st.max_level + 1, 0, 0)
    assert np.isnan(st.tile_error(st.max_level + 1, [0, 1], [0, 0])).all()


def test_heights_match_level_raster(store_path: Path) -> None:
    st = TileStore.open(store_path)
    lv = st.max_level
    with rasterio.open(store_path / f"level_{lv:02d}.vrt") as ds:
        full = ds.read(1)
    n = 2**st.tile_n
    for x, y in [(0, 0), (3, 2), (2 ** (lv + 1) - 1, 2**lv - 1)]:
        np.testing.assert_array_equal(
            st.heights(TileKey(lv, x, y)), full[y * n : y * n + n + 1, x * n : x * n + n + 1]
        )
    assert np.isnan(st.heights(TileKey(lv + 1, 0, 0))).all()


def test_cache_bounded_threadsafe_and_prefetch(store_path: Path) -> None:
    keys = [TileKey(3, x, y) for x in range(16) for y in range(8)]
    with TileStore.open(store_path, cache_tiles=16) as st:
        ref = {k: st.heights(k).copy() for k in keys}
        with ThreadPoolExecutor(8) as pool:
            got = list(pool.map(st.heights, keys * 3))
        for k, g in zip(keys * 3, got):
            np.testing.assert_array_equal(g, ref[k])
        assert sum(st.cached(k) for k in keys) <= 16
        futs = st.prefetch(keys[:10])
        for f in futs:
            f.result(timeout=10)
        assert all(st.cached(k) for k in keys[:10])


def test_open_errors(tmp_path: Path, store_path: Path) -> None:
    with pytest.raises(StoreError, match="not found"):
        TileStore.open(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(StoreError, match=r"no manifest\.json"):
        TileStore.open(tmp_path / "empty")
    bad = tmp_path / "bad"
    shutil.copytree(store_path, bad)
    (bad / "manifest.json").write_text("{not json")
    with pytest.raises(StoreError, match="unreadable"):
        TileStore.open(bad)
    man = json.loads((store_path / "manifest.json").read_text())
    man["format_version"] = 99
    (bad / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(StoreError, match="version"):
        TileStore.open(bad)
    man["format_version"] = FORMAT_VERSION
    del man["levels"]
    (bad / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(StoreError, match="damaged"):
        TileStore.open(bad)
