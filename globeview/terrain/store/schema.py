"""The tile store's manifest (``manifest.json``) as typed, versioned dataclasses.

ONE definition of the format: `globeview.terrain.ingest.driver` builds a `StoreManifest` and writes
it with `StoreManifest.write`; `globeview.terrain.store.tile_store` reads it with
`StoreManifest.from_json`. The JSON keys *are* the dataclass field names (nothing spells a
key a second time), and both directions are driven by the fields and their annotations, so a
field added here is written and read with no other change.

Reading is for untrusted JSON: `from_json` checks every value's type (integers are not
bools or floats, numbers are finite) and then `check` the meaning (ranges, array shapes,
level file names, non-negative errors); anything wrong is a `ManifestError` whose message is
one line naming the field (``levels[3].extent.nx must be ...``).

Units and frames: heights and tile errors are metres above the WGS84 ellipsoid (since
format 4), angles are degrees (EPSG:4326 lon/lat), bboxes are quadtree tile indices of their
level (see `globeview.terrain.levels`).

Versions: 7 (issue #25) lays every level on the global chunk grid (`layout`): chunk files
exist only where there is data, the per-tile metadata lives in binary shards (`shards`) and
the manifest is O(levels), so no tile count caps a store; 6 and 5 were dense (one extent per
level, per-tile arrays in the manifest; 6 continued the surface past data edges, issue #29):
they are not read any more, `TileStore.open` says to rebuild them
(`DENSE_FORMAT_VERSIONS`); 4 heights are ellipsoidal (each source's vertical datum
recorded); 3 added the ``format`` marker; 2 had no marker. Only `FORMAT_VERSION` is read;
older stores are rebuilt (`built_before_vdatums` says which must be), newer ones are refused.
"""

from __future__ import annotations

import json
import math
import re
import types
import typing
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from functools import cache
from typing import Any, TextIO

import numpy as np

from globeview import __version__
from globeview.terrain.dem.vdatum import VDATUM_CHOICES
from globeview.terrain.levels import LevelGrid
from globeview.terrain.quadtree import level_shape
from globeview.terrain.store.layout import chunk_tiles, is_store_path, shard_roots

__all__ = [
    "DENSE_FORMAT_VERSIONS",
    "FORMAT_VERSION",
    "MAX_LEVEL_LIMIT",
    "STORE_FORMAT",
    "TILE_N_RANGE",
    "VDATUM_FORMAT_VERSION",
    "Extent",
    "FileRef",
    "IngestParams",
    "LevelRecord",
    "ManifestError",
    "PoleHeights",
    "ShardsRecord",
    "SourceRecord",
    "StoreHeader",
    "StoreManifest",
    "built_before_vdatums",
    "level_file_name",
    "write_json_array",
]

STORE_FORMAT = "globeview-tile-store"
FORMAT_VERSION = 7
#: Format versions of the dense layout (one extent per level, per-tile arrays in the manifest):
#: not read any more, rebuilt (`TileStore.open` says how).
DENSE_FORMAT_VERSIONS = (5, 6)
# The first version whose heights are ellipsoidal: older stores must never be mixed with newer.
VDATUM_FORMAT_VERSION = 4
MAX_LEVEL_LIMIT = 22  # 180/2^22/64 degrees ~ 7 mm at the equator: far past any DEM
TILE_N_RANGE = (1, 10)
MAX_STRIDES = 16
MAX_STRIDE = 1 << 20

# A field whose own fields sit in the enclosing JSON object instead of a nested one.
_INLINE = "inline"

_SHA256 = re.compile(r"^[0-9a-f]{64}$")


def level_file_name(level: int) -> str:
    """The VRT that mosaics a level's chunk files (what ``gdalinfo`` / QGIS open)."""
    return f"level_{level:02d}.vrt"


class ManifestError(ValueError):
    """A manifest that does not follow the schema (one line, naming the field)."""


def built_before_vdatums(version: object) -> bool:
    """Whether a store of this format version holds unconverted (pre-datum) heights."""
    return (
        isinstance(version, int)
        and not isinstance(version, bool)
        and version < VDATUM_FORMAT_VERSION
    )


# ---------------------------------------------------------------------------------------------
# The schema


@dataclass(frozen=True)
class StoreHeader:
    """What identifies a store. Typed `object` on purpose: `peek` reads these from *any*
    JSON object (somebody else's manifest too) without judging them; `StoreManifest.check`
    then insists on this globeview's format and version."""

    format: object = None  # STORE_FORMAT: only globeview writes it (positive recognition)
    format_version: object = None  # FORMAT_VERSION when written by this globeview
    created_by: object = None  # "globeview X.Y.Z"

    @classmethod
    def peek(cls, raw: Mapping[str, object]) -> StoreHeader:
        """The header fields of a parsed JSON object, unchecked (None where absent)."""
        return cls(**{f.name: raw.get(f.name) for f in fields(cls)})

    @classmethod
    def current(cls) -> StoreHeader:
        """The header this globeview writes."""
        return cls(STORE_FORMAT, FORMAT_VERSION, f"globeview {__version__}")


