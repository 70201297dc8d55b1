"""The decoded-chunk cache of level reads (globeview.terrain.levels.ChunkCache): windows equal
GDAL's own windowed reads bit for bit, the byte bound holds, a rewritten file is read again,
threads share it safely."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.errors import RasterioIOError
from rasterio.windows import Window

from globeview.terrain.levels import ChunkCache, chunk_cache


def _write(path: Path, arr: np.ndarray) -> Path:
    """A level-chunk-like GeoTIFF: tiled 256^2 (or less), deflate, predictor 3, NaN nodata."""
    h, w = arr.shape
    profile = {
        "driver": "GTiff",
        "dtype": "float32",
        "width": w,
        "height": h,
        "count": 1,
        "crs": "EPSG:4326",
        "transform": Affine(0.01, 0.0, -71.0, 0.0, -0.01, 45.0),
        "nodata": np.nan,
        "compress": "deflate",
        "predictor": 3,
        "tiled": h >= 256 and w >= 256,
    }
    if profile["tiled"]:
        profile.update(blockxsize=256, blockysize=256)
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(arr, 1)
    return path


def _heights(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    a = (rng.normal(size=shape) * 700.0).astype(np.float32)
    a[rng.random(shape) < 0.1] = np.nan
    a[rng.random(shape) < 0.05] = -0.0
    return a


def test_windows_are_gdal_windows(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    path = _write(tmp_path / "level_07_r0000_c0001.tif", _heights(rng, (300, 517)))
    cache = ChunkCache(64 << 20)
    with rasterio.open(path) as ds:
        for _ in range(40):
            r, c = int(rng.integers(0, 300)), int(rng.integers(0, 517))
            h, w = int(rng.integers(1, 301 - r)), int(rng.integers(1, 518 - c))
            win = Window(c, r, w, h)
            want = ds.read(1, window=win)
            got = cache.window(path, win)
            assert got.shape == want.shape and got.dtype == np.float32
            np.testing.assert_array_equal(got.view(np.int32), want.view(np.int32))
    assert cache.misses == 1 and cache.hits == 39


def test_arrays_are_read_only(tmp_path: Path) -> None:
    path = _write(tmp_path / "a.tif", np.ones((5, 7), np.float32))
    arr = ChunkCache(1 << 20).array(path)
    with pytest.raises(ValueError, match="read-only"):
        arr[0, 0] = 2.0


def test_byte_bound_evicts_least_recently_used(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    paths = [_write(tmp_path / f"c{i}.tif", _heights(rng, (64, 64))) for i in range(5)]
    one = 64 * 64 * 4
    cache = ChunkCache(2 * one)
    for p in paths[:2]:
        cache.array(p)
    cache.array(paths[0])  # paths[0] is now the most recent
    cache.array(paths[2])  # evicts paths[1]
    assert cache.nbytes <= 2 * one
    hits = cache.hits
    cache.array(paths[0])
    assert cache.hits == hits + 1
    misses = cache.misses
    cache.array(paths[1])
    assert cache.misses == misses + 1
    # A file larger than the bound is still returned (and is the only one kept).
    big = ChunkCache(one // 2)
    assert big.array(paths[3]).shape == (64, 64)
    assert big.array(paths[4]).shape == (64, 64)
    assert big.nbytes == one
    big.clear()
    assert big.nbytes == 0


def test_rewritten_file_is_read_again(tmp_path: Path) -> None:
    path = _write(tmp_path / "c.tif", np.zeros((20, 20), np.float32))
    cache = ChunkCache(1 << 20)
    assert cache.array(path)[3, 4] == 0.0
    time.sleep(0.01)  # a new mtime even on coarse-grained file systems
    _write(path, np.full((20, 20), 8.5, np.float32))
    assert cache.array(path)[3, 4] == 8.5


def test_missing_or_damaged_file_raises_each_time(tmp_path: Path) -> None:
    cache = ChunkCache(1 << 20)
    with pytest.raises(FileNotFoundError):
        cache.array(tmp_path / "nope.tif")
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"II*\x00garbage" * 10)
    for _ in range(2):  # nothing half-read is cached
        with pytest.raises(RasterioIOError):
            cache.array(bad)
    assert cache.nbytes == 0


def test_threads_share_the_cache(tmp_path: Path) -> None:
    rng = np.random.default_rng(9)
    data = [_heights(rng, (96, 80)) for _ in range(6)]
    paths = [_write(tmp_path / f"t{i}.tif", a) for i, a in enumerate(data)]
    cache = ChunkCache(3 * 96 * 80 * 4)  # half of them: evictions while threads read
    errors: list[str] = []

    def work(seed: int) -> None:
        r = np.random.default_rng(seed)
        for _ in range(60):
            i = int(r.integers(0, 6))
            got = cache.window(paths[i], Window(3, 5, 40, 50))
            if not np.array_equal(got, data[i][5:55, 3:43], equal_nan=True):
                errors.append(f"chunk {i}")

    threads = [threading.Thread(target=work, args=(s,)) for s in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert cache.nbytes <= 3 * 96 * 80 * 4
    assert cache.hits + cache.misses == 240


def test_process_cache_is_bounded() -> None:
    assert 0 < chunk_cache().max_bytes <= 256 << 20
