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


def _truncate(p: Path, keep: int | None = None) -> None:
    """Cut a file to ``keep`` bytes (default: half). A chunk keeps its header only: its data
    all lie in its first blocks (the tile spans 23 of its 1024 rows), which half keeps."""
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2 if keep is None else keep])


def _one(s: Path, pattern: str) -> Path:
    """The last file matching (level 6: the chunk with data, its shard)."""
    return sorted(s.glob(pattern))[-1]


def _swap_chunk(s: Path) -> None:
    shutil.copyfile(_one(s, "chunks/05/*/*.tif"), _one(s, "chunks/06/*/*.tif"))


#: name -> (how the store is damaged, the file the message must name)
DAMAGE: dict[str, tuple[Callable[[Path], None], str]] = {
    "truncated chunk": (lambda s: _truncate(_one(s, "chunks/06/*/*.tif"), 400), "chunks/06/"),
    "deleted chunk": (lambda s: _one(s, "chunks/06/*/*.tif").unlink(), "chunks/06/"),
    "swapped chunk": (_swap_chunk, "chunks/06/"),
    "truncated shard": (lambda s: _truncate(_one(s, "meta/06/*/*.gvm")), "meta/06/"),
    "swapped level vrt": (
        lambda s: shutil.copyfile(s / "level_05.vrt", s / "level_06.vrt"),
        "level_06.vrt",
    ),
}


@pytest.mark.slow
def test_an_intact_store_is_described(store: Path, tmp_path: Path) -> None:
    res = globeview("info", str(store), cache=tmp_path / "c")
    assert res.returncode == 0, res.stderr
    assert "tile store, format 7" in res.stdout and "levels 0..6" in res.stdout
    # The top shard and two rooted at level 6: the tile spans a chunk row edge (45 N).
    assert "metadata shards: 3" in res.stdout
    full = globeview("info", "--verify", "--json", str(store), cache=tmp_path / "c")
    assert full.returncode == 0, full.stderr
    assert '"chunk_files_checked": 6' in full.stdout


def test_verify_finds_what_the_size_check_cannot(store: Path, tmp_path: Path) -> None:
    """A chunk with one byte changed keeps its size: only --verify (sha256) sees it."""
    copy = tmp_path / "s"
    shutil.copytree(store, copy)
    p = _one(copy, "chunks/06/*/*.tif")
    data = bytearray(p.read_bytes())
    data[-1] ^= 0xFF
    p.write_bytes(bytes(data))
    assert globeview("info", str(copy), cache=tmp_path / "c").returncode == 0
    line = one_error_line(globeview("info", "--verify", str(copy), cache=tmp_path / "c"))
    assert "chunks/06/" in line and "checksum mismatch" in line, line


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