@dataclass(frozen=True)
class Extent:
    """A level's tile extent: tiles x0..x0+nx-1 (columns modulo 2^(L+1)), rows y0..y0+ny-1."""

    x0: int
    y0: int
    nx: int
    ny: int

    @classmethod
    def of(cls, grid: LevelGrid) -> Extent:
        return cls(int(grid.x0), int(grid.y0), int(grid.nx), int(grid.ny))


@dataclass(frozen=True)
class PoleHeights:
    """The single height (metres) of each pole point when the data reaches it, else None."""

    north: float | None = None
    south: float | None = None

    def as_dict(self) -> dict[str, float | None]:
        """{"north": h, "south": h} (the form `TileStore.pole_heights` has)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class IngestParams:
    """The ingest parameters a store was built with (None: the default / the file's own)."""

    tile_n: int
    max_level: int | None
    wavelet: str
    crs: str | None
    vdatum: str | None


@dataclass(frozen=True)
class SourceRecord:
    """One source DEM: where it was, its content identity and its vertical datum.

    bounds: data footprint (west, south, east, north), degrees; res_deg: (dlon, dlat)
    pixel size, degrees; vertical_datum: "ellipsoid" | "egm96" (heights are converted to
    ellipsoidal ones at ingest); vertical_datum_source: why that datum (CRS, file kind,
    --vdatum); heights: what ingest did, for people.
    """

    path: str
    size: int  # bytes
    sha256: str
    crs: str
    bounds: tuple[float, ...]
    res_deg: tuple[float, ...]
    vertical_datum: str
    vertical_datum_source: str
    heights: str


@dataclass(frozen=True)
class FileRef:
    """A file of the store named by its content: ``file`` (relative to the store, a name
    `layout.is_store_path` accepts), its sha256 (hex) and size in bytes."""

    file: str
    sha256: str
    bytes: int

    def check(self, where: str) -> None:
        if not is_store_path(self.file):
            raise ManifestError(f"{where}.file {self.file[:60]!r} is not a store file name")
        if not _SHA256.match(self.sha256):
            raise ManifestError(f"{where}.sha256 is not a sha256 hex digest")
        _in_range(self.bytes, f"{where}.bytes", 0, 1 << 40)


@dataclass(frozen=True)
class LevelRecord:
    """One pyramid level's summary (its per-tile metadata lives in the shards).

    bbox: the tile bbox (x0, y0, nx, ny) of the level's chunks with data (columns modulo
    2^(L+1): the shortest circular interval), None when the level has none; chunks: chunk
    files; tiles: tiles with data; bytes: of the chunk files; level_error: max tile error
    (metres, None without data); file / sha256: the level's VRT (sizing `gdalinfo` views).
    """

    level: int
    node_spacing_deg: float
    file: str
    sha256: str
    chunks: int
    tiles: int
    bytes: int
    bbox: Extent | None = None
    level_error: float | None = None
    pole_heights: PoleHeights | None = None

    def grid(self, tile_n: int) -> LevelGrid:
        """The raster geometry of the level's bbox (a 1 x 1 tile grid at 0, 0 without one)."""
        e = self.bbox or Extent(0, 0, 1, 1)
        return LevelGrid(self.level, tile_n, e.x0, e.y0, e.nx, e.ny)

    def check(self, index: int) -> None:
        """ManifestError unless this is a sound record of level ``index``."""
        where = f"levels[{index}]"
        if self.level != index:
            raise ManifestError(f"{where}.level is {self.level}, expected {index}")
        ncols, nrows = level_shape(index)
        e = self.bbox
        if e is not None:
            _in_range(e.x0, f"{where}.bbox.x0", 0, ncols - 1)
            _in_range(e.y0, f"{where}.bbox.y0", 0, nrows - 1)
            _in_range(e.nx, f"{where}.bbox.nx", 1, ncols)
            _in_range(e.ny, f"{where}.bbox.ny", 1, nrows - e.y0)
        want = level_file_name(index)
        if self.file != want:
            raise ManifestError(f"{where}.file {self.file[:60]!r} is not its level file {want}")
        if not _SHA256.match(self.sha256):
            raise ManifestError(f"{where}.sha256 is not a sha256 hex digest")
        for name in ("chunks", "tiles", "bytes"):
            _in_range(getattr(self, name), f"{where}.{name}", 0, 1 << 50)
        if self.level_error is not None and self.level_error < 0:
            raise ManifestError(f"{where}: negative tile errors")


@dataclass(frozen=True)
class ShardsRecord:
    """The metadata shards: their root levels (`layout.shard_roots`), how many there are and
    the top shard (the others are named by their parents' child tables)."""

    roots: tuple[int, ...]
    count: int
    top: FileRef


@dataclass(frozen=True, eq=False)
class StoreManifest:
    """The whole manifest (format 7: O(levels) in size, whatever the data's extent).
    ``header`` is inline: its fields are top-level JSON keys.

    bounds: data footprint (west, south, east, north), degrees, west > east across the
    antimeridian; strides: the sample strides of the shards' stride errors; chunk_tiles: k
    (`layout.chunk_tiles`); tile_size: samples per tile side, 2^tile_n + 1.
    """

    header: StoreHeader = field(metadata={_INLINE: True})
    sources: tuple[SourceRecord, ...]
    params: IngestParams
    tile_n: int
    tile_size: int
    chunk_tiles: int
    wavelet: str
    max_level: int
    strides: tuple[int, ...]
    bounds: tuple[float, ...]
    levels: tuple[LevelRecord, ...]
    shards: ShardsRecord
    pole_heights: PoleHeights | None = None
    #: How many updates the store has had (0: a first build, and stores written before
    #: generations, which lack the key); `terrain.store.generations`.
    generation: int = 0

    @classmethod
    def from_json(cls, raw: object) -> StoreManifest:
        """A checked manifest from parsed JSON; ManifestError (one line) if it is not one."""
        try:
            man = _decode_object(cls, raw, "")
        except RecursionError:
            raise ManifestError("nested too deeply") from None
        man.check()
        return man

    def check(self) -> None:
        """ManifestError unless every value is in range and consistent with the others."""
        h = self.header
        if h.format != STORE_FORMAT:
            raise ManifestError(f"format is not {STORE_FORMAT!r}")
        # An int, not 4.0 or true (which compare equal to 4 and 1): only globeview writes it.
        if type(h.format_version) is not int or h.format_version != FORMAT_VERSION:
            raise ManifestError(f"format_version {str(h.format_version)[:20]} is not supported")
        if not isinstance(h.created_by, str):
            raise ManifestError("created_by must be a string")
        _in_range(self.tile_n, "tile_n", *TILE_N_RANGE)
        if self.tile_size != (1 << self.tile_n) + 1:
            raise ManifestError(f"tile_size {self.tile_size} is not 2^tile_n + 1")
        if self.chunk_tiles != chunk_tiles(self.tile_n):
            raise ManifestError(f"chunk_tiles {self.chunk_tiles} is not {chunk_tiles(self.tile_n)}")
        _in_range(self.max_level, "max_level", 0, MAX_LEVEL_LIMIT)
        if not 0 < len(self.strides) <= MAX_STRIDES:
            raise ManifestError(f"strides must hold 1..{MAX_STRIDES} strides")
        for i, s in enumerate(self.strides):
            _in_range(s, f"strides[{i}]", 1, MAX_STRIDE)
        if len(self.bounds) != 4:
            raise ManifestError("bounds must be 4 numbers (west, south, east, north)")
        if len(self.levels) != self.max_level + 1:
            raise ManifestError(f"{len(self.levels)} levels do not match max_level")
        for i, lv in enumerate(self.levels):
            lv.check(i)
        if self.shards.roots != shard_roots(self.max_level, self.tile_n):
            raise ManifestError("shards.roots are not this store's shard levels")
        _in_range(self.shards.count, "shards.count", 1, 1 << 40)
        _in_range(self.generation, "generation", 0, 1 << 62)
        self.shards.top.check("shards.top")
        if not self.shards.top.file.startswith("meta/top-"):
            raise ManifestError("shards.top.file is not a top shard")
        for i, src in enumerate(self.sources):
            where = f"sources[{i}]"
            if src.size < 0 or len(src.bounds) != 4 or len(src.res_deg) != 2:
                raise ManifestError(f"{where}: bad size, bounds or res_deg")
            if src.vertical_datum not in VDATUM_CHOICES:
                raise ManifestError(f"{where}.vertical_datum {src.vertical_datum[:20]!r} unknown")

    def write(self, f: TextIO) -> None:
        """Write as compact JSON."""
        slots = _ArraySlots()
        slots.write(_encode(self, slots), f)


# ---------------------------------------------------------------------------------------------
# Reading: driven by the fields and their annotations


def _in_range(v: int, name: str, lo: int, hi: int) -> None:
    if not lo <= v <= hi:
        raise ManifestError(f"{name} must be in {lo}..{hi}, got {str(v)[:40]}")


@cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _decode(tp: Any, value: object, where: str) -> object:
    """``value`` (parsed JSON) as an instance of the annotation ``tp``; ManifestError if not."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _decode(inner, value, where)
    if origin is tuple:
        if not isinstance(value, list):
            raise ManifestError(f"{where} must be a list")
        item = typing.get_args(tp)[0]
        return tuple(_decode(item, v, f"{where}[{i}]") for i, v in enumerate(value))
    if tp is object:
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ManifestError(f"{where} must be an integer, got {str(value)[:40]}")
        return value
    if tp is float:
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not math.isfinite(value)
        ):
            raise ManifestError(f"{where} must be a finite number, got {str(value)[:40]}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ManifestError(f"{where} must be a string, got {str(value)[:40]}")
        return value
    if tp is np.ndarray:
        return _decode_array(value, where)
    if is_dataclass(tp) and isinstance(tp, type):
        return _decode_object(tp, value, where)
    raise TypeError(f"store schema: no decoder for {tp!r} ({where})")  # a schema bug


def _decode_object(cls: type, value: object, where: str) -> Any:
    """A dataclass from a JSON object: its fields' keys, decoded by their annotations.
    Absent keys take the field's default (required fields have none); unknown keys are
    ignored (a store of another version is refused by its header before this)."""
    if not isinstance(value, dict):
        raise ManifestError(f"{where or 'the manifest'} must be an object")
    hints = _hints(cls)
    kwargs: dict[str, object] = {}
    for f in fields(cls):
        if f.metadata.get(_INLINE):
            kwargs[f.name] = _decode_object(hints[f.name], value, where)
            continue
        name = f"{where}.{f.name}" if where else f.name
        if f.name not in value:
            if f.default is MISSING and f.default_factory is MISSING:
                raise ManifestError(f"{name} is missing")
            continue
        kwargs[f.name] = _decode(hints[f.name], value[f.name], name)
    return cls(**kwargs)


def _decode_array(value: object, where: str) -> np.ndarray:
    """A float64 array from nested lists (null = NaN); its shape is checked by the record."""
    if not isinstance(value, list):
        raise ManifestError(f"{where} must be a list of numbers")
    try:
        a = np.array(value, dtype=np.float64)
    except (ValueError, TypeError, OverflowError) as exc:
        raise ManifestError(f"{where} is not an array of numbers ({type(exc).__name__})") from None
    return a


# ---------------------------------------------------------------------------------------------
# Writing


def _encode(value: object, slots: _ArraySlots) -> object:
    """JSON-ready form of a schema value; arrays become placeholders filled by `slots`."""
    if is_dataclass(value) and not isinstance(value, type):
        out: dict[str, object] = {}
        for f in fields(value):
            v = _encode(getattr(value, f.name), slots)
            if f.metadata.get(_INLINE):
                assert isinstance(v, dict)
                out.update(v)
            else:
                out[f.name] = v
        return out
    if isinstance(value, tuple | list):
        return [_encode(v, slots) for v in value]
    if isinstance(value, np.ndarray):
        return slots.add(value)
    return value


def write_json_array(f: TextIO, a: np.ndarray) -> None:
    """Write compact JSON of an array (NaN as null) to ``f``, one row at a time.

    Nested Python lists of a whole level (``json.dumps(a.tolist())``) cost ~32 bytes a
    number, several hundred bytes a tile: at a million tiles, more than the memory bound.
    Row by row, the peak is one row.
    """
    rows = [a] if a.ndim <= 1 else a
    if a.ndim > 1:
        f.write("[")
    for i, row in enumerate(rows):
        if i:
            f.write(",")
        f.write(json.dumps(row.tolist(), separators=(",", ":")).replace("NaN", "null"))
    if a.ndim > 1:
        f.write("]")


class _ArraySlots:
    """Placeholders for arrays in a JSON-ready object, streamed as JSON text by `write`."""

    def __init__(self) -> None:
        self.arrays: list[np.ndarray] = []

    def add(self, a: np.ndarray) -> str:
        self.arrays.append(a)
        return f"\x00array{len(self.arrays) - 1}\x00"

    def write(self, obj: object, f: TextIO) -> None:
        parts = re.split(r'"\\u0000array(\d+)\\u0000"', json.dumps(obj, separators=(",", ":")))
        for i, part in enumerate(parts):
            if i % 2:
                write_json_array(f, self.arrays[int(part)])
            else:
                f.write(part)
