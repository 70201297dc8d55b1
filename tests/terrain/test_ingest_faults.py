"""Ingest under faults: kill -9 at any point, a disk that fills up, a read-only file system,
Ctrl-C, and a raster far too large. Each leaves one stderr line (exit 2) and nothing behind;
the next ingest cleans what a killed one left, never what a live one is building."""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zygote
from inprocess_cli import run_globeview

from globeview.terrain.ingest.driver import FAULT_ENV, ingest
from globeview.terrain.ingest.safety import build_folder, clean_stale_builds
from globeview.terrain.store.tile_store import TileStore

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
GLOBEVIEW = Path(sys.executable).parent / "globeview"
SMALL = DATA / "craterlake-elev-16bit-30m.tif"  # 14 levels, ~20 window writes, ~2 CPU-s
BIG = DATA / "N44W072.hgt"  # SRTM3, 1201 x 1201: a few MB of levels


def _cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``globeview ARGS`` as a process of its own (the faults kill it or make it exit 2),
    forked from `zygote`'s server: no interpreter start and imports (~1.3 CPU-s) each."""
    e = {**os.environ, **(env or {})}
    return zygote.run([str(GLOBEVIEW), *args], capture_output=True, text=True, timeout=300, env=e)


def _reingest(out: Path) -> subprocess.CompletedProcess:
    """``globeview ingest SMALL --out OUT --quiet`` after a killed one: in this process
    (`inprocess_cli`); the kill is what needs a process of its own, the clean-up does not."""
    return run_globeview(["ingest", str(SMALL), "--out", str(out), "--quiet"])


def _leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name.startswith("."))


def _errors(store: Path) -> list:
    """Every chunk's tile errors (stride errors too) and hmin (store format 7's shards; NaN
    as -1e30 so that equal stores compare equal), in order."""
    with TileStore.open(store) as st:
        return sorted(
            (lv, cy, cx, *(np.nan_to_num(a, nan=-1e30).tolist() for a in (f.errors, f.hmin)))
            for lv, cy, cx, f in st.iter_chunks()
        )


