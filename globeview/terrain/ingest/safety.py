"""Ingest's safety: what ``--out`` is and whether it may be replaced, build folders and their
locks, the atomic commit, stale builds of dead processes, GDAL's chatter on fd 2, and one line
for a failed write (disk full, read-only).

Nothing of the user's is ever lost: only a positively identified globeview store holding
nothing but store files (`globeview.terrain.store.identify`) is replaced or removed, a build
happens in a hidden sibling folder locked with flock for its lifetime (`build_folder`), and
the finished store is renamed into place (`commit`: readers never see a half-built store).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import sys
import tempfile
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import IO

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no stale-build cleaning
    fcntl = None  # type: ignore[assignment]

from globeview.errors import StoreError
from globeview.fileio import describe_os_error
from globeview.paths import cache_dir
from globeview.terrain.ingest.tasks import fault_point
from globeview.terrain.store.backend import RASTER_ERRORS
from globeview.terrain.store.generations import remove_empty_dirs
from globeview.terrain.store.identify import (
    StoreIdentity,
    identify,
    is_store_entry,
    store_files,
)
from globeview.terrain.store.layout import STORE_DIRS
from globeview.terrain.store.schema import FORMAT_VERSION, built_before_vdatums

__all__ = [
    "build_folder",
    "check_target",
    "clean_stale_builds",
    "clear_folder",
    "commit",
    "gdal_quiet",
    "remove_store_dir",
    "tty_stderr",
    "write_error",
]


def _owned_by_cache(out: Path) -> bool:
    """Whether ``out`` is one of globeview's cached stores (rebuilt silently on a format
    change: globeview owns them)."""
    try:
        return out.parent.resolve() == (cache_dir() / "stores").resolve()
    except OSError:
        return False


def check_target(out: Path, force: bool) -> StoreIdentity:
    """What ``out`` is; StoreError when it must not be written (never modifies anything).

    Only a positively identified globeview store (see `identify.identify`) may be replaced,
    and only one holding nothing but store files: a folder with somebody's manifest.json
    and their files is refused, not one byte of it changes.
    """
    ident = identify(out)
    if ident.kind == "file":
        what = "a symbolic link" if out.is_symlink() else "not a directory"
        raise StoreError(f"{out} exists and is {what}; choose another --out")
    if ident.kind == "foreign":
        raise StoreError(f"{out} is not a globeview store, refusing to overwrite it")
    if ident.is_globeview and ident.extra is not None:
        raise StoreError(
            f"{out} is a globeview store but also holds {ident.extra!r}, which globeview did "
            "not write; refusing to replace it"
        )
    if ident.is_globeview and not ident.is_current and not force and not _owned_by_cache(out):
        v = ident.version
        if built_before_vdatums(v):
            raise StoreError(
                f"{out} is a store built before vertical datums (format version {v}, heights"
                " not ellipsoidal); rebuild it with --force"
            )
        newer = isinstance(v, int) and not isinstance(v, bool) and v > FORMAT_VERSION
        who = "a newer globeview" if newer else "an older globeview"
        raise StoreError(
            f"{out} is a store of {who} (format version {str(v)[:20]}; this one writes "
            f"{FORMAT_VERSION}); rebuild it with --force"
        )
    return ident


# Names of build leftovers next to a store NAME: .NAME.lock-T (held with flock while a build
# runs), .NAME.building-T (the store being built), .NAME.old-T (the replaced store between the
# two renames of a commit). Versions before the locks used mkdtemp's 8-character suffixes.
_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?P<kind>lock|building|old)-(?P<tok>[0-9a-f]{12})$")
_LEGACY_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?P<kind>building|old)-(?P<tok>[a-z0-9_]{8})$")


def _leftover_path(parent: Path, name: str, kind: str, tok: str) -> Path:
    return parent / f".{name}.{kind}-{tok}"


def _only_store_files(d: Path) -> bool:
    try:
        return all(
            is_store_entry(d, e.name) and (e.is_file() or e.name in STORE_DIRS) for e in d.iterdir()
        )
    except OSError:
        return False


def remove_store_dir(d: Path) -> None:
    """Remove a store folder file by file, only the files globeview writes; a folder that
    holds anything else is left as it is (never a user's file lost, even in a race)."""
    try:
        for f in store_files(d):
            f.unlink()
        remove_empty_dirs(d)
        d.rmdir()
    except OSError:
        pass


def _try_lock(path: Path) -> int | None:
    """fd holding an exclusive flock on ``path`` if nobody holds it, else None."""
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        # Still the same file (an owner deletes its lock last; a new one may reuse the name)?
        if os.stat(path).st_ino == os.fstat(fd).st_ino:
            return fd
    except OSError:
        pass
    os.close(fd)
    return None


def clean_stale_builds(parent: Path) -> list[str]:
    """Remove what dead ingests left in ``parent``; returns the names removed or restored.

    Liveness is the build's flock: the kernel drops it when its process dies however it
    dies (kill -9, OOM killer), so unlike a recorded pid it cannot be fooled by pid reuse
    and needs no /proc. A live build's folders are never touched. A replaced store that a
    dead commit left as .NAME.old-T is moved back when NAME is missing, else removed (store
    files only).
    """
    if fcntl is None:
        return []
    try:
        entries = [e.name for e in parent.iterdir()]
    except OSError:
        return []
    tokens: dict[tuple[str, str], set[str]] = {}
    for n in entries:
        m = _LEFTOVER.match(n) or _LEGACY_LEFTOVER.match(n)
        if m:
            tokens.setdefault((m["name"], m["tok"]), set()).add(m["kind"])
    done = []
    for (name, tok), _kinds in sorted(tokens.items()):
        lock = _leftover_path(parent, name, "lock", tok)
        fd = _try_lock(lock) if lock.exists() else None
        if lock.exists() and fd is None:
            continue  # a live build (or one that just started): not ours to touch
        try:
            old = _leftover_path(parent, name, "old", tok)
            if old.is_dir():
                out = parent / name
                if not out.exists() and not out.is_symlink():
                    os.replace(old, out)
                    done.append(f"restored {out}")
                elif _only_store_files(old):
                    remove_store_dir(old)
                    done.append(old.name)
            building = _leftover_path(parent, name, "building", tok)
            if building.is_dir() and _only_store_files(building):
                shutil.rmtree(building, ignore_errors=True)
                done.append(building.name)
            if fd is not None:
                lock.unlink(missing_ok=True)
        except OSError:
            pass
        finally:
            if fd is not None:
                os.close(fd)
    return done


@contextlib.contextmanager
def build_folder(parent: Path, name: str) -> Iterator[tuple[Path, str]]:
    """A fresh .NAME.building-T folder in ``parent`` and its token, locked while the context
    lasts; the folder is removed on the way out (it is gone already after a commit)."""
    fd = -1
    for _ in range(20):
        tok = uuid.uuid4().hex[:12]
        lock = _leftover_path(parent, name, "lock", tok)
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_RDWR, 0o644)
        if fcntl is None:
            break
        fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            if os.stat(lock).st_ino == os.fstat(fd).st_ino:
                break  # a cleaner did not remove it between our create and our lock
        except FileNotFoundError:
            pass
        os.close(fd)
        fd = -1
    if fd < 0:
        raise StoreError(f"cannot lock a build folder in {parent}")
    building = _leftover_path(parent, name, "building", tok)
    try:
        building.mkdir()
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(building, 0o777 & ~umask)
        yield building, tok
    finally:
        shutil.rmtree(building, ignore_errors=True)
        lock.unlink(missing_ok=True)
        os.close(fd)


