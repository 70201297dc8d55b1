"""Store format 7 is sparse (issue #25): chunk files only where there is data, a manifest whose
size does not grow with the data's extent, no tile-count cap, and a missing chunk reads as
"no data here" (the layer below shows through)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from globeview.errors import StoreError
from globeview.terrain.ingest import driver
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.quadtree import TileKey, key_for_lonlat
from globeview.terrain.store.layout import chunk_window
from globeview.terrain.store.tile_store import TileStore

RES = 1.0 / 120.0  # 30 arc-seconds: natural level 8 at tile_n 6


def _cell(folder: Path, west: float, north: float, seed: int) -> Path:
    """A 1 x 1 degree 30" DEM (ellipsoidal heights, a smooth hill plus noise)."""
    n = 120
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:n, 0:n] / n
    z = 800.0 + 600.0 * np.sin(3 * xx) * np.cos(2 * yy) + rng.normal(0, 5, (n, n))
    path = folder / f"cell_{seed}.tif"
    prof = {
        "driver": "GTiff",
        "width": n,
        "height": n,
        "count": 1,
        "dtype": "float32",
        "crs": "EPSG:4326",
        "transform": Affine(RES, 0, west, 0, -RES, north),
    }
    with rasterio.open(path, "w", **prof) as ds:
        ds.write(z.astype(np.float32), 1)
    return path


@pytest.fixture(scope="module")
def stores(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One cell near Boston; the same with a second cell near Sydney; both to level 11."""
    # (Natural level 8; "deep" goes three levels past it.)
    base = tmp_path_factory.mktemp("sparse")
    a = _cell(base, -71.8, 44.7, 1)
    b = _cell(base, 150.6, -33.3, 2)
    out = {"one": base / "one", "two": base / "two", "deep": base / "deep"}
    ingest([a], out["one"], vdatum="ellipsoid", workers=1)
    ingest([a, b], out["two"], vdatum="ellipsoid", workers=1)
    ingest([a, b], out["deep"], vdatum="ellipsoid", workers=1, max_level=11)
    return out


def _chunk_files(store: Path) -> list[tuple[int, int, int]]:
    out = []
    for p in store.glob("chunks/*/*/*.tif"):
        out.append((int(p.parts[-3]), int(p.parts[-2]), int(p.name.split("-")[0])))
    return sorted(out)


def _near(level: int, cy: int, cx: int, lon: float, lat: float) -> bool:
    """Whether chunk (level, cy, cx) lies within one chunk of a point (degrees)."""
    gr0, gc0, h, w = chunk_window(level, 6, cy, cx)
    d = 180.0 / 2**level / 64
    west, north = -180.0 + gc0 * d, 90.0 - gr0 * d
    east, south = west + w * d, north - h * d
    return west - w * d <= lon <= east + w * d and south - h * d <= lat <= north + h * d


def test_chunks_only_where_there_is_data(stores: dict[str, Path]) -> None:
    two = _chunk_files(stores["two"])
    one = _chunk_files(stores["one"])
    assert len(two) <= 2 * len(one) + 2
    for lv, cy, cx in two:
        assert _near(lv, cy, cx, -71.3, 44.2) or _near(lv, cy, cx, 151.1, -33.8), (lv, cy, cx)
    with TileStore.open(stores["two"]) as st:
        assert st.max_level == 8
        g = st.level_grid(8)
        assert g.nx * g.ny > 20_000  # the bbox spans more than half the globe ...
        assert st.manifest.levels[8].chunks <= 8  # ... but only the data has files
        for lon, lat in ((-71.3, 44.2), (151.1, -33.8)):
            x, y = key_for_lonlat(8, lon, lat)
            assert np.isfinite(st.heights(TileKey(8, int(x), int(y)))).mean() > 0.5
        x, y = key_for_lonlat(8, 30.0, 0.0)  # between the two: no chunk, no data
        assert not st.has_data(8, int(x), int(y))
        assert np.isnan(st.heights(TileKey(8, int(x), int(y)))).all()


def test_manifest_size_does_not_grow_with_the_extent(stores: dict[str, Path]) -> None:
    one = json.loads((stores["one"] / "manifest.json").read_text())
    two = json.loads((stores["two"] / "manifest.json").read_text())
    size = {k: len(json.dumps(v)) for k, v in (("one", one), ("two", two))}
    one_source = len(json.dumps(two["sources"][1]))
    # The second source adds its record and some bbox digits, never per-tile arrays.
    assert size["two"] - size["one"] < one_source + 400
    assert size["two"] < 8_000


def test_no_tile_count_cap(stores: dict[str, Path]) -> None:
    """Levels 0..11 over both cells' bbox have more tiles than the old cap (2^19) allowed."""
    assert not hasattr(driver, "MAX_TILES")  # (driver._check_size is the disk's bound now)
    with TileStore.open(stores["deep"]) as st:
        total = sum(st.level_grid(lv).nx * st.level_grid(lv).ny for lv in range(12))
        assert total > 1 << 19
        assert sum(lv.chunks for lv in st.manifest.levels) < 60
        x, y = key_for_lonlat(11, 151.1, -33.8)
        assert np.isfinite(st.heights(TileKey(11, int(x), int(y)))).all()


def test_a_deleted_chunk_is_no_data_and_verify_names_it(
    stores: dict[str, Path], tmp_path: Path
) -> None:
    """Metadata says where chunks are; the file of one removed afterwards is one line."""
    copy = tmp_path / "s"
    shutil.copytree(stores["one"], copy)
    victim = sorted(copy.glob("chunks/08/*/*.tif"))[0]
    victim.unlink()
    with TileStore.open(copy) as st:
        with pytest.raises(StoreError) as err:
            st.verify(full=False)
        assert victim.name in str(err.value) and "\n" not in str(err.value)


def test_a_dense_store_gives_the_rebuild_line(stores: dict[str, Path], tmp_path: Path) -> None:
    copy = tmp_path / "old"
    shutil.copytree(stores["one"], copy)
    raw = json.loads((copy / "manifest.json").read_text())
    raw["format_version"] = 6
    (copy / "manifest.json").write_text(json.dumps(raw))
    with pytest.raises(StoreError) as err:
        TileStore.open(copy)
    msg = str(err.value)
    assert "format version 6" in msg and "rebuild it with globeview ingest --force" in msg
    assert "\n" not in msg
