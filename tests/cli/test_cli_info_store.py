"""`globeview info STORE` on a damaged store: a chunk file truncated, deleted or swapped with
another level's is one line (exit 2), as reading the store's tiles is, not a description.
The commands run in this process (`inprocess_cli`); test_cli_hostile and the fault corpus
hold the real process to one line."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from .run_cli import globeview_here as globeview
from .run_cli import one_error_line

SRTM = Path(__file__).resolve().parents[2] / "data" / "N44W072.hgt"


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The SRTM tile ingested to level 6 (a second or two): one chunk file a level."""
    base = tmp_path_factory.mktemp("store")
    res = globeview(
        "ingest", str(SRTM), "--out", str(base / "s"), "--max-level", "6", "--quiet",
        cache=base / "c",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    return base / "s"


def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


#: name -> (how the store is damaged, the file the message must name)
DAMAGE: dict[str, tuple[Callable[[Path], None], str]] = {
    "truncated chunk": (lambda s: _truncate(s / "level_06_r0000_c0000.tif"), "level_06_r0000"),
    "deleted chunk": (lambda s: (s / "level_05_r0000_c0000.tif").unlink(), "level_05_r0000"),
    "swapped chunk": (
        lambda s: shutil.copyfile(s / "level_05_r0000_c0000.tif", s / "level_06_r0000_c0000.tif"),
        "level_06_r0000",
    ),
    "swapped level vrt": (
        lambda s: shutil.copyfile(s / "level_05.vrt", s / "level_06.vrt"),
        "level_06.vrt",
    ),
}


@pytest.mark.slow
def test_an_intact_store_is_described(store: Path, tmp_path: Path) -> None:
    res = globeview("info", str(store), cache=tmp_path / "c")
    assert res.returncode == 0, res.stderr
    assert "tile store, format" in res.stdout and "levels 0..6" in res.stdout


@pytest.mark.slow
@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_damaged_store_is_one_line(store: Path, tmp_path: Path, damage: str) -> None:
    harm, name = DAMAGE[damage]
    copy = tmp_path / "s"
    shutil.copytree(store, copy)
    harm(copy)
    for args in (("info", str(copy)), ("info", "--json", str(copy))):
        line = one_error_line(globeview(*args, cache=tmp_path / "c"))
        assert name in line and ("damaged" in line or "missing" in line), line
    # What reading the finest tiles says too (render, height): the same store refused.
    line = one_error_line(globeview("height", "-71.5,44.5", str(copy), cache=tmp_path / "c"))
    assert name in line