# GDAL's libtiff prints write errors ("_tiffWriteProc: No space left on device.") straight to
# file descriptor 2 from its compression threads, bypassing rasterio's error handler and
# CPL_LOG, so only a descriptor-level redirect keeps them off the terminal. What was
# captured is replayed afterwards except these lines (anything else printed meanwhile, by
# another thread of the process, still appears).
_GDAL_NOISE = re.compile(r"^(_tiff\w+|TIFF\w+|ERROR \d+|Warning \d+|\w+\.tif:).*$")
_stderr_lock = threading.Lock()
_stderr_depth = 0
_stderr_saved: int | None = None
_stderr_file: IO[bytes] | None = None


@contextlib.contextmanager
def gdal_quiet() -> Iterator[list[str]]:
    """Redirect fd 2 for the block; yields a list that receives the dropped GDAL lines."""
    global _stderr_depth, _stderr_saved, _stderr_file
    dropped: list[str] = []
    with _stderr_lock:
        if _stderr_depth == 0:
            try:
                sys.stderr.flush()
                _stderr_file = tempfile.TemporaryFile()  # noqa: SIM115 - closed on exit
                _stderr_saved = os.dup(2)
                os.dup2(_stderr_file.fileno(), 2)
            except (OSError, ValueError, AttributeError):  # no fd 2, or sys.stderr is None
                _stderr_file, _stderr_saved = None, None
        _stderr_depth += 1
    try:
        yield dropped
    finally:
        with _stderr_lock:
            _stderr_depth -= 1
            if _stderr_depth == 0 and _stderr_saved is not None and _stderr_file is not None:
                with contextlib.suppress(OSError, ValueError, AttributeError):
                    sys.stderr.flush()
                os.dup2(_stderr_saved, 2)
                os.close(_stderr_saved)
                _stderr_file.seek(0)
                text = _stderr_file.read().decode("utf-8", "replace")
                _stderr_file.close()
                _stderr_saved, _stderr_file = None, None
                keep: list[str] = []
                for line in text.splitlines():
                    (dropped if _GDAL_NOISE.match(line) else keep).append(line)
                if keep:
                    with contextlib.suppress(OSError, ValueError, AttributeError):
                        sys.stderr.write("\n".join(keep) + "\n")


