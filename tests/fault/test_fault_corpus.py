"""Issue #13, fault injection: every corpus input through `globeview info`, `ingest` and
`render` as real processes (`contract.run_globeview`); outputs into a foreign folder, full and
read-only disks, and kill -9 during an ingest.

The contract: the exit status the case expects; on failure exactly one stderr line
``globeview: error: ...`` (no traceback, no GDAL/PROJ chatter); no leftovers (``*.tmp``,
``.*.building-*``, ``.*.old-*``) and no store that looks valid after a failure; the inputs
untouched; for valid inputs a PNG with the terrain where it belongs.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import zygote
from PIL import Image

from .contract import (
    CHATTER,
    DATA,
    MAGENTA_ARG,
    assert_exit,
    assert_one_error_line,
    assert_quiet_success,
    centre_block,
    corpus_cases,
    fill_disk,
    globeview_argv,
    leftovers,
    remount_readonly,
    terrain_kind,
    tree_digest,
    valid_looking_stores,
)
from .corpus import LAND, Case

pytestmark = pytest.mark.slow

CASES = {c.name: c for c in corpus_cases()}
SIZE = "96x64"


def _corpus_root() -> Path:
    return next(c.path for c in CASES.values() if c.name == "float32").parent


def _strict_json(text: str, what: str):
    """Parse ``text`` as standard JSON: NaN and Infinity (which Python's json writes and
    other readers reject) fail the test, naming ``what``."""

    def reject(token: str):
        raise AssertionError(f"{what} holds {token}, which is not JSON")

    return json.loads(text, parse_constant=reject)


def _check_failure(case: Case, res, work, out: Path | None = None) -> None:
    assert_one_error_line(res, case.error_substring)
    assert not leftovers(work.cwd, work.cache), leftovers(work.cwd, work.cache)
    assert not valid_looking_stores(work.cache), "a failed command left a store in the cache"
    if out is not None:
        assert not out.exists(), f"{out} exists after a failure\n{res.describe()}"


# ---------------------------------------------------------------------------------------------
# The corpus x the three commands


@pytest.fixture(scope="module")
def corpus_snapshot() -> dict[str, str]:
    return tree_digest(_corpus_root())


def _inputs_untouched(snapshot: dict[str, str]) -> None:
    # GDAL likes to drop .aux.xml files beside rasters it has computed statistics for.
    assert tree_digest(_corpus_root()) == snapshot, "the command wrote beside its input"


@pytest.mark.parametrize("name", CASES)
def test_info(name: str, work, corpus_snapshot) -> None:
    case = CASES[name]
    res = work.run("info", str(case.path))
    assert_exit(res, case.expected("info"))
    if res.returncode == 0:
        assert_quiet_success(res)
        assert res.stdout.strip(), "info printed nothing"
        res = work.run("info", "--json", str(case.path))
        assert_quiet_success(res)
        _strict_json(res.stdout, "info --json")
    else:
        _check_failure(case, res, work)
    _inputs_untouched(corpus_snapshot)


@pytest.mark.parametrize("name", CASES)
def test_ingest(name: str, work, corpus_snapshot) -> None:
    case = CASES[name]
    out = work.cwd / "store"
    res = work.run("ingest", str(case.path), "--out", str(out))
    assert_exit(res, case.expected("ingest"))
    if res.returncode == 0:
        assert_quiet_success(res)
        assert (out / "manifest.json").is_file()
        _strict_json((out / "manifest.json").read_text(), "the store's manifest.json")
        assert not leftovers(work.cwd), leftovers(work.cwd)
        from globeview.terrain.store.tile_store import TileStore

        store = TileStore.open(out)
        _w, s, _e, n = store.bounds
        assert -90.0 <= s < n <= 90.0, store.bounds
    else:
        _check_failure(case, res, work, out)
    _inputs_untouched(corpus_snapshot)


def _read_png(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"))


def _look_down_at(work, case: Case, lon: float, lat: float, png: Path, *extra: str) -> str:
    """Render ``case`` from 30 km straight above (lon, lat); what the image centre shows."""
    res = work.run(
        "render",
        str(case.path),
        *extra,
        "--out",
        str(png),
        f"--camera={lon},{lat},30000,0,-90",
        "--no-borders",
        "--size",
        SIZE,
        "--background",
        MAGENTA_ARG,
    )
    assert_quiet_success(res)
    return terrain_kind(centre_block(_read_png(png)))


@pytest.fixture(scope="module")
def registry():
    """The installed plugins, discovered once for the module's in-process frames."""
    from globeview.plugins.registry import PluginRegistry

    return PluginRegistry().discover()


