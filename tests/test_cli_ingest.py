"""`globeview ingest` through its CLI module: exit codes, messages, no-op re-run."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from globeview.cli import ingest as cli_ingest
from globeview.errors import GlobeviewError

DATA = Path(__file__).resolve().parents[1] / "data"


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    cli_ingest.add_arguments(p)
    return p.parse_args(list(argv))


def test_ingest_then_up_to_date(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = str(DATA / "topobathy_vancouver.tif")
    out = str(tmp_path / "store")
    assert cli_ingest.run(_args(src, "--out", out, "--quiet")) == 0
    assert (tmp_path / "store" / "manifest.json").exists()
    capsys.readouterr()
    assert cli_ingest.run(_args(src, "--out", out, "--quiet")) == 0
    assert "store is up to date" in capsys.readouterr().out


def test_bad_input_is_one_line_nonzero(tmp_path: Path) -> None:
    bad = tmp_path / "fake.tif"
    bad.write_text("not a raster")
    with pytest.raises(GlobeviewError):
        cli_ingest.run(_args(str(bad), "--out", str(tmp_path / "s"), "--quiet"))
    # Through the real entry point (a child process): exit code and a single stderr line.
    code = (
        "import sys, argparse\n"
        "from globeview.cli import ingest as m\n"
        "from globeview.errors import GlobeviewError\n"
        "p = argparse.ArgumentParser(); m.add_arguments(p)\n"
        "try:\n    sys.exit(m.run(p.parse_args(sys.argv[1:])))\n"
        "except GlobeviewError as e:\n"
        "    print('globeview: error:', e, file=sys.stderr)\n"
        "    sys.exit(2)\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code, str(bad), "--out", str(tmp_path / "s")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0
    assert len(r.stderr.strip().splitlines()) == 1 and "error" in r.stderr
    assert not (tmp_path / "s").exists()
