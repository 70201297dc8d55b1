"""Store generations (issue #25 item 5): an update commits its files beside the ones readers
have open and switches ``manifest.json`` last, so a reader that opened generation g (a local
`TileStore`, an HTTP client through a real `StaticServer` on 127.0.0.1) reads g's heights and
nothing else across the update; garbage collection keeps exactly g and g - 1; a reader two
generations behind gets one line; a store written before generations still opens.

One small store (two 0.5-degree DEMs to level 6: one chunk file a level, level 6 in a shard of
its own) goes through two updates in a module fixture (about 3 CPU-s in all); the kill -9
test runs `globeview ingest` in a child process (slow)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine

from globeview.bench.http_server import StaticServer
from globeview.errors import StoreError
from globeview.terrain.ingest.driver import ingest
from globeview.terrain.ingest.tasks import FAULT_ENV
from globeview.terrain.store.generations import (
    collect_garbage,
    commit_generation,
    referenced_files,
)
from globeview.terrain.store.http import RemoteOptions, clear_memory
from globeview.terrain.store.identify import MANIFEST_NAME
from globeview.terrain.store.layout import facts_root, generation_manifest_name
from globeview.terrain.store.schema import StoreManifest
from globeview.terrain.store.tile_store import TileStore

N = 128  # pixels a side
RES = 1.0 / 256  # degrees: 0.5-degree tiles
MAX_LEVEL = 6
GLOBEVIEW = Path(sys.executable).with_name("globeview")

Key = tuple[int, int, int]


def _dem(path: Path, west: float, bump: float = 0.0) -> Path:
    """A 0.5-degree DEM (45.5..46 N) with smooth relief; ``bump`` adds a hill at its centre."""
    y, x = np.mgrid[0:N, 0:N].astype(np.float32) / N
    z = 800.0 + 300.0 * np.sin(6.0 * x + west) * np.cos(5.0 * y)
    z += bump * np.exp(-(((x - 0.5) ** 2 + (y - 0.5) ** 2) / 0.02))
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=N,
        height=N,
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=Affine(RES, 0.0, west, 0.0, -RES, 46.0),
    ) as ds:
        ds.write(z.astype(np.float32), 1)
    return path


def _keys(st: TileStore) -> list[Key]:
    """Every tile with data, every level."""
    out = []
    for lv in range(st.max_level + 1):
        g = st.level_grid(lv)
        ncols = 1 << (lv + 1)
        for y in range(g.y0, g.y0 + g.ny):
            for x in range(g.x0, g.x0 + g.nx):
                if st.has_tile(lv, x % ncols, y):
                    out.append((lv, x % ncols, y))
    return out


def _read(st: TileStore, keys: list[Key]) -> dict[Key, np.ndarray]:
    return {k: np.array(st.heights_padded(k)) for k in keys}


def _same(a: dict[Key, np.ndarray], b: dict[Key, np.ndarray]) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)


def _files(store: Path) -> set[str]:
    return {p.relative_to(store).as_posix() for p in store.rglob("*") if p.is_file()}


def _generation_files(store: Path, gen: int) -> set[str]:
    """What generation ``gen`` of ``store`` needs: its shards and chunks, its manifest copy
    and its facts (read from its manifest copy)."""
    m = StoreManifest.from_json(json.loads((store / generation_manifest_name(gen)).read_text()))
    assert m.generation == gen
    facts = store / facts_root(gen) / "facts"
    return (
        referenced_files(store, m)
        | {generation_manifest_name(gen)}
        | {p.relative_to(store).as_posix() for p in facts.rglob("*") if p.is_file()}
    )


@pytest.fixture(scope="module")
def gens(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A store through two updates, with readers opened at each generation and what they
    read; the HTTP ones through a StaticServer serving the store's folder."""
    root = tmp_path_factory.mktemp("gens")
    a, b = _dem(root / "a.tif", 10.0), _dem(root / "b.tif", 10.5)
    store = root / "s"
    ingest([a, b], store, workers=1, max_level=MAX_LEVEL)
    shutil.copytree(store, root / "gen0-copy")  # a store as written before this change
    out: dict = {"root": root, "store": store, "sources": (a, b)}
    opts = RemoteOptions(cache_dir=root / "http-cache", retries=1, backoff_s=0.01)
    with StaticServer(root) as srv, TileStore.open(store) as fresh:
        url = f"{srv.url}/s"
        keys = _keys(fresh)
        out["h0"] = _read(fresh, keys)
        out["files0"] = _files(store)
        local0, http0 = (
            TileStore.open(store, cache_tiles=1),
            TileStore.open(url, remote_options=opts),
        )
        # (its own disk cache: the one above gets generation 0's bytes, which it would serve)
        late_opts = RemoteOptions(cache_dir=root / "http-cache-late", retries=1, backoff_s=0.01)
        late_local0 = TileStore.open(store)
        late_http0 = TileStore.open(url, remote_options=late_opts)
        _dem(b, 10.5, bump=250.0)
        ingest([a, b], store, workers=1, max_level=MAX_LEVEL)
        out["files1"] = _files(store)
        with TileStore.open(store) as st:
            out["gen1"], out["h1"] = st.manifest.generation, _read(st, keys)
        out["local0"], out["http0"] = _read(local0, keys), _read(http0, keys)
        local1, http1 = TileStore.open(store), TileStore.open(url, remote_options=opts)
        _dem(b, 10.5, bump=-120.0)
        ingest([a, b], store, workers=1, max_level=MAX_LEVEL)
        with TileStore.open(store) as st:
            out["gen2"], out["h2"] = st.manifest.generation, _read(st, keys)
        out["local1"], out["http1"] = _read(local1, keys), _read(http1, keys)
        out["late"] = {}
        clear_memory()  # the pages in memory too
        for name, st in (("local", late_local0), ("http", late_http0)):
            try:
                _read(st, keys)
                out["late"][name] = "read"
            except StoreError as exc:
                out["late"][name] = str(exc)
        for st in (local0, http0, late_local0, late_http0, local1, http1):
            st.close()
    return out


