"""Well-known binary (WKB, OGC/ISO, as OGR hands geometries over) into flat coordinate arrays.

`decode_wkb` turns one WKB blob per feature into line parts (line strings and polygon rings,
each an (N, 2) run of a flat array) and points, each tagged with its feature's index, in the
coordinates of the file (any CRS; x east, y north as OGR gives them with the traditional GIS
axis order). Z and M are dropped. A feature whose geometry cannot be drawn (truncated bytes,
an unknown or curved type, a line of one vertex, a ring of fewer than three, non-finite
coordinates) is left out whole and counted as ``broken``; a missing (null) or empty geometry is
counted as ``empty``. Pure Python/numpy: one pass over the bytes, numpy for the coordinates.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Decoded", "decode_wkb"]

#: WKB base types (ISO numbering modulo 1000).
_POINT, _LINE, _POLYGON, _MPOINT, _MLINE, _MPOLYGON, _COLLECTION = 1, 2, 3, 4, 5, 6, 7
#: Deepest nesting of collections accepted (a hostile file could nest without end).
_MAX_DEPTH = 8


class _Broken(Exception):
    """A geometry that cannot be drawn (internal: its feature is skipped and counted)."""


@dataclass
class Decoded:
    """The drawable geometry of a layer's features, in the file's coordinates.

    Attributes:
        line_xy: (N, 2) float64 vertices of every line part, one after another.
        line_starts: (P + 1,) int64 offsets of each part's first vertex in ``line_xy``.
        line_feature: (P,) int64 the feature each part belongs to.
        line_outer: (P,) bool: the part is a line string or a polygon's exterior ring (the
            parts a label is placed on).
        point_xy: (M, 2) float64 points; point_feature: (M,) int64 their features.
        broken: features left out because their geometry cannot be drawn.
        empty: features with a null or empty geometry.
    """

    line_xy: np.ndarray
    line_starts: np.ndarray
    line_feature: np.ndarray
    line_outer: np.ndarray
    point_xy: np.ndarray
    point_feature: np.ndarray
    broken: int = 0
    empty: int = 0


class _Reader:
    """Walks one WKB blob, appending parts to the shared lists."""

    def __init__(self, buf: bytes, parts: list[np.ndarray], outer: list[bool]) -> None:
        self.buf = buf
        self.pos = 0
        self.parts = parts
        self.outer = outer
        self.points: list[np.ndarray] = []

    def _header(self) -> tuple[str, int, int]:
        """(byte order '<' or '>', base type, coordinates per vertex)."""
        if self.pos + 5 > len(self.buf):
            raise _Broken
        order = "<" if self.buf[self.pos] == 1 else ">"
        (raw,) = struct.unpack_from(order + "I", self.buf, self.pos + 1)
        self.pos += 5
        has_z = bool(raw & 0x80000000) or (raw & 0xFFFF) // 1000 in (1, 3)
        has_m = bool(raw & 0x40000000) or (raw & 0xFFFF) // 1000 in (2, 3)
        if raw & 0x20000000:  # EWKB with an SRID: skip it
            self.pos += 4
        return order, (raw & 0xFFFF) % 1000, 2 + has_z + has_m

    def _count(self, order: str) -> int:
        if self.pos + 4 > len(self.buf):
            raise _Broken
        (n,) = struct.unpack_from(order + "I", self.buf, self.pos)
        self.pos += 4
        return int(n)

    def _coords(self, order: str, dims: int, n: int) -> np.ndarray:
        size = n * dims * 8
        if self.pos + size > len(self.buf):
            raise _Broken
        a = np.frombuffer(self.buf, order + "f8", n * dims, self.pos).reshape(n, dims)[:, :2]
        self.pos += size
        return a.astype(np.float64)

    def geometry(self, depth: int = 0) -> None:
        if depth > _MAX_DEPTH:
            raise _Broken
        order, kind, dims = self._header()
        if kind == _POINT:
            p = self._coords(order, dims, 1)
            if not np.isnan(p).all():  # POINT EMPTY is NaN NaN
                self.points.append(p)
        elif kind == _LINE:
            self._line(order, dims, outer=True)
        elif kind == _POLYGON:
            for i in range(self._count(order)):
                self._line(order, dims, outer=i == 0, ring=True)
        elif kind in (_MPOINT, _MLINE, _MPOLYGON, _COLLECTION):
            for _ in range(self._count(order)):
                self.geometry(depth + 1)
        else:  # curves, surfaces, TINs: not drawn
            raise _Broken

    def _line(self, order: str, dims: int, outer: bool, ring: bool = False) -> None:
        n = self._count(order)
        xy = self._coords(order, dims, n)
        if n == 0:
            return
        if n < (3 if ring else 2):
            raise _Broken
        if ring and not (xy[0] == xy[-1]).all():
            xy = np.concatenate([xy, xy[:1]])
        self.parts.append(xy)
        self.outer.append(outer)


def decode_wkb(blobs: Sequence[bytes | None]) -> Decoded:
    """Decode one WKB geometry (or None) per feature; see the module docstring."""
    parts: list[np.ndarray] = []
    outer: list[bool] = []
    part_feature: list[int] = []
    points: list[np.ndarray] = []
    point_feature: list[int] = []
    broken = empty = 0
    for i, blob in enumerate(blobs):
        if blob is None:
            empty += 1
            continue
        r = _Reader(bytes(blob), [], [])
        try:
            r.geometry()
            finite = all(np.isfinite(p).all() for p in (*r.parts, *r.points))
        except (_Broken, struct.error, ValueError):
            broken += 1
            continue
        if not finite:
            broken += 1
            continue
        if not r.parts and not r.points:
            empty += 1
            continue
        parts.extend(r.parts)
        outer.extend(r.outer)
        part_feature.extend([i] * len(r.parts))
        points.extend(r.points)
        point_feature.extend([i] * len(r.points))
    lengths = [len(p) for p in parts]
    return Decoded(
        np.concatenate(parts) if parts else np.zeros((0, 2)),
        np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        np.asarray(part_feature, np.int64),
        np.asarray(outer, bool),
        np.concatenate(points) if points else np.zeros((0, 2)),
        np.asarray(point_feature, np.int64),
        broken,
        empty,
    )
