"""Stride errors of tiles finer than a layer's data ("virtual" tiles), measured on the tile.

A tile at level L below a layer's finest level F = L - f holds its finest ancestor's bilinear
surface B sampled at the tile's nodes (`TerrainStack._layer_heights`). Copying the ancestor's
whole-tile stride errors to it is a valid bound but a loose one (a flat corner of a rugged
ancestor inherits the ancestor's worst error: Vancouver's (8, 76, 56) got 563.7 m at stride 4,
its own part of the ancestor needs 1.6 m), so refining below the data never lowered an error
and the LOD cut could not profit from it. `AncestorErrors` measures each virtual tile's own
part of its ancestor instead, from per-ancestor tables (built once per ancestor, then looked
up for all its descendants at once: the global base is virtual nearly everywhere).

The bound, in the convention of every stored stride error (`globeview.terrain.ingest.driver`: the
surface drawn at stride s is taken as S_s, bilinear between the stride-s nodes, and its
error is max |S_s - T| against the reference T, the finest data's bilinear surface), metres:

- |S_s - T| <= |S_s - B| + |B - T|, and |B - T| <= e_A, the ancestor's stride-1 error
  (column 0 of the store's errors; 0 where the finest level holds the data itself).
- s <= 2^f: each stride-s cell lies inside one ancestor cell (the grids are aligned), where B
  is bilinear, and the bilinear interpolation of a bilinear function over a sub-rectangle is
  the function itself: S_s = B, the term is 0 (what the old copied errors said too).
- s > 2^f: the tile's stride-s nodes are the ancestor's nodes at stride s' = s / 2^f, so S_s
  is the ancestor's S_s' on the tile's part of it, and S_s' - B is piecewise bilinear on the
  ancestor's own grid (both are, on nested grids), so it peaks at an ancestor node: the max
  of |S_s' - node| over the ancestor nodes in the tile (edges included). Exact.

Not included, as in the stored errors: the renderer draws each cell as two triangles, which
depart from the bilinear cell by up to |twist| / 4 (twist = a - b - c + d of its corners).
Charging that here alone made the bounds non-monotone in depth (a finest-level tile at stride
1 is recorded exact, its virtual children were charged up to 61 m at Vancouver) and the
fewest-triangles cut then ran over its tile budget on close views; it belongs in the store's
errors at every level (open, issue #17 notes).

NaN nodes (no data) make the tiles touching them unmeasured (NaN); the caller keeps the
ancestor's copied errors there.
"""

from __future__ import annotations

import functools

import numpy as np

#: Number of index strides with errors: 1, 2, 4, ..., 64 (as `metadata.N_STRIDES`).
N_STRIDES = 7