def test_an_update_makes_a_new_generation_with_new_heights(gens: dict) -> None:
    assert (gens["gen1"], gens["gen2"]) == (1, 2)
    assert not _same(gens["h0"], gens["h1"]) and not _same(gens["h1"], gens["h2"])


def test_a_local_reader_open_across_an_update_reads_only_its_generation(gens: dict) -> None:
    # Opened at generation 0, read nothing before the update (a one-tile cache: every tile
    # read afterwards), then read every tile: generation 0's heights, none of 1's.
    assert _same(gens["local0"], gens["h0"])
    assert _same(gens["local1"], gens["h1"])  # the same at generation 1 across the 2nd update


def test_an_http_reader_open_across_an_update_reads_only_its_generation(gens: dict) -> None:
    assert _same(gens["http0"], gens["h0"])
    assert _same(gens["http1"], gens["h1"])


def test_a_reader_two_generations_behind_gets_one_line(gens: dict) -> None:
    local, remote = gens["late"]["local"], gens["late"]["http"]
    assert local.endswith("the store was updated; reopen it") and "\n" not in local
    assert "/s/chunks/" in remote or "/s/meta/" in remote
    assert remote.endswith("the store was updated on the server; reopen it")


def test_gc_keeps_exactly_the_current_and_the_previous_generation(gens: dict) -> None:
    store = gens["store"]
    want = _generation_files(store, 2) | _generation_files(store, 1)
    want |= {MANIFEST_NAME} | {f"level_{lv:02d}.vrt" for lv in range(MAX_LEVEL + 1)}
    assert _files(store) == want
    assert not (store / "facts").exists()  # generation 0's facts went with it
    # generation 0's chunks that generation 1 did not keep are gone (and its manifest copy)
    gone = gens["files1"] - _files(store)
    assert any(n.startswith("chunks/") for n in gone) and generation_manifest_name(0) in gone


def test_an_update_commits_beside_the_old_files(gens: dict) -> None:
    # After the first update both generations' chunks are there; the switch is manifest.json.
    assert gens["files0"] - {MANIFEST_NAME} <= gens["files1"]
    assert generation_manifest_name(1) in gens["files1"]


def test_a_store_written_before_generations_opens_at_generation_0(gens: dict) -> None:
    old = gens["root"] / "gen0-copy"
    man = json.loads((old / MANIFEST_NAME).read_text())
    del man["generation"]
    (old / MANIFEST_NAME).write_text(json.dumps(man))
    with TileStore.open(old) as st:
        assert st.manifest.generation == 0
        assert _same(_read(st, list(gens["h0"])), gens["h0"])


def test_info_shows_the_generation(gens: dict, tmp_path: Path) -> None:
    from inprocess_cli import run_globeview

    res = run_globeview(["info", str(gens["store"])], env={"GLOBEVIEW_CACHE_DIR": str(tmp_path)})
    assert res.returncode == 0, res.stderr
    assert "generation 2 (2 updates)" in res.stdout
    res = run_globeview(
        ["info", "--json", str(gens["store"])], env={"GLOBEVIEW_CACHE_DIR": str(tmp_path)}
    )
    assert res.returncode == 0 and json.loads(res.stdout)[0]["generation"] == 2


