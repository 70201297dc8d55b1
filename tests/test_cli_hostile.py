"""The command line against a hostile user (issue #13): every bad argument, output path or
environment ends in exactly one stderr line and exit 2, and leaves nothing behind — no
half-written PNG, no temporary, no lost file of the user's.

Real processes of the installed `globeview` script (forked by `zygote`), each with its own
GLOBEVIEW_CACHE_DIR.
Full-disk and read-only cases use real tmpfs mounts when running as root, and the injectable
fault ``GLOBEVIEW_FAULT_WRITE`` (honoured by `globeview.fileio`) everywhere.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import zygote

GLOBEVIEW = Path(sys.executable).with_name("globeview")
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def globeview(
    *args: str, cache: Path, cwd: Path | None = None, **env: str
) -> subprocess.CompletedProcess:
    full_env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(cache), **env}
    full_env.pop("GLOBEVIEW_DEBUG", None)
    full_env.pop("GLOBEVIEW_FAULT_WRITE", None)
    full_env.update(env)
    return zygote.run(
        [str(GLOBEVIEW), *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=cwd,
        env=full_env,
    )


def one_error_line(res: subprocess.CompletedProcess, code: int = 2) -> str:
    """The single stderr line of a failed command (asserting there is exactly one)."""
    lines = res.stderr.strip().splitlines()
    assert res.returncode == code, (res.returncode, res.stderr)
    assert len(lines) == 1, res.stderr
    return lines[0]


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp" in p.name)


@pytest.fixture(scope="module")
def filled_cache(tmp_path_factory: pytest.TempPathFactory, seed_cache) -> Path:
    """A cache folder holding the embedded stores (copied by `seed_cache` instead of an
    ~5 CPU-s ingest) and what one small render adds to a cache besides them."""
    cache = seed_cache(tmp_path_factory.mktemp("cache"))
    out = tmp_path_factory.mktemp("warm") / "warm.png"
    res = globeview("render", "--out", str(out), "--size", "32x24", cache=cache)
    if res.returncode != 0:
        pytest.fail(f"cannot prepare the embedded stores: {res.stderr}")
    return cache


@contextlib.contextmanager
def tmpfs(folder: Path, options: str) -> Iterator[Path]:
    """A real tmpfs mounted at ``folder`` (root only), unmounted afterwards."""
    folder.mkdir(parents=True, exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)], check=True)
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


# -- the before-stop hook's contract ---------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(
    "args",
    [
        ("render", "--out", "/nonexistent/dir/x.png"),
        ("render", "--camera=nan,nan,nan", "--out", "x.png"),
        ("render", "--tau", "-1", "--out", "x.png"),
        ("info", "/dev/null"),
        ("ingest", "/dev/null", "--out", "store"),
    ],
)
def test_hook_commands_print_one_line_and_exit_2(tmp_path: Path, args: tuple[str, ...]) -> None:
    res = globeview(*args, cache=tmp_path / "cache", cwd=tmp_path)
    assert one_error_line(res).startswith("globeview: error: ")
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "store").exists()


# -- hostile view arguments (item 9) ---------------------------------------------------------
HOSTILE_VIEWS = [
    (("--camera=nan,nan,nan",), "--camera"),
    (("--camera=inf,0,1e7",), "--camera"),
    (("--camera=0,95,1e7",), "latitude"),
    (("--camera=0,-90.5,1e7",), "latitude"),
    (("--camera=0,90.0000001,1e7",), "in -90..90 deg, not 90.0000001"),
    (("--camera=1_0,44,9000",), "--camera must be comma-separated numbers"),
    (("--collapse=0,0,1_0,10",), "--collapse must be comma-separated numbers"),
    (("--camera=0,45,-20000",), "height"),
    (("--camera=0,45,2e9",), "height"),
    (("--camera=0,45,1e7,inf,-90",), "heading"),
    (("--camera=0,45,1e7,0,-120",), "pitch"),
    (("--camera=0,45,1e7,0,-90,nan",), "roll"),
    (("--tau", "0"), "--tau must be a finite number in 0.05..1000 px, not 0"),
    (("--tau", "-1"), "--tau must be a finite number in 0.05..1000 px, not -1"),
    (("--tau", "nan"), "--tau"),
    (("--exaggeration", "1e9"), "--exaggeration"),
    (("--exaggeration", "-2"), "--exaggeration"),
    (("--fov", "0"), "--fov"),
    (("--fov", "-10"), "--fov"),
    (("--fov", "180"), "--fov"),
    (("--collapse=nan,0,10,10",), "--collapse"),
    (("--collapse=0,0,10,100",), "--collapse"),
    (("--collapse=0,0,10,10,0",), "--collapse"),
    (("--size", "0x0"), "--size"),
    (("--size", "99999x99999"), "--size"),
    (("--background=2,nan,0",), "--background"),
    (("--background=0,0",), "--background"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("args", "needle"), HOSTILE_VIEWS)
def test_hostile_view_arguments_are_one_line_with_the_range(
    tmp_path: Path, args: tuple[str, ...], needle: str
) -> None:
    out = tmp_path / "x.png"
    res = globeview("render", "--out", str(out), *args, cache=tmp_path / "cache")
    line = one_error_line(res)
    assert line.startswith("globeview: error: ") and needle in line, line
    assert not out.exists() and not leftovers(tmp_path)


def test_huge_but_finite_heading_is_reduced_not_refused() -> None:
    from globeview.model.camera import Camera

    cam = Camera.from_lonlat(10.0, 20.0, 1e6, 1e300, -45.0, 7.2e12)
    assert all(map(lambda v: v == v, cam.lonlat_hpr()))  # no NaN anywhere


# -- output paths (item 5) ---------------------------------------------------------------------
@pytest.mark.slow
def test_out_into_a_missing_folder(tmp_path: Path) -> None:
    res = globeview("render", "--out", str(tmp_path / "no" / "x.png"), cache=tmp_path / "c")
    line = one_error_line(res)
    assert "does not exist" in line and str(tmp_path / "no") in line


@pytest.mark.slow
def test_out_is_a_directory_leaves_no_temporary(tmp_path: Path) -> None:
    d = tmp_path / "d"
    d.mkdir()
    res = globeview("render", "--out", str(d), cache=tmp_path / "c")
    assert "is a directory" in one_error_line(res)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]
    assert list(d.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize(
    ("out", "stats", "needle"),
    [
        ("x.jpg", None, ".png"),
        ("/dev/null", None, "not a regular file"),
        ("x.png", "x.png", "same file"),
        ("x.png", "missing/s.json", "does not exist"),
        ("x.png", ".", "is a directory"),
        ("", None, "needs a file name"),
    ],
)
def test_bad_output_paths(tmp_path: Path, out: str, stats: str | None, needle: str) -> None:
    args = ["render", "--out", out] + (["--stats", stats] if stats else [])
    res = globeview(*args, cache=tmp_path / "c", cwd=tmp_path)
    assert needle in one_error_line(res)
    assert not (tmp_path / "x.png").exists() and not leftovers(tmp_path)


@pytest.mark.slow
@pytest.mark.gl
def test_full_disk_by_fault_keeps_the_old_png_and_writes_nothing(
    tmp_path: Path, filled_cache: Path
) -> None:
    png, stats = tmp_path / "x.png", tmp_path / "s.json"
    png.write_bytes(b"the user's old picture")
    args = ("render", "--out", str(png), "--stats", str(stats), "--size", "32x24")
    res = globeview(*args, cache=filled_cache, GLOBEVIEW_FAULT_WRITE="enospc")
    assert "disk full" in one_error_line(res)
    assert png.read_bytes() == b"the user's old picture"  # never a lost user file
    assert not stats.exists() and not leftovers(tmp_path)


@pytest.mark.slow
@pytest.mark.gl
def test_png_and_stats_are_written_together(tmp_path: Path, filled_cache: Path) -> None:
    png, stats = tmp_path / "x.png", tmp_path / "s.json"
    res = globeview(
        "render", "--out", str(png), "--stats", str(stats), "--size", "32x24", cache=filled_cache
    )
    assert res.returncode == 0, res.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads(stats.read_text())["tiles_drawn"] > 0
    assert not leftovers(tmp_path) and res.stderr == ""


@pytest.mark.slow
@pytest.mark.gl
@pytest.mark.skipif(not IS_ROOT, reason="a real full tmpfs needs root to mount (fault test runs)")
def test_full_disk_real_mount(tmp_path: Path, filled_cache: Path) -> None:
    with tmpfs(tmp_path / "full", "size=64k") as full:
        # Leave a few KB free: less than the PNG needs.
        (full / "filler").write_bytes(b"\0" * (60 * 1024))
        png, stats = full / "x.png", full / "s.json"
        args = ("render", "--out", str(png), "--stats", str(stats), "--size", "256x192")
        res = globeview(*args, cache=filled_cache)
        assert "disk full" in one_error_line(res)
        assert sorted(p.name for p in full.iterdir()) == ["filler"]


@pytest.mark.slow
@pytest.mark.skipif(not IS_ROOT, reason="a real read-only tmpfs needs root to mount")
def test_read_only_mount_out_and_stats(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "ro", "ro") as ro:
        good = tmp_path / "x.png"
        res = globeview("render", "--out", str(ro / "x.png"), cache=tmp_path / "c")
        assert "read-only" in one_error_line(res)
        # --stats on the read-only mount: refused before rendering, so no PNG either.
        res = globeview(
            "render", "--out", str(good), "--stats", str(ro / "s.json"), cache=tmp_path / "c"
        )
        assert "read-only" in one_error_line(res)
        assert not good.exists()


@pytest.mark.slow
@pytest.mark.skipif(not IS_ROOT, reason="a real read-only tmpfs needs root to mount")
def test_read_only_cache_mount_says_how_to_move_it(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "rocache", "ro") as ro:
        res = globeview("render", "--out", str(tmp_path / "x.png"), cache=ro)
        line = one_error_line(res)
        assert "read-only" in line and "GLOBEVIEW_CACHE_DIR" in line
        assert not (tmp_path / "x.png").exists()


@pytest.mark.slow
def test_cache_that_cannot_be_a_folder_says_how_to_move_it(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    res = globeview("render", "--out", str(tmp_path / "x.png"), cache=blocker / "cache")
    line = one_error_line(res)
    assert "GLOBEVIEW_CACHE_DIR" in line and "not a folder" in line


# -- argparse and argv (items 6, 11) -----------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(
    "args",
    [
        ("render", "--bogus", "--out", "x.png"),
        ("render",),
        ("nonsense-command",),
        ("render", "--out", "x.png", "--tau", "abc"),
        ("bench", "flight"),
    ],
)
def test_argparse_errors_are_one_line(tmp_path: Path, args: tuple[str, ...]) -> None:
    res = globeview(*args, cache=tmp_path / "c", cwd=tmp_path)
    assert one_error_line(res).startswith("globeview: error: ")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("flight", "canyon_run", "--tau", "-1"), "--tau"),
        (("flight", "canyon_run", "--frames", "0"), "--frames"),
        (("flight", "canyon_run", "--fps", "nan"), "--fps"),
        (("flight", "canyon_run", "--fps", "-3"), "--fps"),
        (("soak", "--frames", "-5"), "--frames"),
        (("check", "--frames", "0"), "--frames"),
        (("experiments", "--quick", "--out", "/dev/null"), "not a folder"),
        (("flight", "canyon_run", "--csv", "/nonexistent/x.csv"), "does not exist"),
    ],
)
def test_bench_arguments_are_checked_before_running(
    tmp_path: Path, args: tuple[str, ...], needle: str
) -> None:
    res = globeview("bench", *args, cache=tmp_path / "c")
    assert needle in one_error_line(res)
    assert res.stdout == ""  # refused before the machine line, before any frame


def test_help_still_prints_usage(tmp_path: Path) -> None:
    res = globeview("render", "--help", cache=tmp_path / "c")
    assert res.returncode == 0 and "--camera" in res.stdout


@pytest.mark.slow
def test_negative_camera_without_equals_is_a_value(tmp_path: Path) -> None:
    # Parsed as the value of --camera, so the latitude check (not argparse) answers.
    res = globeview("render", "--camera", "-71,95,9000", "--out", "x.png", cache=tmp_path / "c")
    assert "latitude" in one_error_line(res)
    res = globeview("render", "--background", "-1,0,0", "--out", "x.png", cache=tmp_path / "c")
    assert "--background" in one_error_line(res) and "red" in one_error_line(res)


def test_join_negative_values_unit() -> None:
    from globeview.cli import join_negative_values, route_bare_files

    assert join_negative_values(["render", "--camera", "-71,44,9000", "--out", "x.png"]) == [
        "render",
        "--camera=-71,44,9000",
        "--out",
        "x.png",
    ]
    assert join_negative_values(["--tau", "-1"]) == ["--tau=-1"]
    assert join_negative_values(["--camera", "-x"]) == ["--camera", "-x"]  # not numbers
    assert join_negative_values(["--out", "-1,2"]) == ["--out", "-1,2"]  # not numeric option
    assert route_bare_files(["data/x.hgt"]) == ["gui", "data/x.hgt"]
    assert route_bare_files(["render", "--out", "x.png"]) == ["render", "--out", "x.png"]


@pytest.mark.slow
def test_bare_file_opens_the_window(tmp_path: Path) -> None:
    dem = Path(__file__).resolve().parents[1] / "data" / "N44W072.hgt"
    env = {k: "" for k in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM")}
    res = globeview(str(dem), cache=tmp_path / "c", **env)
    # Without a display: the window's own one-line message, not "invalid choice".
    line = one_error_line(res, code=1)
    assert "no display" in line and "invalid choice" not in res.stderr


# -- GDAL chatter and the last line of defence (item 6) --------------------------------------
@pytest.mark.slow
def test_bad_crs_prints_no_gdal_chatter(tmp_path: Path) -> None:
    dem = Path(__file__).resolve().parents[1] / "data" / "N44W072.hgt"
    for cmd in (("info",), ("ingest", "--out", str(tmp_path / "s"))):
        res = globeview(*cmd, str(dem), "--crs", "EPSG:999999", cache=tmp_path / "c")
        line = one_error_line(res)
        assert "ERROR 1" not in res.stderr and "EPSG:999999" in line


INTERNAL_BUG = (
    "import sys; from globeview import cli; import globeview.cli.info as info; "
    "info.run = lambda args: {}[1]; "
    "sys.exit(cli.main(['info']))"
)


@pytest.mark.slow
def test_internal_error_is_one_line_with_the_traceback_in_the_log(tmp_path: Path) -> None:
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(tmp_path)}
    env.pop("GLOBEVIEW_DEBUG", None)
    res = subprocess.run(
        [sys.executable, "-c", INTERNAL_BUG], capture_output=True, text=True, env=env
    )
    line = one_error_line(res, code=1)
    assert line.startswith("globeview: internal error: KeyError: 1 (details in ")
    log = (tmp_path / "globeview.log").read_text()
    assert "Traceback" in log and "KeyError" in log
    # GLOBEVIEW_DEBUG=1: the traceback itself.
    res = subprocess.run(
        [sys.executable, "-c", INTERNAL_BUG],
        capture_output=True,
        text=True,
        env={**env, "GLOBEVIEW_DEBUG": "1"},
    )
    assert res.returncode == 1 and "Traceback" in res.stderr


MEMORY = (
    "import sys; from globeview import cli; import globeview.cli.info as info; "
    "info.run = lambda args: (_ for _ in ()).throw(MemoryError()); sys.exit(cli.main(['info']))"
)


def test_out_of_memory_is_one_line_exit_2(tmp_path: Path) -> None:
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(tmp_path)}
    env.pop("GLOBEVIEW_DEBUG", None)
    res = subprocess.run([sys.executable, "-c", MEMORY], capture_output=True, text=True, env=env)
    assert "out of memory" in one_error_line(res)
