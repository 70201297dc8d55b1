"""The issue #13 contract as reusable checks: run `globeview` as a real process (forked from
the pre-warmed `zygote` server: its own process, exit status and stderr, without the
interpreter start; ``GV_TEST_ZYGOTE=0`` makes each a plain subprocess), then judge its exit
status, its stderr, what it left on disk and what it drew."""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
import zygote

from .corpus import LAND, WATER, Case, make_corpus

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "data"
TIMEOUT_S = 120

# Names a failed or finished command must not leave: render's "x.png.tmp", ingest's
# ".store.building-*" work folder and ".store.old-*" replaced store, any "*.part".
LEFTOVER = re.compile(r"(\.tmp$|\.part$|\.building-|\.old-)")
# GDAL/PROJ chatter and Python noise that must never reach the user's terminal.
CHATTER = re.compile(r"Traceback|^ERROR \d+:|^Warning \d+:|Warning:|^\s+File \"", re.MULTILINE)


@cache
def corpus_cases() -> tuple[Case, ...]:
    """The corpus, written once per test process into a temporary folder (removed at exit)."""
    root = Path(tempfile.mkdtemp(prefix="globeview-fault-corpus-"))
    atexit.register(shutil.rmtree, root, True)
    return tuple(make_corpus(root))


def globeview_argv() -> list[str]:
    """The installed console script next to this Python, else ``python -m globeview``."""
    script = Path(sys.executable).with_name("globeview")
    return [str(script)] if script.exists() else [sys.executable, "-m", "globeview"]


@dataclass
class Result:
    argv: list[str]
    returncode: int
    stdout: str
    stderr: str

    def describe(self) -> str:
        return f"$ {' '.join(self.argv)}\nexit {self.returncode}\nstderr:\n{self.stderr[-3000:]}"


def run_globeview(
    args: list[str], cwd: Path, cache_dir: Path, timeout: float = TIMEOUT_S
) -> Result:
    """Run ``globeview ARGS`` in ``cwd`` with its cache in ``cache_dir``."""
    argv = [*globeview_argv(), *args]
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(cache_dir)}
    try:
        p = zygote.run(argv, cwd=cwd, env=env, capture_output=True, timeout=timeout)
    except subprocess.TimeoutExpired as exc:
        err = (exc.stderr or b"").decode("utf-8", "replace")
        raise AssertionError(
            f"$ {' '.join(argv)}\nstill running after {timeout} s\n{err}"
        ) from None
    return Result(
        argv,
        p.returncode,
        p.stdout.decode("utf-8", "replace"),
        p.stderr.decode("utf-8", "replace"),
    )


def assert_exit(res: Result, allowed: tuple[int, ...]) -> None:
    assert res.returncode in allowed, f"expected exit {allowed}\n{res.describe()}"


def assert_one_error_line(res: Result, substring: str | None = None) -> None:
    """Exit 2 and exactly one non-empty stderr line, ``globeview: error: ...``."""
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2, f"expected exit 2\n{res.describe()}"
    assert len(lines) == 1, f"expected one stderr line, got {len(lines)}\n{res.describe()}"
    assert lines[0].startswith("globeview: error: "), res.describe()
    assert not CHATTER.search(res.stderr), res.describe()
    if substring is not None:
        assert substring.lower() in lines[0].lower(), f"want {substring!r}\n{res.describe()}"


def assert_quiet_success(res: Result) -> None:
    """Exit 0 with no traceback, warning or GDAL/PROJ message on stderr (a progress bar is
    fine)."""
    assert res.returncode == 0, res.describe()
    assert not CHATTER.search(res.stderr), f"noise on stderr\n{res.describe()}"


def leftovers(*roots: Path) -> list[str]:
    """Paths under ``roots`` whose names mark half-written work."""
    found = []
    for root in roots:
        if not root.exists():
            continue
        for dirpath, dirnames, filenames in os.walk(root):
            for name in dirnames + filenames:
                if LEFTOVER.search(name):
                    found.append(os.path.join(dirpath, name))
    return found


def valid_looking_stores(root: Path) -> list[str]:
    """Folders under ``root`` holding a manifest.json (a store that looks usable)."""
    if not root.exists():
        return []
    return [str(p.parent) for p in root.rglob("manifest.json")]


def tree_digest(root: Path) -> dict[str, str]:
    """{relative path: sha256 of content, or 'dir'/'link'} of everything under ``root``."""
    out: dict[str, str] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            rel = str(p.relative_to(root))
            if p.is_symlink():
                out[rel] = "link:" + os.readlink(p)
            elif p.is_dir():
                out[rel] = "dir"
            else:
                out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


# ---------------------------------------------------------------------------------------------
# Pixels

MAGENTA_ARG = "1,0,1"  # --background: never a terrain colour


def terrain_kind(rgb: np.ndarray) -> str:
    """What a small block of pixels shows: 'background', LAND (the brown plateau), WATER (the
    blue sea bed) or 'other' (the green 0 m ellipsoid where there is no data, lines, ...).

    Judged from the block's median colour, by channel order only, so lighting and fog (which
    scale and haze the colour) do not change the verdict: rendered, the 2200..2800 m plateau is
    about (114, 87, 63), the -110 m sea bed (83, 128, 169), bare ellipsoid (72, 115, 89).
    """
    r, g, b = (float(v) for v in np.median(rgb.reshape(-1, 3).astype(np.float64), axis=0))
    if r > 200 and b > 200 and g < 60:
        return "background"
    if r > g + 10 and r > b + 20:
        return LAND
    if b > g + 15 and b > r + 40:
        return WATER
    return "other"


def centre_block(rgb: np.ndarray, half: int = 2) -> np.ndarray:
    h, w = rgb.shape[:2]
    return rgb[h // 2 - half : h // 2 + half + 1, w // 2 - half : w // 2 + half + 1]


# ---------------------------------------------------------------------------------------------
# Disk faults


@contextlib.contextmanager
def tmpfs(mountpoint: Path, size: str = "256k", readonly: bool = False) -> Iterator[Path]:
    """A small tmpfs mounted at ``mountpoint`` (root only); unmounted afterwards. Raises
    PermissionError/OSError when it cannot be mounted (the caller skips)."""
    mountpoint.mkdir(parents=True, exist_ok=True)
    opts = f"size={size}" + (",ro" if readonly else "")
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(mountpoint)],
        capture_output=True,
        text=True,
    )
    if r.returncode != 0:
        raise OSError(f"cannot mount a tmpfs: {r.stderr.strip()}")
    try:
        yield mountpoint
    finally:
        subprocess.run(["umount", "-l", str(mountpoint)], capture_output=True)


def remount_readonly(mountpoint: Path) -> None:
    subprocess.run(["mount", "-o", "remount,ro", str(mountpoint)], check=True)


def fill_disk(mountpoint: Path, leave_bytes: int = 0) -> Path:
    """Fill the file system of ``mountpoint`` with one file, leaving about ``leave_bytes``."""
    st = os.statvfs(mountpoint)
    free = st.f_bavail * st.f_frsize
    filler = mountpoint / "filler.bin"
    with open(filler, "wb", buffering=0) as f, contextlib.suppress(OSError):
        f.write(b"\xa5" * max(free - leave_bytes, 0))
        while leave_bytes == 0:  # top up whatever block rounding left, until ENOSPC
            f.write(b"\xa5" * 512)
    return filler