def _files(store: Path) -> dict[str, bytes]:
    """Every file of a store (chunks and shards in their folders) with its bytes."""
    return {
        p.relative_to(store).as_posix(): p.read_bytes()
        for p in sorted(store.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def clean_errors(tmp_path_factory: pytest.TempPathFactory, seed_dem_store) -> list:
    """The tile errors of what ``ingest([SMALL], out)`` writes: the session's
    `seed_dem_store` of SMALL (the same files, byte for byte), not ingested again."""
    (out,) = (seed_dem_store(tmp_path_factory.mktemp("clean"), SMALL) / "stores").iterdir()
    return _errors(out)


@pytest.fixture(scope="module")
def tile5_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A store of SMALL with tiles of 2^5 nodes (not what an ingest with the defaults
    writes: that one replaces it), built once; tests copy it (`_old_store`)."""
    out = tmp_path_factory.mktemp("tile5") / "s"
    ingest([SMALL], out, tile_n=5)
    return out


def _old_store(tile5_store: Path, out: Path) -> None:
    """``out``: a copy of `tile5_store` (its files, not hard links: a test may change them)."""
    shutil.copytree(tile5_store, out)


def _one_error_line(r: subprocess.CompletedProcess) -> str:
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, r.stderr
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("globeview: error: ")
    return lines[0]


# -- kill -9 -----------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("point", ["1", "4", "9", "manifest", "commit", "commit-swap"])
def test_kill9_at_a_point_then_reingest_is_clean(
    tmp_path: Path, clean_errors: list, tile5_store: Path, point: str
) -> None:
    out = tmp_path / "s"
    if point.startswith("commit"):
        _old_store(tile5_store, out)  # a store to be replaced: killed mid-commit
    if point == "commit-swap":  # a store that does not open is replaced whole (two renames)
        next(out.glob("meta/top-*.gvm")).unlink()
    fault = point.removesuffix("-swap")
    r = _cli("ingest", str(SMALL), "--out", str(out), "--quiet", env={FAULT_ENV: f"KILL@{fault}"})
    assert r.returncode == -signal.SIGKILL
    assert _leftovers(tmp_path), "the kill should have left a build folder behind"
    if point == "commit-swap":
        assert not out.exists()  # killed between the two renames: the old store is aside
    elif point == "commit":
        # Killed in the commit of the store's next generation (its new files moved in beside
        # the old ones, manifest.json not switched): the store is still the one it was.
        with TileStore.open(out) as st:
            assert st.tile_n == 5 and st.manifest.generation == 0
    r = _reingest(out)
    assert r.returncode == 0, r.stderr
    assert _leftovers(tmp_path) == []
    with TileStore.open(out) as st:
        st.verify()
    assert _errors(out) == clean_errors


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_kill9_at_a_random_time_then_reingest_is_clean(
    tmp_path: Path, clean_errors: list, seed: int
) -> None:
    out = tmp_path / "s"
    rng = random.Random(seed)
    p = zygote.popen(
        [str(GLOBEVIEW), "ingest", str(SMALL), "--out", str(out), "--quiet"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    # Kill it while it builds: once its build folder exists, after a random part of a build.
    while p.poll() is None and not any(".building-" in n for n in _leftovers(tmp_path)):
        time.sleep(0.005)
    time.sleep(rng.uniform(0.0, 0.3))
    p.send_signal(signal.SIGKILL)
    p.wait()
    r = _reingest(out)
    assert r.returncode == 0, r.stderr
    assert _leftovers(tmp_path) == []
    with TileStore.open(out) as st:
        st.verify()
    assert _errors(out) == clean_errors


@pytest.mark.slow
def test_a_live_build_is_never_cleaned(tmp_path: Path) -> None:
    # This process holds a build folder (and its lock) while another process cleans.
    with build_folder(tmp_path, "s") as (building, _tok):
        (building / "level_00.tif").write_bytes(b"in progress")
        code = "import sys; from pathlib import Path; from globeview.terrain.ingest.safety import "
        code += "clean_stale_builds as c; print(c(Path(sys.argv[1])))"
        r = subprocess.run(
            [sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True
        )
        assert r.returncode == 0, r.stderr
        assert building.is_dir() and (building / "level_00.tif").exists()
        r = _cli("ingest", str(SMALL), "--out", str(tmp_path / "s"), "--quiet")
        assert r.returncode == 0, r.stderr
        assert building.is_dir() and (building / "level_00.tif").exists()
    assert not building.exists()


def test_leftovers_of_older_versions_and_foreign_folders(tmp_path: Path) -> None:
    stale = tmp_path / ".s.building-ab_cd123"  # mkdtemp's name, from before the locks
    stale.mkdir()
    (stale / "level_03.tif").write_bytes(b"x")
    lookalike = tmp_path / ".s.building-zz_zz999"  # same pattern, but not our files
    lookalike.mkdir()
    (lookalike / "thesis.docx").write_text("precious")
    removed = clean_stale_builds(tmp_path)
    assert stale.name in removed and not stale.exists()
    assert (lookalike / "thesis.docx").read_text() == "precious"


# -- disk full, read-only, interrupt ------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("at", ["1", "6", "manifest", "commit"])
def test_injected_disk_full_is_one_line_and_leaves_nothing(
    tmp_path: Path, tile5_store: Path, at: str
) -> None:
    out = tmp_path / "s"
    old = None
    if at == "commit":
        _old_store(tile5_store, out)
        old = _files(out)
    r = _cli("ingest", str(SMALL), "--out", str(out), env={FAULT_ENV: f"ENOSPC@{at}"})
    line = _one_error_line(r)
    assert f"disk full writing {out} (needs about " in line and " MB)" in line
    assert _leftovers(tmp_path) == []
    if old is None:
        assert not out.exists()
    else:  # the store that was there is intact, byte for byte
        assert _files(out) == old


@pytest.mark.slow
def test_injected_read_only_is_one_line(tmp_path: Path) -> None:
    r = _cli("ingest", str(SMALL), "--out", str(tmp_path / "s"), env={FAULT_ENV: "EROFS@2"})
    assert "read-only file system" in _one_error_line(r)
    assert _leftovers(tmp_path) == [] and not (tmp_path / "s").exists()


@pytest.mark.parametrize(
    ("fault", "needle"), [("EIO@2", "Input/output error"), ("EACCES@manifest", "permission denied")]
)
@pytest.mark.slow
def test_other_os_errors_are_one_line(tmp_path: Path, fault: str, needle: str) -> None:
    r = _cli("ingest", str(SMALL), "--out", str(tmp_path / "s"), env={FAULT_ENV: fault})
    assert needle in _one_error_line(r)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_interrupt_during_build_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(FAULT_ENV, "INTERRUPT@3")
    with pytest.raises(KeyboardInterrupt):
        ingest([SMALL], tmp_path / "s")
    assert list(tmp_path.iterdir()) == []


needs_root = pytest.mark.skipif(
    os.geteuid() != 0, reason="mounting a tmpfs needs root (the injected faults run anyway)"
)


def _mount(target: Path, opts: str) -> None:
    target.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(target)], check=True)


@pytest.mark.slow
@needs_root
def test_real_disk_full_tmpfs(tmp_path: Path) -> None:
    """A store that cannot fit on a real 1 MB file system is refused before anything is
    written (store format 7 plans its chunks first: an upper bound of their bytes); a disk
    that fills up during the writes is the injected ENOSPC above."""
    mnt = tmp_path / "small"
    _mount(mnt, "size=1m")
    try:
        r = _cli("ingest", str(BIG), "--out", str(mnt / "s"))
        line = _one_error_line(r)  # not 37 lines of _tiffWriteProc chatter
        assert f"{BIG} is 1201x1201 pixels: its finest level " in line
        assert f"the limit is the free space in {mnt}: " in line and "--max-level" in line
        assert list(mnt.iterdir()) == []
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


@pytest.mark.slow
@needs_root
def test_real_read_only_tmpfs(tmp_path: Path) -> None:
    mnt = tmp_path / "ro"
    _mount(mnt, "ro")
    try:
        r = _cli("ingest", str(SMALL), "--out", str(mnt / "s"))
        assert "Read-only file system" in _one_error_line(r)
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


# -- a raster far too large --------------------------------------------------------------------


@pytest.mark.slow
def test_huge_vrt_is_refused_up_front_within_the_memory_bound(tmp_path: Path) -> None:
    # 2,000,000 x 1,000,000 pixels of a real little GeoTIFF placed in a global grid.
    vrt = tmp_path / "huge.vrt"
    vrt.write_text(
        '<VRTDataset rasterXSize="2000000" rasterYSize="1000000">\n'
        "  <SRS>EPSG:4326</SRS>\n"
        "  <GeoTransform>-180.0, 0.00018, 0.0, 90.0, 0.0, -0.00018</GeoTransform>\n"
        '  <VRTRasterBand dataType="Float32" band="1"><SimpleSource>\n'
        f'    <SourceFilename relativeToVRT="0">{DATA / "topobathy_vancouver.tif"}'
        "</SourceFilename>\n"
        "    <SourceBand>1</SourceBand>\n"
        '    <SrcRect xOff="0" yOff="0" xSize="100" ySize="100"/>\n'
        '    <DstRect xOff="0" yOff="0" xSize="100" ySize="100"/>\n'
        "  </SimpleSource></VRTRasterBand>\n</VRTDataset>\n"
    )
    code = (
        "import resource, subprocess, sys\n"
        "r = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
        "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024\n"
        "print(r.returncode, peak); sys.stdout.write(r.stderr)\n"
    )
    out = tmp_path / "s"
    r = subprocess.run(
        [sys.executable, "-c", code, str(GLOBEVIEW), "ingest", str(vrt), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    head, *err = r.stdout.splitlines()
    rc, peak = (int(v) for v in head.split())
    assert rc == 2 and len(err) == 1, r.stdout
    assert "2000000x1000000 pixels" in err[0] and "the limit is" in err[0]
    assert "--max-level" in err[0]
    assert peak < 1 << 30, f"peak RSS {peak / 2**20:.0f} MiB"
    assert not out.exists() and _leftovers(tmp_path) == []
