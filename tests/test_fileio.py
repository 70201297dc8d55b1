"""`globeview.fileio`: output paths checked before the work, several outputs written
all-or-nothing, OS errors as one line; nothing left behind on any error, Ctrl-C included."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from globeview.errors import GlobeviewError
from globeview.fileio import (
    FAULT_ENV,
    OutputError,
    atomic_outputs,
    atomic_write_bytes,
    check_output_file,
    describe_os_error,
    writable_folder_problem,
)


def names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_outputs_appear_together_with_ordinary_permissions(tmp_path: Path) -> None:
    a, b = tmp_path / "a.png", tmp_path / "b.json"
    with atomic_outputs([a, b]) as (ta, tb):
        ta.write_bytes(b"png")
        tb.write_text("{}")
        assert not a.exists() and not b.exists()  # nothing visible until both are done
    assert a.read_bytes() == b"png" and b.read_text() == "{}"
    assert names(tmp_path) == ["a.png", "b.json"]
    umask = os.umask(0)
    os.umask(umask)
    assert a.stat().st_mode & 0o777 == 0o666 & ~umask


@pytest.mark.parametrize("exc", [KeyboardInterrupt, RuntimeError, OSError])
def test_an_error_while_writing_leaves_the_old_files_and_no_temporaries(
    tmp_path: Path, exc: type[BaseException]
) -> None:
    a, b = tmp_path / "a.png", tmp_path / "b.json"
    a.write_bytes(b"old")
    with pytest.raises((exc, OutputError)), atomic_outputs([a, b]) as (ta, _):  # noqa: PT012  write, then fail
        ta.write_bytes(b"new, half")
        raise exc(errno.EIO, "boom") if exc is OSError else exc()
    assert a.read_bytes() == b"old" and names(tmp_path) == ["a.png"]


@pytest.mark.parametrize(("fault", "needle"), [("enospc", "disk full"), ("erofs", "read-only")])
def test_injected_fault_is_one_line_and_commits_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fault: str, needle: str
) -> None:
    monkeypatch.setenv(FAULT_ENV, fault)
    a = tmp_path / "a.png"
    a.write_bytes(b"old")
    with pytest.raises(OutputError) as info:
        atomic_write_bytes(a, b"new")
    assert needle in str(info.value) and "\n" not in str(info.value)
    assert isinstance(info.value, GlobeviewError)
    assert a.read_bytes() == b"old" and names(tmp_path) == ["a.png"]


def test_check_output_file(tmp_path: Path) -> None:
    assert check_output_file(tmp_path / "x.png", suffixes=(".png",)) == tmp_path / "x.png"
    (tmp_path / "d").mkdir()
    cases = [
        (tmp_path / "d", "is a directory"),
        (tmp_path / "x.PNG.txt", "must end in .png"),
        (tmp_path / "no" / "x.png", "does not exist"),
        (Path("/dev/null"), "not a regular file"),
        ("", "needs a file name"),
    ]
    (tmp_path / "f").write_text("")
    cases.append((tmp_path / "f" / "x.png", "is not a folder"))
    # Too long for the temporary beside it (ENAMETOOLONG after the render), or for the
    # file system at all (stat() itself fails).
    cases.append((tmp_path / ("a" * 240 + ".png"), "file name too long"))
    cases.append((tmp_path / ("a" * 300 + ".png"), "file name too long"))
    for path, needle in cases:
        with pytest.raises(OutputError, match=needle):
            check_output_file(path, "--out", (".png",))
    assert check_output_file(tmp_path / "X.PNG", suffixes=(".png",))  # case-insensitive


def test_writable_folder_problem_looks_at_the_nearest_existing_folder(tmp_path: Path) -> None:
    assert writable_folder_problem(tmp_path / "a" / "b" / "c") is None
    (tmp_path / "f").write_text("")
    assert "not a folder" in writable_folder_problem(tmp_path / "f" / "cache")


def test_describe_os_error_is_one_line_per_cause() -> None:
    for code, needle in [
        (errno.ENOSPC, "disk full"),
        (errno.EROFS, "read-only"),
        (errno.EACCES, "permission denied"),
        (errno.ENOENT, "does not exist"),
    ]:
        text = describe_os_error(OSError(code, os.strerror(code)), "/a/x.png")
        assert needle in text and "/a/x.png" in text and "\n" not in text


def test_a_folder_that_is_there_but_takes_no_files_is_not_writable(tmp_path: Path) -> None:
    """ENOENT creating a file in a folder that exists (/proc, where root passes os.access)
    is a folder that is not writable, not one that "does not exist"."""
    target = tmp_path / "x.mp4"
    text = describe_os_error(FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT)), target)
    assert f"folder {tmp_path} is not writable" in text and "does not exist" not in text
    if Path("/proc").is_dir():  # the reviewer's case, a real error from the kernel
        with pytest.raises((FileNotFoundError, PermissionError)) as info:
            open("/proc/.globeview-test.tmp", "w").close()
        text = describe_os_error(info.value, "/proc/x.mp4")
        assert "does not exist" not in text and "\n" not in text
