"""Writing user files safely: check output paths before the work, write atomically after it.

Pure standard library (any layer may use it). The contract for every command that writes a
file the user named:

1. `check_output_file` before the expensive work, so a bad ``--out`` fails in one line at
   once instead of after a minute of rendering;
2. `atomic_outputs` (or `atomic_write_bytes` for one file) to write: each output goes to a
   temporary file in its own folder, and only when *all* of them were written completely are
   they moved over their targets (``os.replace``, atomic on one file system). On any error,
   Ctrl-C included, every temporary is removed and no target has changed;
3. OS errors come out as a one-line `GlobeviewError` (`describe_os_error`): "disk full
   writing x.png", "cannot write x.png: read-only file system", ...

Fault injection (tests without root, where a real full or read-only mount cannot be made):
``GLOBEVIEW_FAULT_WRITE=enospc`` (or ``erofs``, ``eacces``, ``eio``) makes `atomic_outputs`
fail as that OS error after the temporaries were written, before anything is committed,
exactly like a disk filling up during the last write.
"""

from __future__ import annotations

import errno
import os
import secrets
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path

from globeview.errors import GlobeviewError

#: Environment variable naming an OS error that `atomic_outputs` raises (see module doc).
FAULT_ENV = "GLOBEVIEW_FAULT_WRITE"
_FAULTS = {
    "enospc": errno.ENOSPC,
    "erofs": errno.EROFS,
    "eacces": errno.EACCES,
    "eio": errno.EIO,
}


class OutputError(GlobeviewError):
    """An output file cannot be written (bad path, full disk, read-only folder...)."""


def describe_os_error(exc: OSError, path: str | os.PathLike) -> str:
    """One line for a person about an OS error met while writing ``path``."""
    code = exc.errno
    if code in (errno.ENOSPC, errno.EDQUOT):
        return f"disk full writing {path} (free some space or write elsewhere)"
    if code == errno.EROFS:
        return f"cannot write {path}: read-only file system"
    if code in (errno.EACCES, errno.EPERM):
        return f"cannot write {path}: permission denied"
    if code == errno.ENOENT:
        folder = Path(path).parent
        if folder.is_dir():  # e.g. /proc: there, but no file can be made in it
            return f"cannot write {path}: folder {folder} is not writable ({exc.strerror})"
        return f"cannot write {path}: folder {folder} does not exist"
    if code == errno.EISDIR:
        return f"cannot write {path}: it is a directory"
    if code == errno.ENAMETOOLONG:
        return f"cannot write {path}: file name too long"
    reason = exc.strerror or type(exc).__name__
    return f"cannot write {path}: {reason}"


def _folder_problem(folder: Path) -> str | None:
    """Why files cannot be created in ``folder``, or None if they can (as far as we can tell
    without writing: existence, type, read-only mount, permissions)."""
    if not folder.exists():
        return f"folder {folder} does not exist"
    if not folder.is_dir():
        return f"{folder} is not a folder"
    try:
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            return f"folder {folder} is on a read-only file system"
    except OSError:
        pass
    # os.access honours read-only mounts and, for non-root users, the permission bits.
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"folder {folder} is not writable (permission denied)"
    return None


def check_output_file(
    path: str | os.PathLike, option: str = "--out", suffixes: Sequence[str] = ()
) -> Path:
    """Check, before any work, that ``path`` can become a file the user asked for.

    Refuses (`OutputError`, one line naming ``option``): an empty name, an existing
    directory, an existing non-regular file (a device such as /dev/null would be replaced),
    a name without one of ``suffixes`` (lower-case, e.g. ``(".png",)``; empty: any), a folder
    that does not exist, is not a folder, is read-only or not writable. Returns the path.
    """
    text = os.fspath(path)
    if not text.strip():
        raise OutputError(f"{option} needs a file name")
    p = Path(text)
    try:
        return _check_output_file(p, option, suffixes)
    except OSError as exc:  # e.g. ENAMETOOLONG or ELOOP from stat() on the name itself
        raise OutputError(f"{option}: {describe_os_error(exc, p)}") from None