class _LookDown:
    """Frames from 30 km straight above places, drawn in this process by the one frame
    pipeline `globeview render` runs (`GlobeSession`, the same defaults: chunked-sse, tau,
    fov; no borders, the magenta background), over the store the command left in the
    test's cache. A process a look costs ~1 CPU-s (a new session, stack and GL context);
    here a look is a frame."""

    def __init__(self, ctx, registry, store) -> None:
        from globeview.app.session import GlobeSession
        from globeview.model.camera import Camera
        from globeview.render.offscreen import OffscreenTarget
        from globeview.terrain.compose.stack import TerrainStack

        self._size = (96, 64)
        self._camera = Camera
        camera = Camera.from_lonlat(0.0, 0.0, 2.0e7, 0.0, -90.0)
        self._session = GlobeSession(
            ctx, TerrainStack.from_stores([store]), camera, registry=registry
        )
        self._session.settings.background = (1.0, 0.0, 1.0)
        self._target = OffscreenTarget(ctx, self._size)

    def kind(self, lon: float, lat: float) -> str:
        self._session.camera = self._camera.from_lonlat(lon, lat, 30000.0, 0.0, -90.0)
        self._session.render(self._target.fbo, self._size)  # uploads the tiles
        self._session.reset_lod()
        self._session.render(self._target.fbo, self._size)
        return terrain_kind(centre_block(self._target.read_rgb()))

    def release(self) -> None:
        self._target.release()
        self._session.release_gl()


@pytest.mark.gl
@pytest.mark.parametrize("name", CASES)
def test_render(name: str, work, corpus_snapshot, globeview_gl, registry, monkeypatch) -> None:
    """Default camera (it frames the source's footprint), as a real process: the image centre
    shows the terrain; then, in this process over the store that command left in the cache,
    views from 30 km straight above the probe (the terrain is there), places beyond the
    footprint (bare ellipsoid) and fill (never drawn as heights). `render --camera` as a
    process is `test_the_no_crs_hint_works`'s (and the CLI's own tests')."""
    case = CASES[name]
    png, stats = work.cwd / "x.png", work.cwd / "s.json"
    common = ("--size", SIZE, "--background", MAGENTA_ARG)
    res = work.run("render", str(case.path), "--out", str(png), "--stats", str(stats), *common)
    assert_exit(res, case.expected("render"))
    if res.returncode != 0:
        _check_failure(case, res, work, png)
        assert not stats.exists()
        _inputs_untouched(corpus_snapshot)
        return
    assert_quiet_success(res)
    assert not leftovers(work.cwd, work.cache), leftovers(work.cwd, work.cache)
    rgb = _read_png(png)
    assert rgb.shape == (64, 96, 3)
    assert _strict_json(stats.read_text(), "render --stats")["tiles_drawn"] > 0
    seen = terrain_kind(centre_block(rgb))
    assert seen == case.kind, f"image centre (default camera) shows {seen}, not {case.kind}"

    assert case.probe is not None
    checks = [(case.probe, {case.kind})]
    checks += [((lon, lat), {kind}) for lon, lat, kind in case.extra_probes]
    checks += [(place, {"other"}) for place in case.outside]
    checks += [(place, {LAND, "other"}) for place in case.fill_places]
    from globeview.terrain.sources import open_source

    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(work.cache))
    cached = sorted((work.cache / "stores").iterdir())
    look = _LookDown(globeview_gl, registry, open_source(case.path))
    try:
        wrong = []
        for (lon, lat), allowed in checks:
            seen = look.kind(lon, lat)
            if seen not in allowed:
                wrong.append(f"({lon:.3f}, {lat:.3f}) shows {seen}, not {sorted(allowed)}")
    finally:
        look.release()
    assert not wrong, "seen from 30 km straight above: " + "; ".join(wrong)
    # The looks drew the store the command left (open_source found it: nothing ingested).
    assert sorted((work.cache / "stores").iterdir()) == cached, "the looks ingested again"
    _inputs_untouched(corpus_snapshot)


