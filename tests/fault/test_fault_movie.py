"""`globeview movie` on hostile ground (issue #26 item 5's bad input): a full disk and a
read-only one (small tmpfs mounts, root only), and Ctrl-C mid-movie: one line, exit != 0,
nothing partial left (the movie is written to a temporary and renamed at the end)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import zygote

from .contract import (
    assert_one_error_line,
    corpus_cases,
    fill_disk,
    globeview_argv,
    leftovers,
    tree_digest,
)
from .corpus import ALPS_CENTRE

pytestmark = [pytest.mark.gl, pytest.mark.slow]

CASES = {c.name: c for c in corpus_cases()}
LON, LAT = ALPS_CENTRE
#: Two cameras over the corpus's plateau, 2 s apart.
CAMERAS = f"{LON - 0.3},{LAT - 0.2},60000,0,-90;{LON},{LAT},20000,30,-40"


def movie_args(out: Path, *extra: str) -> list[str]:
    return ["movie", "-o", str(out), *extra, CAMERAS, str(CASES["float32"].path)]


def test_movie_on_a_full_disk(work, mount_tmpfs) -> None:
    """Room for a few kB: ffmpeg meets ENOSPC partway through a 320x240 movie."""
    disk = mount_tmpfs("full", size="256k")
    fill_disk(disk, leave_bytes=16 * 1024)
    before = tree_digest(disk)
    res = work.run(*movie_args(disk / "m.mp4", "--size", "320x240", "--fps", "10"))
    assert_one_error_line(res, "disk full")
    assert tree_digest(disk) == before, "the failed movie left something on the disk"


def test_gif_on_a_read_only_disk(work, mount_tmpfs) -> None:
    disk = mount_tmpfs("ro", readonly=True)
    res = work.run(*movie_args(disk / "m.gif", "--size", "64x48"))
    assert_one_error_line(res, "read-only")
    assert tree_digest(disk) == {}
    assert not leftovers(work.cwd, work.cache)


def test_movie_interrupted_by_ctrl_c(work) -> None:
    """SIGINT once ffmpeg is writing: exit 130 with one line, no movie and no temporary."""
    out = work.cwd / "m.mp4"
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(work.cache)}
    argv = [
        *globeview_argv(),
        *movie_args(out, "--size", "64x48", "--fps", "60", "--seconds", "30"),
    ]
    proc = zygote.popen(argv, cwd=work.cwd, env=env, stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 120
        while time.monotonic() < end and proc.poll() is None and not leftovers(work.cwd):
            time.sleep(0.01)  # the temporary appears once the DEM is ingested
        assert leftovers(work.cwd), "the movie's temporary never appeared"
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["globeview: interrupted"], err
    assert not out.exists() and not leftovers(work.cwd), os.listdir(work.cwd)
    # ffmpeg ran in a session of its own: it must not outlive the command.
    ps = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True).stdout
    assert str(out.parent) not in ps