@functools.lru_cache(maxsize=16)
def _stride_weights(size: int, s: int) -> np.ndarray:
    """(size, cells / s + 1) linear interpolation weights from every s-th node of ``size``
    nodes to all of them (one axis; read-only)."""
    t = np.arange(size) / s
    i0 = np.minimum(np.floor(t).astype(int), (size - 1) // s - 1)
    frac = t - i0
    w = np.zeros((size, (size - 1) // s + 1))
    w[np.arange(size), i0] = 1.0 - frac
    w[np.arange(size), i0 + 1] = frac
    w.setflags(write=False)
    return w


def bilinear_node_error(h: np.ndarray, s: int) -> np.ndarray:
    """(size, size) metres: |S_s - h| at each node of the (size, size) node heights ``h``
    (row 0 north), S_s bilinear between every s-th node (the stored errors' stride surface;
    bilinear is separable: two small matrix products)."""
    w = _stride_weights(h.shape[-1], s)
    if not np.isnan(h).any():
        return np.abs(w @ h[::s, ::s] @ w.T - h)
    # A matrix product would spread a NaN (no data) over whole rows (NaN * 0 is NaN): gather
    # each node's 4 corners instead, so only the cells touching a NaN are NaN.
    size = h.shape[-1]
    t = np.arange(size)
    i0 = np.minimum(t // s, (size - 1) // s - 1)
    frac = (t - i0 * s) / s
    sub = h[::s, ::s]
    u = frac[None, :]
    top = sub[i0][:, i0] * (1.0 - u) + sub[i0][:, i0 + 1] * u
    bot = sub[i0 + 1][:, i0] * (1.0 - u) + sub[i0 + 1][:, i0 + 1] * u
    v = frac[:, None]
    return np.abs(top * (1.0 - v) + bot * v - h)


class AncestorErrors:
    """Per-ancestor tables for `bounds`: built once from the ancestor's (size, size) node
    heights (metres, row 0 north; NaN where no data). They grow as levels below are asked
    for, to about 0.16 MB for a 65-node tile (size^2 x ~37 bytes); `nbytes` says how much."""

    def __init__(self, anc: np.ndarray) -> None:
        self._h = np.asarray(anc, dtype=np.float64)
        self.size = self._h.shape[0]
        self.log_cells = int(np.log2(self.size - 1))
        #: (k', f) -> `_block_max` (k' >= 1; built when first needed): at f = log2(cells)
        #: the max of |S_{2^k'} - node| over each ancestor cell's 4 corners; a block of
        #: cells' max is then the max over its nodes.
        self._cells: dict[int, np.ndarray] = {}
        self._tables: dict[int, np.ndarray] = {}

    @property
    def nbytes(self) -> int:
        """Bytes held now: the heights and every table built so far."""
        held = [self._h, *self._cells.values(), *self._tables.values()]
        return sum(a.nbytes for a in held)

    def _block_max(self, k: int, f: int) -> np.ndarray:
        """(2^f, 2^f): max of |S_{2^k} - node| over the nodes of each descendant ``f``
        levels below (its block of cells)."""
        key = k * 64 + f
        hit = self._cells.get(key)
        if hit is None:
            if f >= self.log_cells:
                hit = _corner_max(bilinear_node_error(self._h, 2**k)).astype(np.float32)
            else:
                q, m = 1 << f, (self.size - 1) >> f
                hit = self._block_max(k, self.log_cells).reshape(q, m, q, m).max(axis=(1, 3))
            self._cells[key] = hit
        return hit

    def bounds(self, f: int, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """(K, N_STRIDES) metres: max |S_s - B| (the module's bound without e_A) for the K
        descendants ``f`` >= 1 levels below, at tile offsets (dx, dy) inside the ancestor;
        NaN where their nodes have no data; inf at strides beyond the grid."""
        # From log2(cells) levels down every stride (<= cells) is <= 2^f: each draws B itself.
        deep = f >= self.log_cells
        out = np.zeros((len(dx), N_STRIDES)) if deep else self._table(f)[dy, dx].astype(np.float64)
        out[:, 2.0 ** np.arange(N_STRIDES) > self.size - 1] = np.inf
        return out

    def _table(self, f: int) -> np.ndarray:
        """(2^f, 2^f, N_STRIDES) `bounds` of every descendant ``f`` < log2(cells) levels below,
        by (dy, dx); built once per f (float32; all f together about 4 x cells^2 x N_STRIDES
        bytes)."""
        hit = self._tables.get(f)
        if hit is not None:
            return hit
        q = 1 << f
        out = np.zeros((q, q, N_STRIDES), dtype=np.float32)
        for k in range(f + 1, min(N_STRIDES, self.log_cells + 1)):
            out[..., k] = self._block_max(k - f, f)
        self._tables[f] = out
        return out


def _corner_max(a: np.ndarray) -> np.ndarray:
    """(n, n) max of ``a`` (n + 1 nodes a side) over each cell's 4 corners (NaN if any is)."""
    rows = np.maximum(a[:-1], a[1:])
    return np.maximum(rows[:, :-1], rows[:, 1:])