@pytest.mark.parametrize("command", ["info", "ingest", "render"])
def test_the_no_crs_hint_works(work, command: str) -> None:
    """The no-CRS error says to add --crs; doing so makes the same file work (the terrain
    lands where the hinted CRS puts it)."""
    case = CASES["no_crs"]
    if command == "info":
        res = work.run("info", str(case.path), "--crs", "EPSG:4326")
    elif command == "ingest":
        res = work.run("ingest", str(case.path), "--out", "store", "--crs", "EPSG:4326")
    else:
        lon, lat = CASES["float32"].probe or (0.0, 0.0)
        seen = _look_down_at(work, case, lon, lat, work.cwd / "x.png", "--crs", "EPSG:4326")
        assert seen == LAND
        return
    assert_quiet_success(res)


@pytest.mark.parametrize("name", CASES)
def test_library_entry_point(name: str, tmp_path: Path, monkeypatch, capfd) -> None:
    """What the window and plugins call in-process (`open_source`: open the DEM, ingest it
    into the cache, open the store): a store for valid inputs; otherwise a `GlobeviewError`
    with a one-line message and never another exception, with nothing on the process's
    stderr (GDAL's C-level chatter included) and nothing left in the cache."""
    from globeview.errors import GlobeviewError
    from globeview.terrain.sources import open_source

    cache = tmp_path / "cache"
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(cache))
    case = CASES[name]
    if case.valid:
        assert open_source(case.path).max_level >= 0
    else:
        with pytest.raises(GlobeviewError) as err:
            open_source(case.path)
        message = str(err.value)
        assert message.strip() and "\n" not in message.strip(), repr(message)
        if case.error_substring:
            assert case.error_substring.lower() in message.lower(), message
        assert not valid_looking_stores(cache)
    assert not leftovers(cache), leftovers(cache)
    stderr = capfd.readouterr().err
    assert not CHATTER.search(stderr), stderr


# ---------------------------------------------------------------------------------------------
# Outputs that belong to someone else


def _user_folder(root: Path, with_manifest: bool) -> Path:
    d = root / "my_project"
    (d / "photos").mkdir(parents=True)
    (d / "photos" / "summit.jpg").write_bytes(bytes(range(256)) * 40)
    (d / "notes.txt").write_text("do not lose me\n")
    if with_manifest:
        (d / "manifest.json").write_text(json.dumps({"name": "my project", "version": 7}))
    return d


@pytest.mark.parametrize("with_manifest", [True, False], ids=["manifest", "no_manifest"])
def test_ingest_into_a_user_folder_leaves_it_untouched(work, with_manifest: bool) -> None:
    """`--out` naming a folder of user files (with an unrelated manifest.json, or none): exit
    2, every file byte for byte as it was, nothing added beside it."""
    folder = _user_folder(work.cwd, with_manifest)
    before = tree_digest(work.cwd)
    res = work.run("ingest", str(CASES["float32"].path), "--out", str(folder))
    assert_one_error_line(res)
    assert tree_digest(work.cwd) == before


