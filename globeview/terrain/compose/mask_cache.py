"""Blend masks kept in the user's cache between sessions (issue #27, the window's launch).

A layer's `blend.BlendMask` is a box mean of its coverage (~0.05-0.2 CPU-s a regional layer),
and the LOD's first frame asks for its `blend.interpolation_error` at a dozen cell sizes
(~0.02-0.1 CPU-s each on the embedded layers): together most of a CPU second of the window's
first frame. Both depend only on the store's contents, so the weight raster is written once to
``<cache>/blend-masks/<key>.npz`` and the interpolation errors, as they are measured, to
``<cache>/blend-masks/<key>-interp.json``; the next launch reads them back. The key is a
sha256 of this module's `MASK_FORMAT`, globeview's version, the terrain package's source
(`band_tables.code_digest`) and the store's ``manifest.json`` bytes (`band_tables.store_digest`:
a rebuilt store gets another key). Remote stores are not kept. A file that cannot be written or
read back as expected costs only the recomputation: nothing here raises.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
from pathlib import Path

import numpy as np

from globeview import __version__
from globeview.fileio import atomic_write_bytes
from globeview.paths import cache_dir
from globeview.terrain.compose.band_tables import code_digest, store_digest
from globeview.terrain.store.tile_store import TileStore

__all__ = [
    "MASK_FORMAT",
    "load_interp_errors",
    "load_weights",
    "mask_key",
    "save_interp_errors",
    "save_weights",
]

log = logging.getLogger(__name__)

#: Bump when the kept arrays change meaning: old files are then never read.
MASK_FORMAT = 2


def mask_key(st: TileStore) -> str | None:
    """The file name stem of a store's mask; None for a store that is not kept (remote, or
    its manifest unreadable now)."""
    digest = store_digest(st)
    if digest is None:
        return None
    parts = [f"format={MASK_FORMAT}", __version__, code_digest(), digest]
    return hashlib.sha256("|".join(parts).encode()).hexdigest()[:32]


def _folder() -> Path:
    return cache_dir() / "blend-masks"


def load_weights(key: str, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """The weight raster and its integral image kept under ``key`` (`save_weights`) if the
    raster is a float32 array of ``shape`` (rows, columns) with values in [0, 1] and the
    integral an int64 array one row and column larger ending in the count of w < 1, else
    None."""
    path = _folder() / f"{key}.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as npz:
            w, partial = npz["w"], npz["partial"]
    except (OSError, ValueError, KeyError, EOFError) as exc:
        log.debug("blend mask %s unreadable (%s): built again", path, exc)
        return None
    if w.shape != shape or w.dtype != np.float32 or not (w.min() >= 0.0 and w.max() <= 1.0):
        return None
    rows, cols = shape
    if partial.shape != (rows + 1, cols + 1) or partial.dtype != np.int64:
        return None
    if partial[-1, -1] != np.count_nonzero(w < 1.0):
        return None
    return w, partial


def save_weights(key: str, w: np.ndarray, partial: np.ndarray) -> None:
    """Keep the weight raster ``w`` and its integral image ``partial`` (of "w < 1", with a
    leading row and column of zeros) under ``key`` (atomic; a cache that cannot be written
    is skipped)."""
    buf = io.BytesIO()
    np.savez(buf, w=w, partial=partial)
    _write(_folder() / f"{key}.npz", buf.getvalue())


def load_interp_errors(key: str) -> dict[int, float]:
    """The interpolation errors kept under ``key``: cell size in raster steps -> error (w
    units, [0, 1]); empty where none are kept or the file is unreadable."""
    path = _folder() / f"{key}-interp.json"
    try:
        raw = json.loads(path.read_text())
        out = {int(m): float(e) for m, e in raw.items()}
    except (OSError, ValueError, TypeError, AttributeError):
        return {}
    if any(m < 2 or not 0.0 <= e <= 1.0 for m, e in out.items()):
        return {}
    return out


def save_interp_errors(key: str, errors: dict[int, float]) -> None:
    """Keep ``errors`` (`load_interp_errors`'s mapping) under ``key``, atomically (two
    processes writing at once: the last one's set is kept, the other's values are measured
    again at a later launch)."""
    text = json.dumps({str(m): e for m, e in sorted(errors.items())})
    _write(_folder() / f"{key}-interp.json", text.encode())


def _write(path: Path, data: bytes) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, data)
    except OSError as exc:
        log.debug("blend mask file %s not kept (%s)", path, exc)
