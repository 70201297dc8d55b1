"""The example plugin as a third party ships it: built into a wheel, installed with pip into
a fresh virtual environment, found through its entry point, and its own tests (which use
globeview's pytest fixtures) passing there, against the wheel's copy, not the source tree."""

from __future__ import annotations

import os
import re
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples/globeview-fixedlevel"


def _run(args: list[str], **kwargs) -> subprocess.CompletedProcess:
    res = subprocess.run(args, capture_output=True, text=True, timeout=900, **kwargs)
    assert res.returncode == 0, f"{args[:4]} failed:\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    return res


def _deps_dir(dest: Path) -> Path:
    """This environment's site-packages as links, minus the editable install of the example
    (so the fresh environment sees globeview and its dependencies, but the example only
    from the wheel)."""
    dest.mkdir()
    for sp in site.getsitepackages():
        for entry in Path(sp).iterdir():
            if "fixedlevel" in entry.name or entry.name.endswith(".pth"):
                continue
            if not (dest / entry.name).exists():
                (dest / entry.name).symlink_to(entry)
    return dest


@pytest.mark.slow
def test_example_wheel_installs_and_passes_its_tests(tmp_path: Path) -> None:
    wheels = tmp_path / "wheels"
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheels), str(EXAMPLE)])
    (wheel,) = wheels.glob("globeview_fixedlevel-*.whl")

    # The fresh environment gets no pip of its own (`ensurepip` costs ~7 CPU-s): this
    # environment's pip installs the wheel into it (`pip --python`), as it would with its own.
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)])
    py = venv / "bin" / "python"
    purelib = _run(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]
    ).stdout.strip()
    # globeview itself (from this checkout) and its dependencies, through a .pth file.
    deps = _deps_dir(tmp_path / "deps")
    (Path(purelib) / "globeview_deps.pth").write_text(f"{deps}\n{ROOT}\n", encoding="utf-8")
    pip = [sys.executable, "-m", "pip", "--python", str(py)]
    _run([*pip, "install", "-q", "--no-deps", "--no-index", str(wheel)])

    work = tmp_path / "work"  # away from the source tree: imports come from the venv
    shutil.copytree(EXAMPLE / "tests", work / "tests")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["GLOBEVIEW_CACHE_DIR"] = str(tmp_path / "cache")
    where = _run(
        [str(py), "-c", "import globeview_fixedlevel as m; print(m.__file__)"], cwd=work, env=env
    ).stdout.strip()
    assert Path(where).is_relative_to(venv), where
    listed = _run([str(py), "-m", "globeview", "plugins", "list"], cwd=work, env=env).stdout
    row = next(line for line in listed.splitlines() if line.startswith("fixed-level "))
    assert row.split()[:5] == ["fixed-level", "0.1.0", "lod,tool,layer", "yes", "ok"]

    res = _run(
        [str(py), "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests"], cwd=work, env=env
    )
    summary = res.stdout.strip().splitlines()[-1]
    passed = re.search(r"(\d+) passed", summary)
    assert passed and int(passed.group(1)) >= 15 and "failed" not in summary, summary