def test_ingest_onto_a_user_file_leaves_it_untouched(work) -> None:
    target = work.cwd / "thesis.docx"
    target.write_bytes(b"PK\x03\x04 my thesis")
    before = tree_digest(work.cwd)
    res = work.run("ingest", str(CASES["float32"].path), "--out", str(target))
    assert_one_error_line(res)
    assert tree_digest(work.cwd) == before


def test_render_of_a_user_folder_with_a_manifest_fails_cleanly(work) -> None:
    """A folder holding an unrelated manifest.json given to render as a store."""
    folder = _user_folder(work.cwd, with_manifest=True)
    before = tree_digest(work.cwd)
    res = work.run("render", str(folder), "--out", "x.png", "--size", SIZE)
    assert_one_error_line(res)
    assert tree_digest(work.cwd) == before


def test_render_out_is_a_folder(work) -> None:
    folder = _user_folder(work.cwd, with_manifest=False)
    before = tree_digest(work.cwd)
    res = work.run("render", str(CASES["float32"].path), "--out", str(folder), "--size", SIZE)
    assert_one_error_line(res)
    assert tree_digest(work.cwd) == before


def _copy_of(case_name: str, folder: Path) -> Path:
    src = CASES[case_name].path
    dst = folder / src.name
    dst.write_bytes(src.read_bytes())
    return dst


def test_ingest_out_is_its_own_source(work) -> None:
    """`ingest dem.tif --out dem.tif` (a typo): exit 2, the DEM intact."""
    dem = _copy_of("float32", work.cwd)
    before = tree_digest(work.cwd)
    res = work.run("ingest", str(dem), "--out", str(dem))
    assert_one_error_line(res)
    assert tree_digest(work.cwd) == before


@pytest.mark.gl
def test_render_out_is_its_own_source(work) -> None:
    """`render dem.tif --out dem.tif` (a typo) must not replace the DEM by a picture of it."""
    dem = _copy_of("float32", work.cwd)
    before = tree_digest(work.cwd)
    res = work.run("render", str(dem), "--out", str(dem), "--size", SIZE)
    assert_one_error_line(res)
    assert tree_digest(work.cwd) == before


def test_ingest_with_one_bad_source_among_good_ones(work) -> None:
    """A valid DEM and a broken one together: exit 2 naming the broken one, no store."""
    bad = CASES["truncated"].path
    out = work.cwd / "store"
    res = work.run("ingest", str(CASES["float32"].path), str(bad), "--out", str(out))
    assert_one_error_line(res, bad.name)
    assert not out.exists() and not leftovers(work.cwd)


@pytest.mark.gl
@pytest.mark.parametrize("name", ["text_file", "zero_byte", "directory", "symlink_loop", "missing"])
def test_render_with_a_bad_overlay(work, name: str) -> None:
    """`render --layer X` with a hostile overlay file: exit 2 in one line, no PNG."""
    png = work.cwd / "x.png"
    res = work.run(
        "render",
        str(CASES["float32"].path),
        "--layer",
        str(CASES[name].path),
        "--out",
        str(png),
        "--size",
        SIZE,
    )
    assert_one_error_line(res)
    assert not png.exists() and not leftovers(work.cwd, work.cache)


# ---------------------------------------------------------------------------------------------
# Full and read-only disks (small tmpfs mounts)


def test_ingest_on_a_full_disk(work, mount_tmpfs) -> None:
    """Room for the first levels only (the store needs ~60 kB): ENOSPC midway."""
    disk = mount_tmpfs("full", size="256k")
    fill_disk(disk, leave_bytes=24 * 1024)
    before = tree_digest(disk)
    res = work.run("ingest", str(CASES["float32"].path), "--out", str(disk / "store"))
    assert_one_error_line(res)
    assert tree_digest(disk) == before, "the failed ingest left something on the disk"


