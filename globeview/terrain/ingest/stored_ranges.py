"""Per-tile height ranges (hmin, hmax) of the nodes a store holds (issue #25).

A tile is closed: its (s_n + 1)^2 nodes include its last row and column, which are the first
row and column of the tiles south and east of it. Where those tiles are in another chunk, the
store holds those nodes in that chunk's file (the chunk stores its closing row and column
only when the chunk beyond has no data, `layout.EXTRA_ROW` / `EXTRA_COL`), computed by that
chunk's task from its own window. A chunk's window values of its closing row and column
need not be those (the edge continuation past a data edge sees one window at a time), so the
range of a tile must come from the nodes as stored: its own chunk's stored part, plus the
first row of the chunk south of it, the first column of the chunk east of it and the first
node of the chunk south-east of it.

A chunk task reports (`stored_part_facts`) its tiles' ranges over the nodes it stores and,
for its north, west and north-west neighbours, the extremes of its stored first row and first
column by tile (closed segments) and its first node; `tile_ranges` combines them once every
chunk of a level is known. Heights metres, NaN where a tile holds no stored node.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from globeview.terrain.ingest.tile_errors import data_blocks, tile_min_max

__all__ = ["EdgeFacts", "stored_part_facts", "tile_ranges"]

#: (level, cy, cx) of a chunk.
Key = tuple[int, int, int]


class EdgeFacts:
    """The extremes of a chunk's stored first row by tile column (``north``: (2, ktx), min
    and max over nodes tx*s_n..(tx+1)*s_n that it stores), of its stored first column by tile
    row (``west``: (2, kty)), and its first node (``corner``); float32 metres, NaN where it
    stores none. Packed as one float32 array (`pack` / `unpack`) for results and facts."""

    def __init__(self, north: np.ndarray, west: np.ndarray, corner: float) -> None:
        self.north, self.west, self.corner = north, west, corner

    def pack(self) -> np.ndarray:
        """[north min, north max, west min, west max, corner] as one float32 array."""
        parts = [self.north[0], self.north[1], self.west[0], self.west[1], [self.corner]]
        return np.concatenate([np.asarray(p, dtype=np.float32) for p in parts])

    @classmethod
    def unpack(cls, packed: np.ndarray, kty: int, ktx: int) -> EdgeFacts:
        """The facts `pack` gave, for a chunk of kty x ktx tiles."""
        north = packed[: 2 * ktx].reshape(2, ktx)
        west = packed[2 * ktx : 2 * ktx + 2 * kty].reshape(2, kty)
        return cls(north, west, float(packed[-1]))


def _segments(line: np.ndarray, s_n: int, n_tiles: int) -> np.ndarray:
    """(2, n_tiles) NaN-ignoring min and max of ``line`` over closed segments [t*s_n,
    (t+1)*s_n] (clipped to the line's length), NaN where a segment holds no finite value."""
    out = np.full((2, n_tiles), np.nan, dtype=np.float32)
    for t in range(n_tiles):
        seg = line[t * s_n : (t + 1) * s_n + 1]
        if seg.size and np.isfinite(seg).any():
            out[0, t], out[1, t] = np.nanmin(seg), np.nanmax(seg)
    return out


def stored_part_facts(
    window: np.ndarray, stored_rows: int, stored_cols: int, s_n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(hmin, hmax, packed `EdgeFacts`) of a chunk whose closed window (kty * s_n + 1 rows,
    ktx * s_n + 1 columns, float32) it stores the first ``stored_rows`` x ``stored_cols``
    nodes of: its tiles' ranges over those nodes ((kty, ktx) float32) and the facts of its
    first row and column its neighbours' tiles close on."""
    part = window[:stored_rows, :stored_cols]
    kty, ktx = (window.shape[0] - 1) // s_n, (window.shape[1] - 1) // s_n
    hmin = np.full((kty, ktx), np.nan, dtype=np.float32)
    hmax = hmin.copy()
    box = data_blocks(part, s_n)  # the tiles holding a stored finite node
    if box is not None:
        ty, tx = box
        shape = ((ty.stop - ty.start) * s_n + 1, (tx.stop - tx.start) * s_n + 1)
        own = np.full(shape, np.nan, dtype=np.float32)
        got = part[ty.start * s_n : ty.stop * s_n + 1, tx.start * s_n : tx.stop * s_n + 1]
        own[: got.shape[0], : got.shape[1]] = got
        hmin[ty, tx], hmax[ty, tx] = tile_min_max(own, s_n)
    corner = float(part[0, 0]) if part.size else float("nan")
    edges = EdgeFacts(_segments(part[0], s_n, ktx), _segments(part[:, 0], s_n, kty), corner)
    return hmin, hmax, edges.pack()


def _fold(
    lo: np.ndarray,
    hi: np.ndarray,
    at: tuple[int | slice, int | slice],
    vmin: np.ndarray | float,
    vmax: np.ndarray | float,
) -> None:
    """lo[at] = fmin(lo[at], vmin), hi[at] = fmax(hi[at], vmax), in place."""
    lo[at] = np.fmin(lo[at], vmin)
    hi[at] = np.fmax(hi[at], vmax)


def tile_ranges(
    own: Mapping[Key, tuple[np.ndarray, np.ndarray, np.ndarray]],
    east_of: Callable[[int, int, int], int | None],
) -> dict[Key, tuple[np.ndarray, np.ndarray]]:
    """Each chunk's per-tile (hmin, hmax) over the nodes the store holds for its tiles
    (float64 (kty, ktx)): ``own[key]`` (`stored_part_facts` of the chunk), folded with the
    facts of the chunks south, east and south-east of it that are in ``own``. ``east_of(lv,
    cy, cx)``: the chunk column east of column cx (wrapping round a level that goes all the
    way round), None past the level's last."""

    def edges(key: Key) -> EdgeFacts | None:
        got = own.get(key)
        return None if got is None else EdgeFacts.unpack(got[2], *got[0].shape)

    out: dict[Key, tuple[np.ndarray, np.ndarray]] = {}
    for (lv, cy, cx), (hmin, hmax, _) in own.items():
        lo, hi = hmin.astype(np.float64), hmax.astype(np.float64)
        kty, ktx = lo.shape
        south = edges((lv, cy + 1, cx))
        if south is not None:  # its first row closes this chunk's last tile row
            _fold(lo, hi, (-1, slice(None)), south.north[0, :ktx], south.north[1, :ktx])
        east = east_of(lv, cy, cx)
        if east is not None:
            e = edges((lv, cy, east))
            if e is not None:  # its first column closes this chunk's last tile column
                _fold(lo, hi, (slice(None), -1), e.west[0, :kty], e.west[1, :kty])
            se = edges((lv, cy + 1, east))
            if se is not None:  # its first node is the last tile's last corner
                _fold(lo, hi, (-1, -1), se.corner, se.corner)
        out[(lv, cy, cx)] = (lo, hi)
    return out