def _killed_update(store: Path, sources: tuple[Path, Path], fault: str) -> int:
    """``globeview ingest`` of ``sources`` into ``store`` in a child process that kills
    itself with SIGKILL at ingest fault point ``fault``; its return code."""
    env = {**os.environ, FAULT_ENV: f"KILL@{fault}", "GLOBEVIEW_CACHE_DIR": str(store.parent)}
    args = [str(GLOBEVIEW), "ingest", *map(str, sources), "--out", str(store)]
    args += ["--max-level", str(MAX_LEVEL), "--workers", "1", "--quiet"]
    return subprocess.run(args, env=env, capture_output=True, timeout=300).returncode


@pytest.mark.slow
@pytest.mark.parametrize("fault", ["3", "generation-switch", "generation-vrts"])
def test_kill_9_mid_update_leaves_a_whole_generation_and_the_next_ingest_completes(
    tmp_path: Path, fault: str
) -> None:
    # "3": killed while building (3 chunk files written); "generation-switch": the new files
    # moved into the store, both generations' manifests written, just before manifest.json is
    # replaced; "generation-vrts": just after, the level VRTs still the previous generation's.
    # (test_ingest_faults kills at "commit": the new files in, no manifest switched.)
    a, b = _dem(tmp_path / "a.tif", 10.0), _dem(tmp_path / "b.tif", 10.5)
    store = tmp_path / "s"
    ingest([a, b], store, workers=1, max_level=MAX_LEVEL)
    with TileStore.open(store) as st:
        keys = _keys(st)
        h0 = _read(st, keys)
    files0 = _files(store)
    _dem(b, 10.5, bump=250.0)
    assert _killed_update(store, (a, b), fault) == -signal.SIGKILL
    switched = fault == "generation-vrts"
    with TileStore.open(store) as st:
        assert st.manifest.generation == int(switched)
        assert _same(_read(st, keys), h0) is not switched
        st.verify()  # (the VRTs of the other generation are accepted)
    if fault != "3":
        assert _files(store) > files0  # the killed update's files are in
    ingest([a, b], store, workers=1, max_level=MAX_LEVEL)  # an update, or VRTs made whole
    gen = 1 + int(switched)
    with TileStore.open(store) as st:
        assert st.manifest.generation == gen
        assert not _same(_read(st, keys), h0)
        st.verify()
    want = _generation_files(store, gen) | _generation_files(store, gen - 1)
    want |= {MANIFEST_NAME} | {f"level_{lv:02d}.vrt" for lv in range(MAX_LEVEL + 1)}
    assert _files(store) == want  # the leftovers collected
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".s.")]  # no build folder


def test_gc_deletes_nothing_it_cannot_account_for(gens: dict, tmp_path: Path) -> None:
    store = shutil.copytree(gens["store"], tmp_path / "s")
    cur = StoreManifest.from_json(json.loads((store / MANIFEST_NAME).read_text()))
    prev = StoreManifest.from_json(json.loads((store / generation_manifest_name(1)).read_text()))
    stray = store / "chunks" / "06" / "0" / f"0-{'ab' * 8}.tif"  # garbage: no generation's
    stray.parent.mkdir(parents=True, exist_ok=True)
    stray.write_bytes(b"old")
    (store / "notes.txt").write_text("mine")  # not globeview's: never looked at
    shard = sorted((store / "meta" / "06").rglob("*.gvm"))[0]
    saved = shard.read_bytes()
    shard.unlink()  # a kept generation's shard tree cannot be walked: nothing is deleted
    before = _files(store)
    with pytest.raises(StoreError, match="missing"):
        collect_garbage(store, [cur, prev])
    assert _files(store) == before
    shard.write_bytes(saved)
    assert collect_garbage(store, [cur, prev]) == [stray.relative_to(store).as_posix()]
    assert (store / "notes.txt").read_text() == "mine"


def test_a_commit_over_a_store_another_ingest_changed_is_one_line(
    gens: dict, tmp_path: Path
) -> None:
    store = shutil.copytree(gens["store"], tmp_path / "s")
    stale = StoreManifest.from_json(json.loads((store / generation_manifest_name(1)).read_text()))
    before = _files(store)
    building = tmp_path / "building"
    building.mkdir()
    with pytest.raises(StoreError, match="changed by another ingest during this one; run it"):
        commit_generation(building, store, stale, replace(stale, generation=2))
    assert _files(store) == before
