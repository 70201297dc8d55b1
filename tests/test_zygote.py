"""The fork server of the CLI tests (`zygote`) gives what a plain `globeview` subprocess gives,
on the cases the fault corpus checks: the exit status, stdout and stderr (an error line, an
argparse complaint, a success), a picture drawn through EGL in the child, Ctrl-C mid-ingest
(exit 130, one line) and kill -9 (killed by SIGKILL, nothing but what the command wrote); and it
falls back to a plain subprocess where forking could not be the same (GV_TEST_ZYGOTE=0, a
variable read at start-up)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zygote
from fault.corpus import ALPS, plateau, write_raster
from PIL import Image

from globeview.app.testing import PluginSite, plugin_manifest

pytestmark = pytest.mark.slow  # each case starts a plain `globeview` too (~1 CPU-s)

REPO = Path(__file__).resolve().parent.parent
DEM = REPO / "data" / "N44W072.hgt"
SCRIPT = str(zygote.CONSOLE_SCRIPT)


def _env(tmp: Path) -> dict[str, str]:
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(tmp / "cache")}
    env.pop("GLOBEVIEW_DEBUG", None)
    return env


def _both(argv: list[str], tmp: Path) -> tuple[subprocess.CompletedProcess, ...]:
    env = _env(tmp)
    plain = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=tmp, timeout=300)
    assert zygote.forkable(argv, env)
    forked = zygote.run(argv, capture_output=True, text=True, env=env, cwd=tmp, timeout=300)
    return plain, forked


@pytest.mark.parametrize(
    "args",
    [
        ["info", "no-such-file.tif"],  # a GlobeviewError: one line, exit 2
        ["render", "--camera", "1,2", "--out", "x.png"],  # argparse's complaint, exit 2
        ["info", "--json", str(DEM)],  # a success that prints
        ["ingest", str(DEM)],  # a refusal after the subcommand's imports
    ],
    ids=["error", "argparse", "info", "refusal"],
)
@pytest.mark.parametrize("form", ["script", "module"])
def test_the_same_as_a_plain_subprocess(args: list[str], form: str, tmp_path: Path) -> None:
    head = [SCRIPT] if form == "script" else [sys.executable, "-m", "globeview"]
    plain, forked = _both([*head, *args], tmp_path)
    assert (forked.returncode, forked.stdout, forked.stderr) == (
        plain.returncode,
        plain.stdout,
        plain.stderr,
    )


@pytest.mark.gl
def test_a_render_through_egl_draws_the_same_picture(tmp_path: Path) -> None:
    env = _env(tmp_path)
    dem = write_raster(tmp_path / "alps.tif", plateau(64, 96), ALPS, "EPSG:4326", dtype="float32")
    view = ["--size", "64x48", "--camera=9,46.25,60000,0,-60", "--no-borders"]
    pictures = []
    for how, run in (("plain", subprocess.run), ("forked", zygote.run)):
        argv = [SCRIPT, "render", str(dem), "-o", f"{how}.png", *view]
        res = run(argv, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
        assert res.returncode == 0 and res.stderr == "", (how, res.stderr)
        assert res.stdout.startswith(f"wrote {how}.png (64x48; "), res.stdout
        pictures.append(np.asarray(Image.open(tmp_path / f"{how}.png")))
    assert pictures[0].shape[:2] == (48, 64)
    assert np.array_equal(pictures[0], pictures[1])


def _wait_for(check: Callable[[], bool], proc, limit_s: float = 60.0) -> None:
    end = time.monotonic() + limit_s
    while time.monotonic() < end and proc.poll() is None and not check():
        time.sleep(0.005)


def _building(folder: Path) -> bool:
    return any(".building-" in p.name for p in folder.iterdir())


@pytest.mark.parametrize("how", ["plain", "forked"])
def test_ctrl_c_mid_ingest_is_exit_130_and_one_line(tmp_path: Path, how: str) -> None:
    argv = [SCRIPT, "ingest", str(DEM), "--out", str(tmp_path / "store")]
    start = subprocess.Popen if how == "plain" else zygote.popen
    proc = start(
        argv, env=_env(tmp_path), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert isinstance(proc, zygote.ZygoteProcess) == (how == "forked")
    _wait_for(lambda: _building(tmp_path), proc)
    if proc.poll() is not None:
        pytest.skip("the ingest finished before the interrupt")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    text = err.decode()
    assert proc.returncode == 130, text
    assert text.splitlines()[-1].split("\r")[-1] == "globeview: interrupted", text
    assert "Traceback" not in text


@pytest.mark.parametrize("how", ["plain", "forked"])
def test_kill_9_is_death_by_sigkill(tmp_path: Path, how: str) -> None:
    argv = [SCRIPT, "ingest", str(DEM), "--out", str(tmp_path / "store"), "--quiet"]
    start = subprocess.Popen if how == "plain" else zygote.popen
    proc = start(
        argv, env=_env(tmp_path), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    _wait_for(lambda: _building(tmp_path), proc)
    proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL, err
    assert b"Traceback" not in err


def test_commands_run_apart_and_at_once(tmp_path: Path) -> None:
    """Two forked commands at a time, each with its own folder, environment and result."""
    procs = []
    for name in ("a", "b"):
        folder = tmp_path / name
        folder.mkdir()
        env = {**_env(folder), "GLOBEVIEW_CACHE_DIR": str(folder / "cache")}
        procs.append(
            zygote.popen(
                [SCRIPT, "info", f"{name}.tif"], env=env, cwd=folder, stderr=subprocess.PIPE
            )
        )
    errors = [p.communicate(timeout=120)[1].decode() for p in procs]
    assert [p.returncode for p in procs] == [2, 2]
    assert "a.tif" in errors[0] and "b.tif" in errors[1], errors


def test_what_cannot_be_forked_is_a_plain_subprocess(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    env = _env(tmp_path)
    argv = [SCRIPT, "--version"]
    assert zygote.forkable(argv, env)
    assert zygote.forkable(argv, {**env, "GLOBEVIEW_CONFIG_DIR": str(tmp_path)})
    assert zygote.forkable(argv, {**env, "PYTHONPATH": str(tmp_path)})  # put on sys.path
    assert zygote.forkable(argv, {**env, "CPL_LOG": os.devnull})  # what main sets itself
    monkeypatch.setattr(zygote, "_warned", set())
    with pytest.warns(UserWarning, match="plain subprocess.*LC_ALL"):
        assert not zygote.forkable(argv, {**env, "LC_ALL": "C.UTF-8"})  # the streams' encoding
    with pytest.warns(UserWarning, match="GDAL_DATA"):
        assert not zygote.forkable(argv, {**env, "GDAL_DATA": str(tmp_path)})  # read at import
    with pytest.warns(UserWarning, match="PYTHONSAFEPATH"):
        assert not zygote.forkable(argv, {**env, "PYTHONSAFEPATH": "1"})  # the start's sys.path
    assert not zygote.forkable([sys.executable, "-c", "pass"], env)
    monkeypatch.setenv(zygote.SWITCH, "0")
    assert not zygote.forkable(argv, {**env, zygote.SWITCH: "0"})
    res = zygote.run(argv, capture_output=True, text=True, env=env)
    assert res.returncode == 0 and res.stdout.startswith("globeview "), res


def test_a_plugin_on_pythonpath_is_found_as_by_a_plain_subprocess(
    tmp_path: Path, plugin_site: PluginSite
) -> None:
    """PYTHONPATH's folders go on the forked command's sys.path as a fresh interpreter puts
    them: an installed plugin there (a dist-info and its entry point) is listed the same."""
    manifest = plugin_manifest("gvt-zygote-probe", "gvt_zygote_probe")
    plugin_site.add("gvt_zygote_probe", manifest, {"impl": "class Provider:\n    pass\n"})
    env = {**_env(tmp_path), "PYTHONPATH": f"{plugin_site.root}{os.pathsep}"}
    env["GLOBEVIEW_CONFIG_DIR"] = str(tmp_path / "config")
    argv = [SCRIPT, "plugins", "list"]
    plain = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=tmp_path)
    assert zygote.forkable(argv, env)
    forked = zygote.run(argv, capture_output=True, text=True, env=env, cwd=tmp_path)
    assert "gvt-zygote-probe" in plain.stdout, plain.stdout + plain.stderr
    assert (forked.returncode, forked.stdout, forked.stderr) == (
        plain.returncode,
        plain.stdout,
        plain.stderr,
    )