#: Bytes a temporary's name adds to its target's (``.NAME.PID-XXXXXXXX.tmp``).
_TEMP_NAME_EXTRA = 24


def _check_output_file(p: Path, option: str, suffixes: Sequence[str]) -> Path:
    folder = p.parent if str(p.parent) else Path(".")
    try:
        name_max = os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255
    if len(os.fsencode(p.name)) + _TEMP_NAME_EXTRA > name_max:
        raise OutputError(
            f"{option} {p}: file name too long (at most {name_max - _TEMP_NAME_EXTRA} bytes)"
        )
    if p.is_dir():
        raise OutputError(f"{option} {p} is a directory; give a file name, e.g. {p / 'out'}")
    if p.exists() and not p.is_file():
        raise OutputError(f"{option} {p} exists and is not a regular file")
    if suffixes and p.suffix.lower() not in suffixes:
        raise OutputError(f"{option} {p} must end in {' or '.join(suffixes)}")
    problem = _folder_problem(folder)
    if problem is not None:
        raise OutputError(f"{option} {p}: {problem}")
    return p


def writable_folder_problem(folder: str | os.PathLike) -> str | None:
    """Why ``folder`` (or, if missing, its nearest existing ancestor, where it would be
    created) cannot receive files; None when it can."""
    p = Path(folder).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return _folder_problem(p)


def _temp_beside(target: Path) -> Path:
    """Create an empty temporary file next to ``target`` (same folder, so os.replace is an
    atomic rename) and return its path. Created with O_EXCL and mode 0666 less the umask, so
    the final file gets the permissions a plain open() would have given it."""
    for _ in range(100):
        tmp = target.with_name(f".{target.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(target))


def _injected_fault(path: Path) -> None:
    name = os.environ.get(FAULT_ENV, "").strip().lower()
    if name:
        code = _FAULTS.get(name, errno.EIO)
        raise OSError(code, os.strerror(code), str(path))


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _remove_quietly(paths: Sequence[Path]) -> None:
    for tmp in paths:
        with suppress(OSError):
            tmp.unlink(missing_ok=True)


@contextmanager
def atomic_outputs(targets: Sequence[str | os.PathLike]) -> Iterator[list[Path]]:
    """Write several files all-or-nothing.

    Yields one temporary path per target (same folder, already created empty); the body
    writes each completely. On a normal exit every temporary replaces its target; if the body
    raises anything (Ctrl-C included) or a write fails, every temporary is removed and no
    target is touched. OS errors become a one-line `OutputError`; other exceptions propagate.
    (Only the final renames are not all-or-nothing together: they run after every byte is
    on disk and a rename within a folder needs no space, so only a folder vanishing or
    changing permission between two renames could leave the first target replaced.)

    Example::

        with atomic_outputs([png, stats]) as (png_tmp, stats_tmp):
            image.save(png_tmp, format="PNG")
            stats_tmp.write_text(text)
    """
    paths = [Path(t) for t in targets]
    temps: list[Path] = []
    # The output an OS error is about: known while creating, syncing and committing; while
    # the caller writes, the one whose temporary the error names (else all of them).
    current: str | Path = ", ".join(map(str, paths))
    try:
        for p in paths:
            current = p
            temps.append(_temp_beside(p))
        current = ", ".join(map(str, paths))
        yield list(temps)
        for p, tmp in zip(paths, temps, strict=True):
            current = p
            _injected_fault(p)
            _fsync(tmp)  # a full disk may only show when the data reaches it
        # Commit: every file is complete now; renames within a folder do not run out of space.
        for p, tmp in zip(paths, temps, strict=True):
            current = p
            os.replace(tmp, p)
    except OSError as exc:
        _remove_quietly(temps)
        named = {str(t): p for p, t in zip(paths, temps, strict=False)}.get(str(exc.filename))
        raise OutputError(describe_os_error(exc, named or current)) from None
    except BaseException:
        _remove_quietly(temps)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see `atomic_outputs`); returns the path."""
    with atomic_outputs([path]) as (tmp,), open(tmp, "wb") as f:
        f.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see `atomic_outputs`); returns the path."""
    return atomic_write_bytes(path, text.encode(encoding))
