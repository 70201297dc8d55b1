"""The geoid checks in a clean clone: without ``../shared`` next to the checkout they run on the
embedded grid (data/egm96_15.tif), none skipped."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]


@pytest.mark.slow
def test_geoid_checks_run_without_the_shared_folder(tmp_path: Path) -> None:
    # The module copied to <tmp>/parent/clone/tests/geodesy: its ../shared is <tmp>/parent/shared,
    # which does not exist, as beside a fresh `git clone`.
    clone = tmp_path / "parent" / "clone"
    dest = clone / "tests" / "geodesy"
    dest.mkdir(parents=True)
    shutil.copy(HERE / "test_geoid.py", dest)
    assert not (tmp_path / "parent" / "shared").exists()
    # The repository's pytest settings (warnings as errors), the copy as the only test.
    settings = ["-c", str(REPO / "pyproject.toml"), f"--rootdir={clone}", "-pno:cacheprovider"]
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-rs", *settings, str(dest)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=clone,
    )
    summary = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else res.stderr
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    assert " passed" in summary and "skipped" not in summary, summary
