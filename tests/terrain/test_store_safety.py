"""A store is recognised positively and checked before use: ingest never overwrites what it
did not write, and a damaged store is one StoreError line, never a traceback."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from inprocess_cli import run_globeview

from globeview.errors import StoreError
from globeview.terrain.quadtree import TileKey
from globeview.terrain.sources import open_source, store_path_for
from globeview.terrain.store.identify import identify
from globeview.terrain.store.schema import FORMAT_VERSION, STORE_FORMAT
from globeview.terrain.store.tile_store import TileStore

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
SMALL = DATA / "craterlake-elev-16bit-30m.tif"


def _cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``globeview ARGS`` run in this process (`inprocess_cli`: its output and exit status
    as a child process would give them), ``env`` set for the call."""
    return run_globeview(list(args), env=env)


def _snapshot(d: Path) -> dict[str, bytes | None]:
    """Every path under d (folders too) with its bytes: 'not one byte changes'."""
    return {
        str(p.relative_to(d)): (p.read_bytes() if p.is_file() else None)
        for p in sorted(d.rglob("*"))
    }


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory, seed_dem_store) -> Path:
    """What ``ingest([SMALL], out)`` writes: the session's `seed_dem_store` of SMALL (the
    same files, byte for byte), not ingested again. Tests change copies only (`_copy`)."""
    (out,) = (seed_dem_store(tmp_path_factory.mktemp("st"), SMALL) / "stores").iterdir()
    return out


