"""The in-process runner of the CLI tests (`inprocess_cli`) reports what a child process does:
the same exit status, stdout and stderr, argparse's exit included, and leaves this process's
logging, environment and working folder as they were."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest
from inprocess_cli import run_globeview

CASES = [
    ["info", "no-such-file.tif"],  # a GlobeviewError: one line, exit 2
    ["info", "--no-such-option"],  # argparse's complaint (SystemExit 2)
    ["plugins", "list"],  # a success that prints
]


@pytest.mark.slow
@pytest.mark.parametrize("argv", CASES, ids=lambda a: " ".join(a))
def test_the_same_as_a_child_process(argv: list[str], tmp_path: Path) -> None:
    env = {"GLOBEVIEW_CACHE_DIR": str(tmp_path / "c"), "GLOBEVIEW_DEBUG": None}
    child_env = {k: v for k, v in {**os.environ, **env}.items() if v is not None}
    child = subprocess.run(
        [sys.executable, "-m", "globeview", *argv],
        capture_output=True,
        text=True,
        env=child_env,
        cwd=tmp_path,
        timeout=120,
    )
    here = run_globeview(argv, env=env, cwd=tmp_path)
    assert (here.returncode, here.stdout, here.stderr) == (
        child.returncode,
        child.stdout,
        child.stderr,
    )


def test_the_process_is_left_as_it_was(tmp_path: Path) -> None:
    root = logging.getLogger()
    before = (list(root.handlers), root.level, dict(os.environ), os.getcwd())
    res = run_globeview(["info", "no-such-file.tif"], env={"GV_X": "1"}, cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.startswith("globeview: error: "), res
    assert (list(root.handlers), root.level, dict(os.environ), os.getcwd()) == before
