"""`Bookmarks`: named camera views of a globe (issue #26 item 4), plain data with one event.

A bookmark is a name and a camera pose: (lon, lat) geodetic degrees on WGS84, height in
metres above the WGS84 ellipsoid, heading degrees clockwise from north, pitch degrees from
the horizontal (-90 looks straight down), roll degrees. Names are unique: adding a bookmark
under a name that exists replaces it in place. Every change emits ``changed`` (psygnal, no
arguments); the window's Bookmarks menu and a project file read the list.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from psygnal import Signal

from globeview.model.camera import check_lonlat_hpr

__all__ = ["MAX_NAME_CHARS", "Bookmark", "Bookmarks", "check_bookmark_name"]

#: Longest bookmark name (characters).
MAX_NAME_CHARS = 200

#: (lon, lat, height, heading, pitch, roll): degrees, metres above WGS84, degrees.
Pose = tuple[float, float, float, float, float, float]


def check_bookmark_name(name: object) -> str:
    """A bookmark name: text, stripped, 1..`MAX_NAME_CHARS` characters on one line;
    ValueError (one line) otherwise."""
    if not isinstance(name, str):
        raise ValueError(f"a bookmark name must be text, not {type(name).__name__}")
    text = name.strip()
    if not text or len(text) > MAX_NAME_CHARS or any(c in text for c in "\r\n\t\0"):
        raise ValueError(
            f"bookmark name {text[:40]!r} must be 1..{MAX_NAME_CHARS} characters on one line"
        )
    return text


@dataclass(frozen=True)
class Bookmark:
    """A named view. ``pose`` is (lon, lat, height, heading, pitch, roll), checked by
    `check_lonlat_hpr` (lon in -180..180, heading and roll in 0..360)."""

    name: str
    pose: Pose

    @classmethod
    def make(cls, name: object, pose: Iterable[float]) -> Bookmark:
        """A checked bookmark: ValueError (one line) for a bad name or pose (NaN, a latitude
        beyond 90, a height out of range...)."""
        values = [float(v) for v in pose]
        if len(values) != 6:
            raise ValueError(f"a bookmark's camera is 6 numbers, not {len(values)}")
        if not all(math.isfinite(v) for v in values):
            raise ValueError("a bookmark's camera must be finite numbers")
        return cls(check_bookmark_name(name), check_lonlat_hpr(*values))


class Bookmarks:
    """An ordered list of `Bookmark`, names unique."""

    #: Emitted after every change (added, replaced, removed, the whole list set).
    changed = Signal()

    def __init__(self) -> None:
        self._items: list[Bookmark] = []

    def __iter__(self) -> Iterator[Bookmark]:
        return iter(list(self._items))

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, name: object) -> bool:
        return any(b.name == name for b in self._items)

    def __getitem__(self, name: str) -> Bookmark:
        for b in self._items:
            if b.name == name:
                return b
        raise KeyError(name)

    @property
    def names(self) -> list[str]:
        """The names, in order."""
        return [b.name for b in self._items]

    def add(self, name: object, pose: Iterable[float]) -> Bookmark:
        """Add (or replace, in place) the bookmark ``name``; ValueError for a bad one."""
        mark = Bookmark.make(name, pose)
        for i, b in enumerate(self._items):
            if b.name == mark.name:
                if b == mark:
                    return mark
                self._items[i] = mark
                break
        else:
            self._items.append(mark)
        self.changed.emit()
        return mark

    def remove(self, name: str) -> None:
        """Remove the bookmark ``name`` (KeyError if there is none)."""
        index = self.names.index(name) if name in self else -1
        if index < 0:
            raise KeyError(name)
        del self._items[index]
        self.changed.emit()

    def set(self, marks: Iterable[Bookmark]) -> None:
        """Replace the whole list (one event); ValueError for repeated names."""
        items = list(marks)
        names = [b.name for b in items]
        if len(set(names)) != len(names):
            raise ValueError("bookmark names must be unique")
        if items != self._items:
            self._items = items
            self.changed.emit()
