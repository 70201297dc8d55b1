"""The rules a quadtree walk applies to what a policy answers, shared by the level-by-level
walk (`globeview.lod.traversal`) and the flat one (`globeview.lod.flat_walk`): the tile
budget's choice of which tiles refine (`budget_refinement`) and the checks of a policy's
answers (`checked`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from globeview.lod.policy import LodPolicy

BOOL, F64, I64 = np.dtype(bool), np.dtype(np.float64), np.dtype(np.int64)


def budget_refinement(
    refine: np.ndarray, priority: np.ndarray, room: int, fanout: int = 4
) -> np.ndarray:
    """Limit refinement so the drawn tiles stay within a budget: when refining every tile in
    ``refine`` would add more than ``room`` tiles (each refined tile becomes ``fanout``), the
    tiles with the largest ``priority`` refine first. Returns the (possibly new) mask."""
    n_ref = int(np.count_nonzero(refine))
    if n_ref * fanout <= room or n_ref == 0:
        return refine
    allowed = max(room // fanout, 0)
    order = np.argsort(-priority)
    idx = order[refine[order]][:allowed]
    out = np.zeros_like(refine)
    out[idx] = True
    return out


def checked(
    policy: LodPolicy,
    what: str,
    value: Any,
    shape: tuple[int, ...],
    dtype: np.dtype,
    none_ok: bool = False,
) -> Any:
    """``value`` as an array of ``dtype`` after checking it has ``shape`` (one-line
    ValueError naming the policy's method otherwise: a policy bug fails its provider).
    With ``none_ok`` None passes as None (`LodPolicy.cull`: keep every tile)."""
    # The plain case first, with no more work than these tests: a frame has a dozen levels
    # and a few policy calls per level, so what each check costs adds up.
    if type(value) is np.ndarray and value.dtype is dtype and value.shape == shape:
        return value
    if value is None and none_ok:
        return None
    arr = np.asarray(value)
    if arr.shape != shape:
        raise ValueError(
            f"{type(policy).__name__}.{what} returned shape {arr.shape}, expected {shape}"
        )
    if dtype is I64 and arr.dtype.kind not in "iu":
        raise ValueError(f"{type(policy).__name__}.{what} returned {arr.dtype}, not integers")
    if dtype is F64 and arr.dtype.kind not in "fiu":
        raise ValueError(f"{type(policy).__name__}.{what} returned {arr.dtype}, not numbers")
    return arr.astype(dtype, copy=False)
