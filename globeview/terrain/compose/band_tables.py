"""The border blend's difference tables kept in the user's cache between sessions.

`band_errors.BandErrors._difference_table` measures |upper - lower| on every tile of a layer's
border band at a level: a few hundred composed tiles for the embedded terrain, about half a
second of CPU at the window's first frame (issue #27's launch target). The tables depend only
on the stores' contents and the order of the layers, so they are written once to
``<cache>/band-tables/<key>.npz`` and read back at the next launch. The key is a sha256 of
this module's `TABLE_FORMAT`, globeview's version, the terrain package's source
(`code_digest`), the level, whether layers blend, and the ``manifest.json`` bytes of the layer
and of each layer below it (a manifest names every level file's sha256, so a rebuilt store
gets other keys). Remote stores are not kept (their
manifest is not a local file). A file that cannot be written or read back as the expected
arrays costs only the recomputation: nothing here raises.
"""

from __future__ import annotations

import functools
import hashlib
import io
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from globeview import __version__
from globeview.fileio import atomic_write_bytes
from globeview.paths import cache_dir
from globeview.terrain.compose.metadata import N_STRIDES
from globeview.terrain.store.identify import MANIFEST_NAME
from globeview.terrain.store.tile_store import TileStore

__all__ = ["TABLE_FORMAT", "Tables", "load_tables", "save_tables", "store_digest", "tables_key"]

log = logging.getLogger(__name__)

#: Bump when `_difference_table`'s arrays change meaning: old files are then never read.
TABLE_FORMAT = 1

#: (table (ny, nx), spread (ny, nx, N_STRIDES), measured (ny, nx, N_STRIDES)), metres.
Tables = tuple[np.ndarray, np.ndarray, np.ndarray]


def store_digest(st: TileStore) -> str | None:
    """sha256 of a local store's manifest.json bytes; None for a remote store or one whose
    manifest cannot be read now."""
    if st.url is not None:
        return None
    try:
        return hashlib.sha256((Path(st.path) / MANIFEST_NAME).read_bytes()).hexdigest()
    except OSError:
        return None


@functools.cache
def code_digest() -> str:
    """sha256 of the terrain package's source (~50 files, a few ms once a process): the
    tables are its results, so any change of the code that reads, composes or measures
    heights makes new keys (the version number does not change with every commit)."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parents[1]  # globeview/terrain
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def tables_key(upper: str, below: Sequence[str], level: int, blend: bool) -> str:
    """The file name stem of a table: layer digest ``upper`` over ``below`` (bottom first)."""
    parts = [f"format={TABLE_FORMAT}", __version__, code_digest(), f"level={level}"]
    parts += [f"blend={blend}", upper]
    return hashlib.sha256("|".join([*parts, *below]).encode()).hexdigest()[:32]


def _path(key: str) -> Path:
    return cache_dir() / "band-tables" / f"{key}.npz"


def load_tables(key: str, shape: tuple[int, int]) -> Tables | None:
    """The tables stored under ``key`` if they exist and have ``shape`` (ny, nx), else None."""
    path = _path(key)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as npz:
            out = (npz["table"], npz["spread"], npz["measured"])
    except (OSError, ValueError, KeyError) as exc:
        log.debug("band table %s unreadable (%s): recomputed", path, exc)
        return None
    shapes = (shape, (*shape, N_STRIDES), (*shape, N_STRIDES))
    if any(a.shape != s or a.dtype != np.float64 for a, s in zip(out, shapes, strict=True)):
        return None
    return out


def save_tables(key: str, tables: Tables) -> None:
    """Keep ``tables`` under ``key`` (atomic; a cache that cannot be written is skipped)."""
    table, spread, measured = tables
    buf = io.BytesIO()
    np.savez(buf, table=table, spread=spread, measured=measured)
    path = _path(key)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, buf.getvalue())
    except OSError as exc:
        log.debug("band table %s not kept (%s)", path, exc)