def test_render_on_a_full_disk(work, mount_tmpfs) -> None:
    disk = mount_tmpfs("full", size="256k")
    fill_disk(disk)
    before = tree_digest(disk)
    res = work.run(
        "render",
        str(CASES["float32"].path),
        "--out",
        str(disk / "x.png"),
        "--stats",
        str(disk / "s.json"),
        "--size",
        SIZE,
    )
    assert_one_error_line(res)
    assert tree_digest(disk) == before


def test_ingest_on_a_read_only_disk(work, mount_tmpfs) -> None:
    disk = mount_tmpfs("ro", readonly=True)
    res = work.run("ingest", str(CASES["float32"].path), "--out", str(disk / "store"))
    assert_one_error_line(res)
    assert tree_digest(disk) == {}
    assert not leftovers(work.cwd, work.cache)


def test_render_on_a_read_only_disk(work, mount_tmpfs) -> None:
    disk = mount_tmpfs("ro", readonly=True)
    res = work.run(
        "render",
        str(CASES["float32"].path),
        "--out",
        str(disk / "x.png"),
        "--stats",
        str(disk / "s.json"),
        "--size",
        SIZE,
    )
    assert_one_error_line(res)
    assert tree_digest(disk) == {}


def test_render_stats_on_a_read_only_disk(work, mount_tmpfs) -> None:
    """The PNG can be written, the stats cannot: exit 2 in one line, no temporary files."""
    disk = mount_tmpfs("ro", readonly=True)
    res = work.run(
        "render",
        str(CASES["float32"].path),
        "--out",
        str(work.cwd / "x.png"),
        "--stats",
        str(disk / "s.json"),
        "--size",
        SIZE,
    )
    assert_one_error_line(res)
    assert tree_digest(disk) == {}
    assert not leftovers(work.cwd, work.cache)


def test_render_with_a_read_only_cache(work, mount_tmpfs) -> None:
    """GLOBEVIEW_CACHE_DIR on a read-only disk: rendering a DEM (which ingests it into the
    cache) fails in one line and writes nothing."""
    disk = mount_tmpfs("cache", size="1m")
    (disk / "stores").mkdir()
    remount_readonly(disk)
    before = tree_digest(disk)
    png = work.cwd / "x.png"
    res = work.run(
        "render", str(CASES["float32"].path), "--out", str(png), "--size", SIZE, cache=disk
    )
    assert_one_error_line(res)
    assert tree_digest(disk) == before
    assert not png.exists() and not leftovers(work.cwd)


# ---------------------------------------------------------------------------------------------
# kill -9 during an ingest, then the same ingest again


KILL_CASES = [
    # (seed, when): "start" kills 0.05..1.5 s after the command starts (imports, hashing,
    # opening the DEM, building); "build" kills 0..0.8 s after its work folder appears;
    # "replace" does the same to `ingest --force` over a complete store (the old-store swap).
    *((seed, "start") for seed in (1, 2, 3)),
    *((seed, "build") for seed in (4, 5, 6)),
    *((seed, "replace") for seed in (7, 8)),
]


def _wait_for_work_folder(parent: Path, proc: subprocess.Popen, limit_s: float = 30.0) -> None:
    end = time.monotonic() + limit_s
    while time.monotonic() < end and proc.poll() is None:
        if any(".building-" in p.name for p in parent.iterdir()):
            return
        time.sleep(0.005)


@pytest.fixture(scope="module")
def complete_store(tmp_path_factory: pytest.TempPathFactory, seed_dem_store) -> Path:
    """A complete store of N44W072.hgt for the cases that replace one (each works on a
    copy): the one `ingest` writes into a cache, built once per session by `seed_dem_store`
    (~3 CPU-s for an `ingest --out` of its own)."""
    (store,) = (seed_dem_store(tmp_path_factory.mktemp("complete"), DATA / "N44W072.hgt")
                / "stores").iterdir()  # fmt: skip
    assert (store / "manifest.json").is_file()
    return store