def _copy(store: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "copy"
    shutil.copytree(store, dst)
    return dst


# -- never overwrite what globeview did not write ----------------------------------------------


@pytest.mark.parametrize(
    "manifest",
    [
        '{"a": 1}',
        "garbage, not JSON",
        "",
        '{"format_version": 2}',
        json.dumps({"format_version": FORMAT_VERSION, "levels": []}),
        '["format", "globeview-tile-store"]',
    ],
)
@pytest.mark.slow
def test_foreign_folder_with_a_manifest_is_refused(tmp_path: Path, manifest: str) -> None:
    mine = tmp_path / "mine"
    (mine / "sub").mkdir(parents=True)
    (mine / "manifest.json").write_text(manifest)
    (mine / "thesis.docx").write_text("precious")
    (mine / "sub" / "data.csv").write_text("1,2,3")
    before = _snapshot(mine)
    for extra in ([], ["--force"]):
        r = _cli("ingest", str(SMALL), "--out", str(mine), "--quiet", *extra)
        assert r.returncode == 2
        assert r.stderr.strip().splitlines() == [
            f"globeview: error: {mine} is not a globeview store, refusing to overwrite it"
        ]
        assert _snapshot(mine) == before
    with pytest.raises(StoreError, match=r"not a globeview tile store|unreadable manifest"):
        TileStore.open(mine)


@pytest.mark.slow
def test_store_holding_a_user_file_is_not_replaced(store: Path, tmp_path: Path) -> None:
    s = _copy(store, tmp_path)
    (s / "notes.txt").write_text("mine")
    before = _snapshot(s)
    r = _cli("ingest", str(SMALL), "--out", str(s), "--quiet", "--force")
    assert r.returncode == 2 and "notes.txt" in r.stderr and len(r.stderr.splitlines()) == 1
    assert _snapshot(s) == before
    TileStore.open(s).close()  # still a store to read


def _legacy(s: Path) -> None:
    """Rewrite a store's manifest as format 2 wrote it (no marker)."""
    man = json.loads((s / "manifest.json").read_text())
    del man["format"]
    man["format_version"] = 2
    (s / "manifest.json").write_text(json.dumps(man))


@pytest.mark.slow
def test_older_store_needs_force_then_is_rebuilt(store: Path, tmp_path: Path) -> None:
    s = _copy(store, tmp_path)
    _legacy(s)
    assert identify(s).kind == "legacy"
    with pytest.raises(StoreError, match=r"built before vertical datums \(format version 2"):
        TileStore.open(s)
    before = _snapshot(s)
    r = _cli("ingest", str(SMALL), "--out", str(s), "--quiet")
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1
    assert "built before vertical datums (format version 2" in r.stderr and "--force" in r.stderr
    assert _snapshot(s) == before
    r = _cli("ingest", str(SMALL), "--out", str(s), "--quiet", "--force")
    assert r.returncode == 0, r.stderr
    TileStore.open(s).close()
    assert [p.name for p in tmp_path.iterdir()] == ["copy"]


@pytest.mark.slow
def test_newer_store_is_refused_without_force(store: Path, tmp_path: Path) -> None:
    s = _copy(store, tmp_path)
    man = json.loads((s / "manifest.json").read_text())
    man["format_version"] = FORMAT_VERSION + 1
    (s / "manifest.json").write_text(json.dumps(man))
    r = _cli("ingest", str(SMALL), "--out", str(s), "--quiet")
    assert r.returncode == 2 and "newer globeview" in r.stderr
    with pytest.raises(StoreError, match="not supported"):
        TileStore.open(s)


@pytest.mark.parametrize("version", [True, False, "4", 4.5, None])
def test_a_version_that_is_not_this_format_number_is_refused(
    store: Path, tmp_path: Path, version: object
) -> None:
    s = _copy(store, tmp_path)
    man = json.loads((s / "manifest.json").read_text())
    man["format_version"] = version
    (s / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(StoreError) as err:
        TileStore.open(s)
    assert len(str(err.value).splitlines()) == 1


@pytest.mark.slow
def test_cached_store_of_another_version_is_rebuilt_silently(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, seed_dem_store
) -> None:
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    seed_dem_store(tmp_path / "cache", SMALL)  # what open_source(SMALL) caches, not ingested
    _legacy(store_path_for(SMALL))
    with open_source(SMALL) as st:  # globeview owns its cache: no --force needed
        assert st.manifest.header.format == STORE_FORMAT
        assert st.manifest.header.format_version == FORMAT_VERSION


def test_manifest_has_the_marker(store: Path) -> None:
    man = json.loads((store / "manifest.json").read_text())
    assert man["format"] == STORE_FORMAT and man["format_version"] == FORMAT_VERSION


# -- the cache keys stores by the DEM's full path ----------------------------------------------


def _dem(path: Path, height: float) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    z = np.full((50, 60), height, np.float32) + np.arange(60, dtype=np.float32)
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=60,
        height=50,
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=Affine(0.01, 0, 7.0, 0, -0.01, 46.0),
    ) as ds:
        ds.write(z, 1)
    return path


@pytest.mark.slow
def test_two_dems_with_one_file_name_get_two_stores(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    a = _dem(tmp_path / "a" / "dem.tif", 1000.0)
    b = _dem(tmp_path / "b" / "dem.tif", 3000.0)
    assert store_path_for(a) != store_path_for(b)
    assert store_path_for(a) == store_path_for(tmp_path / "a" / ".." / "a" / "dem.tif")
    with open_source(a) as sa, open_source(b) as sb:
        lv = sa.max_level
        key = next(
            TileKey(lv, x, y)
            for y in range(2**lv)
            for x in range(2 ** (lv + 1))
            if sa.has_data(lv, x, y)
        )
        ha, hb = sa.heights(key), sb.heights(key)  # the first is still readable
        assert 900 < np.nanmin(ha) < 1100 and 2900 < np.nanmin(hb) < 3100
    # Ingesting both through the CLI into the cache: both stores stay.
    r = _cli("ingest", str(a), "--out", str(store_path_for(a)), "--quiet")
    assert r.returncode == 0 and "up to date" in r.stdout
    assert sorted(p.name.split("-")[0] for p in (tmp_path / "cache" / "stores").iterdir()) == [
        "dem",
        "dem",
    ]


# -- damaged stores ------------------------------------------------------------------------------


def test_level_file_swapped_for_another_valid_geotiff(store: Path, tmp_path: Path) -> None:
    s = _copy(store, tmp_path)
    shutil.copy(s / "level_04.vrt", s / "level_03.vrt")
    with pytest.raises(StoreError, match=r"level_03\.vrt does not match"):
        TileStore.open(s)


@pytest.mark.parametrize("damage", ["truncated", "garbage", "missing", "empty", "folder"])
def test_damaged_level_file_is_a_store_error(store: Path, tmp_path: Path, damage: str) -> None:
    s = _copy(store, tmp_path)
    f = sorted(s.glob("chunks/06/*/*.tif"))[0]  # a chunk file of level 6 (format 7)
    data = f.read_bytes()
    if damage == "truncated":
        # The data's blocks come first (a global-grid chunk is mostly NaN blocks, a few bytes
        # each, after them): cut into the data, keeping the header.
        f.write_bytes(data[:600])
    elif damage == "garbage":
        f.write_bytes(os.urandom(len(data)))
    elif damage == "missing":
        f.unlink()
    elif damage == "empty":
        f.write_bytes(b"")
    else:
        f.unlink()
        f.mkdir()
    # A truncated file may open: reading its tiles must fail then.
    with pytest.raises(StoreError) as exc, TileStore.open(s) as st:  # noqa: PT012  reads until a tile fails
        for y in range(2**6):
            for x in range(2**7):
                if st.has_data(6, x, y):
                    st.heights(TileKey(6, x, y))
    assert "chunks/06/" in str(exc.value) and "\n" not in str(exc.value)


def test_damage_after_open_is_a_store_error(store: Path, tmp_path: Path) -> None:
    s = _copy(store, tmp_path)
    with TileStore.open(s) as st:
        lv = st.max_level
        g = st.level_grid(lv)
        # Tiles are read from the chunk files, not through the level's VRT.
        name = next(f.file for lvl, _, _, f in st.iter_chunks() if lvl == lv and f.file)
        f = s / name
        size = f.stat().st_size
        with f.open("r+b") as fh:  # in place: the same inode, now half gone
            fh.truncate(size // 3)
        keys = [
            TileKey(lv, (g.x0 + ix) % g.ncols, g.y0 + iy)
            for iy in range(g.ny)
            for ix in range(g.nx)
        ]
        with pytest.raises(StoreError, match=name):  # noqa: PT012  reads until a tile fails
            for k in keys:
                st.heights(k)


def _mutations(man: dict) -> list[tuple[str, dict]]:
    """Manifests with one thing wrong: keys deleted, wrong types, NaN, huge numbers."""
    out = []
    bad_values = [None, "x", [], {}, -1, 10**30, 1e308, math.nan, True, [1, 2]]
    for key in man:
        m = json.loads(json.dumps(man))
        del m[key]
        out.append((f"del {key}", m))
        for v in bad_values:
            m = json.loads(json.dumps(man))
            m[key] = v
            out.append((f"{key}={v!r}", m))
    level = man["levels"][-1]
    for key in level:
        m = json.loads(json.dumps(man))
        del m["levels"][-1][key]
        out.append((f"del levels[-1].{key}", m))
        for v in bad_values:
            m = json.loads(json.dumps(man))
            m["levels"][-1][key] = v
            out.append((f"levels[-1].{key}={v!r}", m))
    for key in level["bbox"]:
        for v in [None, -5, 10**12, 2.5, "1", math.nan]:
            m = json.loads(json.dumps(man))
            m["levels"][-1]["bbox"][key] = v
            out.append((f"bbox.{key}={v!r}", m))
    for key in man["shards"]["top"]:
        for v in [None, -5, 10**15, 2.5, "1", "meta/top-0000000000000000.gvm", "0" * 64]:
            m = json.loads(json.dumps(man))
            m["shards"]["top"][key] = v
            out.append((f"shards.top.{key}={v!r}", m))
    m = json.loads(json.dumps(man))
    m["levels"][-1]["file"] = "../../../etc/passwd"
    out.append(("file outside", m))
    return out


@pytest.mark.slow
def test_fuzzed_manifest_is_always_one_store_error(store: Path, tmp_path: Path) -> None:
    s = _copy(store, tmp_path)
    man = json.loads((store / "manifest.json").read_text())
    # Fields the reader does not use may be anything; every other mutation must be refused.
    unused = {"created_by", "sources", "params", "tile_size", "wavelet"}
    unused |= {f"levels[-1].{k}" for k in ("node_spacing_deg", "sha256", "chunks", "tiles")}
    unused |= {"levels[-1].bytes", "shards.count"}
    nullable = {"pole_heights", "levels[-1].pole_heights", "levels[-1].level_error"}
    accepted = []
    for name, m in _mutations(man):
        (s / "manifest.json").write_text(json.dumps(m))
        try:
            TileStore.open(s).close()
            accepted.append(name)
        except StoreError as exc:
            assert "\n" not in str(exc), name  # noqa: PT017  a loop of cases, some accepted
        except Exception as exc:  # noqa: BLE001  any other exception type is what this test reports
            pytest.fail(f"{name}: {type(exc).__name__}: {exc}")
    for name in accepted:
        key = name.removeprefix("del ").split("=")[0]
        value = name.partition("=")[2]
        ok = key in unused or (key in nullable and (name.startswith("del ") or value == "None"))
        ok |= "pole_heights" in key and value == "{}"  # no pole heights recorded
        ok |= name == "del generation"  # stores written before generations: generation 0
        ok |= key == "levels[-1].level_error" and value in (
            "1000000000000000000000000000000",
            "1e+308",
        )
        assert ok, name


@pytest.mark.slow
def test_stem_keyed_cache_store_of_format_2_is_dropped(
    store: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(tmp_path / "cache"))
    old = tmp_path / "cache" / "stores" / SMALL.stem  # where format 2 cached it
    shutil.copytree(store, old)
    _legacy(old)
    foreign = tmp_path / "cache" / "stores" / "dem"  # same place, not a globeview store
    foreign.mkdir()
    (foreign / "manifest.json").write_text("{}")
    open_source(SMALL).close()
    assert not old.exists()
    _dem(tmp_path / "x" / "dem.tif", 5.0)
    open_source(tmp_path / "x" / "dem.tif").close()
    assert (foreign / "manifest.json").read_text() == "{}"


@pytest.mark.slow
def test_reingest_rebuilds_a_damaged_store_instead_of_calling_it_up_to_date(
    store: Path, tmp_path: Path
) -> None:
    s = _copy(store, tmp_path)
    shutil.copy(s / "level_04.vrt", s / "level_03.vrt")
    r = _cli("ingest", str(SMALL), "--out", str(s), "--quiet")
    assert r.returncode == 0 and "up to date" not in r.stdout
    with TileStore.open(s) as st:
        st.verify()


def test_verify_names_a_level_file_removed_after_open(store: Path, tmp_path: Path) -> None:
    s = _copy(store, tmp_path)
    with TileStore.open(s) as st:
        f = sorted(s.glob("chunks/06/*/*.tif"))[0]
        f.unlink()
        with pytest.raises(StoreError, match=f.name):
            st.verify()


def test_a_symlink_to_a_store_opens(store: Path, tmp_path: Path) -> None:
    (tmp_path / "link").symlink_to(store)
    with TileStore.open(tmp_path / "link") as st:
        assert st.max_level >= 0


def test_cache_that_cannot_be_created_is_a_store_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    blocker = tmp_path / "cache"
    blocker.write_text("a file where the cache folder should be")
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(blocker))
    with pytest.raises(StoreError, match="cannot create the store cache"):
        open_source(SMALL)
    assert blocker.read_text().startswith("a file")