def tty_stderr() -> IO[str] | None:
    """A stream on the real stderr (for the progress bar while fd 2 is redirected)."""
    if _stderr_saved is None:
        return None
    return os.fdopen(os.dup(_stderr_saved), "w", closefd=True)


def _disk_full(dropped: list[str], where: Path) -> bool:
    """Whether a failed raster write was the disk filling up: libtiff said so, or there is
    not room for one more compressed block."""
    if any("No space left" in line or "Disk quota" in line for line in dropped):
        return True
    try:
        st = os.statvfs(where)
        return st.f_bavail * st.f_frsize < 1 << 20
    except OSError:
        return False


def clear_folder(folder: Path) -> None:
    """Remove the store files in a building folder (links of a refused update)."""
    for f in store_files(folder):
        f.unlink(missing_ok=True)
    remove_empty_dirs(folder)


def write_error(
    exc: BaseException, dropped: list[str], out: Path, parent: Path, megabytes: int
) -> StoreError:
    """One line for a failed build (the building folder is removed by `build_folder`)."""
    if isinstance(exc, StoreError):
        return exc
    code = getattr(exc, "errno", None)
    if code in (errno.ENOSPC, errno.EDQUOT) or (
        isinstance(exc, RASTER_ERRORS) and _disk_full(dropped, parent)
    ):
        return StoreError(f"disk full writing {out} (needs about {megabytes} MB)")
    if code == errno.EROFS or any("Read-only file system" in line for line in dropped):
        return StoreError(f"cannot write the store {out}: {parent} is on a read-only file system")
    if isinstance(exc, OSError) and not isinstance(exc, RASTER_ERRORS) and exc.errno:
        return StoreError(describe_os_error(exc, out))
    text = getattr(exc, "strerror", None) or str(exc).strip().splitlines()[0:1]
    if isinstance(text, list):
        text = text[0] if text else type(exc).__name__
    return StoreError(f"cannot write the store {out}: {text}")


def commit(tmp: Path, out: Path, tok: str) -> None:
    """Move the finished store into place. ``out`` is checked again now (a build takes
    time): an old store is moved aside, the new one renamed in, and only then is the old
    one removed; if the second rename fails the old store is put back."""
    ident = identify(out)
    if ident.kind in ("absent", "empty"):
        # rename(2) replaces an empty folder atomically and fails on a non-empty one.
        os.replace(tmp, out)
        return
    if not ident.is_globeview or ident.extra is not None:
        raise StoreError(f"{out} changed during the build and is not a globeview store now")
    old = _leftover_path(out.parent, out.name, "old", tok)
    os.replace(out, old)
    try:
        fault_point("commit")
        os.replace(tmp, out)
    except BaseException:
        os.replace(old, out)
        raise
    remove_store_dir(old)