@pytest.mark.parametrize(("seed", "when"), KILL_CASES)
def test_ingest_killed_then_rerun(work, seed: int, when: str, request) -> None:
    """SIGKILL at a seeded random moment of an ingest, then the same ingest again: exit 0, a
    store that opens, and nothing left of the killed run."""
    from globeview.terrain.store.tile_store import TileStore

    src = DATA / "N44W072.hgt"
    out = work.cwd / "store"
    rng = random.Random(seed)
    extra = []
    if when == "replace":
        shutil.copytree(request.getfixturevalue("complete_store"), out, symlinks=True)
        assert (out / "manifest.json").is_file()
        extra = ["--force"]
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(work.cache)}
    argv = [*globeview_argv(), "ingest", str(src), "--out", str(out), "--quiet", *extra]
    proc = zygote.popen(
        argv, cwd=work.cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        if when == "start":
            delay = rng.uniform(0.05, 1.5)
        else:
            _wait_for_work_folder(work.cwd, proc)
            delay = rng.uniform(0.0, 0.8)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    # Whatever the kill left, a store that is there must be complete.
    if (out / "manifest.json").exists():
        TileStore.open(out)

    res = work.run("ingest", str(src), "--out", str(out), "--quiet")
    assert_quiet_success(res)
    store = TileStore.open(out)
    assert store.max_level >= 1
    assert not leftovers(work.cwd), f"killed {when} + {delay:.2f} s: {leftovers(work.cwd)}"


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_ingest_interrupted_by_ctrl_c(work, seed: int) -> None:
    """SIGINT (Ctrl-C) while the store is being built: exit 130 with one line, no work folder
    left, and no store unless a complete one."""
    out = work.cwd / "store"
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(work.cache)}
    argv = [*globeview_argv(), "ingest", str(DATA / "N44W072.hgt"), "--out", str(out)]
    proc = zygote.popen(argv, cwd=work.cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _wait_for_work_folder(work.cwd, proc)
    time.sleep(random.Random(seed).uniform(0.0, 0.5))
    if proc.poll() is not None:
        pytest.skip("the ingest finished before the interrupt (machine too fast for this seed)")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    lines = [ln for ln in err.decode("utf-8", "replace").splitlines() if ln.strip()]
    # The progress bar shares stderr; the last line must be the one message.
    assert proc.returncode == 130, err
    assert lines and lines[-1].split("\r")[-1].strip().startswith("globeview: interrupted"), err
    assert b"Traceback" not in err
    assert not leftovers(work.cwd), leftovers(work.cwd)
    if out.exists():  # interrupted inside the final rename: then the store is complete
        from globeview.terrain.store.tile_store import TileStore

        TileStore.open(out)


@pytest.mark.gl
@pytest.mark.parametrize("seed", [21, 22])
def test_render_killed_while_ingesting_then_rerun(work, seed: int) -> None:
    """kill -9 during render's first-time ingest of a DEM into the cache, then the same render:
    exit 0, a PNG, and nothing of the killed run left in the cache."""
    png = work.cwd / "x.png"
    args = ["render", str(DATA / "N44W072.hgt"), "--out", str(png), "--size", SIZE]
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(work.cache)}
    proc = zygote.popen(
        [*globeview_argv(), *args],
        cwd=work.cwd,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    stores = work.cache / "stores"
    end = time.monotonic() + 30.0
    while time.monotonic() < end and proc.poll() is None and not stores.is_dir():
        time.sleep(0.005)
    if stores.is_dir():
        _wait_for_work_folder(stores, proc)
    time.sleep(random.Random(seed).uniform(0.0, 0.8))
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    png.unlink(missing_ok=True)

    res = work.run(*args)
    assert_quiet_success(res)
    assert png.is_file()
    assert not leftovers(work.cwd, work.cache), leftovers(work.cwd, work.cache)
