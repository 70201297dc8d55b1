"""Metadata shards of store format 7 (``.gvm`` files): per-chunk records and per-tile facts of
one subtree of the chunk tree (`layout.ShardRef`), binary and compressed (issue #25, design 2.4).

A shard holds, for each chunk slot of its subtree (`layout.shard_chunks` order) that has data
(tiles with data or a chunk file): the chunk file's sha256 and size (all-zero sha256 and size
0: no file, only edge nodes of its neighbours reach its tiles), and its k x k tiles' error and
stride errors (float16, rounded *up*: `f16_up`) and height range (float32, hmin rounded down,
hmax up), NaN hmin meaning "no data in that tile"; and, for each child shard (rooted at the
next root level under it), its root chunk, sha256 and size. Missing slots are chunks without
data: the layer below shows through. Heights and errors are metres.

Layout (little-endian, deterministic bytes)::

    header (64 B): magic "GVM7", u16 version, u8 tile_n, u8 n_strides, u16 k, u8 depth,
                   u8 root_level, u32 root_cy, u32 root_cx, u32 n_chunks, u32 n_children,
                   u32 body_zlen, u32 body_len, 28 B zero
    body (zlib):   availability bits (one per slot, little bit order, padded to bytes)
                   children  n_children x (u32 cy, u32 cx, 32 B sha256, u32 bytes), sorted
                   chunks    n_chunks x (32 B sha256, u32 bytes, u8 flags)
                   errors    n_chunks x k^2 x (1 + n_strides) float16, byte-shuffled
                   heights   n_chunks x k^2 x 2 (hmin, hmax) float32, byte-shuffled

The top shard may also carry the store's **coverage** (version 2; version 1 has none): which
nodes of one level hold data over the level's bbox, the raster a layer's blend mask is made
from (`Coverage`), so a remote store's first frame needs no chunk of that level. The header's
last 28 bytes then hold u8 level, u32 row0, u32 col0, u32 rows, u32 cols, u32 zlen, and the
bits (one per node, row-major, little bit order, zlib) follow the body.

`decode` is written for hostile bytes: sizes are checked against the header before anything
is inflated (no zip bomb: at most `MAX_SHARD_BYTES`), and every count, bit and value after;
anything wrong is a `ShardError` (one line).
"""

from __future__ import annotations

import dataclasses
import hashlib
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from globeview.terrain.store.layout import (
    ShardRef,
    chunk_tiles,
    shard_chunks,
    shard_file_name,
    shard_of,
)
from globeview.terrain.store.level_chunks import write_atomic

__all__ = [
    "MAGIC",
    "MAX_SHARD_BYTES",
    "ChildRef",
    "ChunkRecord",
    "Coverage",
    "Shard",
    "ShardError",
    "add_coverage",
    "decode",
    "encode",
    "f16_up",
    "f32_down",
    "f32_up",
    "write_tree",
]

MAGIC = b"GVM7"
VERSION = 1
#: A top shard with a `Coverage`.
VERSION_COVERAGE = 2
#: Most coverage nodes accepted (64 M bits: 8 MB packed).
MAX_COVERAGE_NODES = 1 << 26
#: Largest inflated shard body accepted (a planet shard of 85 chunks is ~1 MB raw).
MAX_SHARD_BYTES = 16 << 20
_HEADER = struct.Struct("<4sHBBHBBIIIIII28s")
_CHILD = struct.Struct("<II32sI")
_CHUNK = struct.Struct("<32sIB")
_NO_FILE = bytes(32)
_COVERAGE = struct.Struct("<BIIIII7x")  # in the header's last 28 bytes


class ShardError(ValueError):
    """Bytes that are not a sound shard of the expected subtree (one line)."""


@dataclass(frozen=True)
class ChildRef:
    """A child shard: root chunk (cy, cx) at the next root level, its file's sha256 and size."""

    cy: int
    cx: int
    sha256: str
    bytes: int


@dataclass(frozen=True, eq=False)
class Coverage:
    """Which nodes of level ``level`` hold data: ``bits[r, c]`` is global node row
    ``row0 + r``, column ``(col0 + c) mod`` the level's width (a bool raster over the
    level's bbox, a blend mask's input: `coverage.read_coverage`)."""

    level: int
    row0: int
    col0: int
    bits: np.ndarray


@dataclass(frozen=True, eq=False)
class Shard:
    """One decoded (or to-be-encoded) shard.

    present: (n_slots,) bool over `layout.shard_chunks(ref, tile_n)`; chunk_sha256 / chunk_bytes:
    per present chunk ("" and 0: no file); errors: (n_chunks, k*k, 1 + n_strides) float32
    metres (column 0 the tile error), NaN without data; hmin, hmax: (n_chunks, k*k) float32
    metres, NaN without data; tiles row-major within the chunk (tile (x0 + i % k, y0 + i // k)).
    """

    ref: ShardRef
    tile_n: int
    n_strides: int
    present: np.ndarray
    chunk_sha256: tuple[str, ...]
    chunk_bytes: np.ndarray
    errors: np.ndarray
    hmin: np.ndarray
    hmax: np.ndarray
    children: tuple[ChildRef, ...] = ()
    chunk_flags: np.ndarray | None = None  # (n_chunks,) `layout.EXTRA_ROW` | `EXTRA_COL`
    coverage: Coverage | None = None  # the top shard's only

    def slots(self) -> list[tuple[int, int, int]]:
        """(level, cy, cx) of the present chunks, in record order."""
        all_slots = shard_chunks(self.ref, self.tile_n)
        return [s for s, p in zip(all_slots, self.present) if p]


# ---------------------------------------------------------------------------------------------
# Directed rounding


def f16_up(x: np.ndarray) -> np.ndarray:
    """float16 of ``x`` rounded toward +inf (so a stored error bound stays a bound); NaN
    stays NaN. ValueError past float16's range (65 504 m)."""
    x = np.asarray(x, dtype=np.float64)
    h = x.astype(np.float16)
    low = h.astype(np.float64) < x
    h = np.where(low, np.nextafter(h, np.float16(np.inf)), h)
    if np.isinf(h[np.isfinite(x)]).any():
        raise ValueError("a tile error is past float16's range")
    return h.astype(np.float16)


def _f32(x: np.ndarray, up: bool) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    f = x.astype(np.float32)
    wrong = f.astype(np.float64) < x if up else f.astype(np.float64) > x
    toward = np.float32(np.inf if up else -np.inf)
    return np.where(wrong, np.nextafter(f, toward), f).astype(np.float32)


def f32_down(x: np.ndarray) -> np.ndarray:
    """float32 of ``x`` rounded toward -inf (hmin)."""
    return _f32(x, up=False)


def f32_up(x: np.ndarray) -> np.ndarray:
    """float32 of ``x`` rounded toward +inf (hmax)."""
    return _f32(x, up=True)


def _shuffle(a: np.ndarray) -> bytes:
    """Bytes grouped by significance (compresses better): the byte planes one after another."""
    w = a.dtype.itemsize
    return np.ascontiguousarray(a).view(np.uint8).reshape(-1, w).T.tobytes()


def _unshuffle(data: bytes, dtype: type, shape: tuple[int, ...]) -> np.ndarray:
    w = np.dtype(dtype).itemsize
    planes = np.frombuffer(data, dtype=np.uint8).reshape(w, -1)
    return np.ascontiguousarray(planes.T).view(dtype).reshape(shape)


# ---------------------------------------------------------------------------------------------
# Encoding


def encode(shard: Shard) -> bytes:
    """The shard's bytes (deterministic: the same shard, the same bytes).

    ``errors`` are rounded up to float16 here (`f16_up`); hmin/hmax must be float32 already
    (rounded outward by the caller: `f32_down` / `f32_up`)."""
    k = chunk_tiles(shard.tile_n)
    n = int(shard.present.sum())
    kk = k * k
    ns1 = shard.n_strides + 1
    if shard.errors.shape != (n, kk, ns1) or shard.hmin.shape != (n, kk):
        raise ValueError("shard arrays do not match its chunks")
    children = sorted(shard.children, key=lambda c: (c.cy, c.cx))
    body = [np.packbits(shard.present.astype(bool), bitorder="little").tobytes()]
    body += [_CHILD.pack(c.cy, c.cx, bytes.fromhex(c.sha256), c.bytes) for c in children]
    flags = shard.chunk_flags if shard.chunk_flags is not None else np.zeros(n, np.int64)
    body += [
        _CHUNK.pack(bytes.fromhex(h) if h else _NO_FILE, int(b), int(f))
        for h, b, f in zip(shard.chunk_sha256, shard.chunk_bytes, flags)
    ]
    body.append(_shuffle(f16_up(shard.errors)))
    heights = np.stack([shard.hmin, shard.hmax], axis=-1).astype(np.float32)
    body.append(_shuffle(heights))
    raw = b"".join(body)
    if len(raw) > MAX_SHARD_BYTES:
        raise ValueError("shard body over MAX_SHARD_BYTES")
    z = zlib.compress(raw, 6)
    ref = shard.ref
    cov, tail = _encode_coverage(shard)
    head = _HEADER.pack(
        MAGIC,
        VERSION if shard.coverage is None else VERSION_COVERAGE,
        shard.tile_n,
        shard.n_strides,
        k,
        ref.depth,
        ref.level,
        ref.cy,
        ref.cx,
        n,
        len(children),
        len(z),
        len(raw),
        cov,
    )
    return head + z + tail


def _encode_coverage(shard: Shard) -> tuple[bytes, bytes]:
    """(the header's last 28 bytes, the bytes after the body) for the shard's coverage."""
    c = shard.coverage
    if c is None:
        return bytes(28), b""
    if not shard.ref.is_top:
        raise ValueError("only the top shard carries a coverage")
    rows, cols = c.bits.shape
    if rows * cols > MAX_COVERAGE_NODES:
        raise ValueError("coverage over MAX_COVERAGE_NODES")
    z = zlib.compress(np.packbits(c.bits.astype(bool).ravel(), bitorder="little").tobytes(), 6)
    return _COVERAGE.pack(c.level, c.row0, c.col0, rows, cols, len(z)), z


# ---------------------------------------------------------------------------------------------
# Decoding (hostile input)


def decode(data: bytes, ref: ShardRef, tile_n: int, n_strides: int) -> Shard:
    """The shard ``ref`` of a store of ``tile_n`` with ``n_strides`` strides from its bytes;
    ShardError (one line) unless they are exactly that."""
    if len(data) < _HEADER.size:
        raise ShardError(f"truncated ({len(data)} bytes, no header)")
    (magic, version, t_n, n_s, k, depth, root, cy, cx, n, n_children, zlen, blen, cov) = (
        _HEADER.unpack_from(data)
    )
    if magic != MAGIC:
        raise ShardError("not a globeview metadata shard (bad magic)")
    if version not in (VERSION, VERSION_COVERAGE) or (
        version == VERSION_COVERAGE and not ref.is_top
    ):
        raise ShardError(f"shard version {version} is not supported")
    if (t_n, n_s, k) != (tile_n, n_strides, chunk_tiles(tile_n)):
        raise ShardError("tile_n, strides or chunk size do not match the store")
    if (root, cy, cx, depth) != tuple(ref):
        raise ShardError(
            f"holds subtree {root}/{cy}/{cx} (depth {depth}), not {'/'.join(map(str, ref))}"
        )
    slots = shard_chunks(ref, tile_n)
    kk = k * k
    n_bits = (len(slots) + 7) // 8
    want = (
        n_bits
        + n_children * _CHILD.size
        + n * _CHUNK.size
        + n * kk * (1 + n_strides) * 2
        + n * kk * 8
    )
    if n > len(slots) or blen != want or blen > MAX_SHARD_BYTES:
        raise ShardError(f"sizes do not add up ({n} chunks, body {blen} bytes)")
    level, row0, col0, rows, cols, czlen = (
        _COVERAGE.unpack(cov) if version == VERSION_COVERAGE else (0, 0, 0, 0, 0, 0)
    )
    if version == VERSION and cov != bytes(28):
        raise ShardError("reserved header bytes are not zero")
    end = _HEADER.size + zlen
    if len(data) != end + czlen:
        raise ShardError(f"truncated or padded ({len(data)} bytes, expected {end + czlen})")
    raw = _inflate(data[_HEADER.size : end], blen, "body")
    shard = _parse(raw, ref, tile_n, n_strides, slots, n, n_children)
    if version == VERSION:
        return shard
    if rows * cols > MAX_COVERAGE_NODES or not (rows and cols):
        raise ShardError(f"coverage of {rows} x {cols} nodes is out of range")
    packed = np.frombuffer(_inflate(data[end:], (rows * cols + 7) // 8, "coverage"), np.uint8)
    bits = np.unpackbits(packed, bitorder="little")
    if bits[rows * cols :].any():
        raise ShardError("coverage padding bits are not zero")
    coverage = Coverage(level, row0, col0, bits[: rows * cols].astype(bool).reshape(rows, cols))
    return dataclasses.replace(shard, coverage=coverage)


def _inflate(z: bytes, size: int, what: str) -> bytes:
    """``z`` inflated to exactly ``size`` bytes (ShardError naming ``what`` otherwise)."""
    try:
        d = zlib.decompressobj()
        raw = d.decompress(z, size + 1)
    except zlib.error as exc:
        raise ShardError(f"damaged {what} ({exc})") from None
    if len(raw) != size or not d.eof:
        raise ShardError(f"damaged {what} (wrong inflated size)")
    return raw


def _parse(
    raw: bytes,
    ref: ShardRef,
    tile_n: int,
    n_strides: int,
    slots: list[tuple[int, int, int]],
    n: int,
    n_children: int,
) -> Shard:
    k = chunk_tiles(tile_n)
    kk = k * k
    pos = (len(slots) + 7) // 8
    bits = np.unpackbits(np.frombuffer(raw[:pos], np.uint8), bitorder="little")
    present = bits[: len(slots)].astype(bool)
    if bits[len(slots) :].any() or int(present.sum()) != n:
        raise ShardError("availability bits do not match the chunk count")
    children = []
    for _ in range(n_children):
        ccy, ccx, sha, size = _CHILD.unpack_from(raw, pos)
        pos += _CHILD.size
        children.append(ChildRef(ccy, ccx, sha.hex(), size))
    _check_children(children, ref)
    shas, sizes, flags = [], [], []
    for _ in range(n):
        sha, size, flag = _CHUNK.unpack_from(raw, pos)
        pos += _CHUNK.size
        if flag > 3:
            raise ShardError("unknown chunk flags")
        shas.append("" if sha == _NO_FILE else sha.hex())
        sizes.append(size)
        flags.append(flag)
    e_len = n * kk * (1 + n_strides) * 2
    errors = _unshuffle(raw[pos : pos + e_len], np.float16, (n, kk, 1 + n_strides))
    pos += e_len
    heights = _unshuffle(raw[pos:], np.float32, (n, kk, 2))
    errors = errors.astype(np.float32)
    if np.isinf(errors).any() or (errors < 0).any() or np.isinf(heights).any():
        raise ShardError("holds negative or infinite values")
    return Shard(
        ref,
        tile_n,
        n_strides,
        present,
        tuple(shas),
        np.array(sizes, dtype=np.int64),
        errors,
        np.ascontiguousarray(heights[..., 0]),
        np.ascontiguousarray(heights[..., 1]),
        tuple(children),
        np.array(flags, dtype=np.int64),
    )


def _check_children(children: list[ChildRef], ref: ShardRef) -> None:
    """Children sorted, unique and inside the subtree (the top shard: anywhere)."""
    keys = [(c.cy, c.cx) for c in children]
    if keys != sorted(set(keys)):
        raise ShardError("child shards are not sorted or repeat")
    if ref.is_top:
        return
    for c in children:
        if (c.cy >> ref.depth, c.cx >> ref.depth) != (ref.cy, ref.cx):
            raise ShardError("a child shard lies outside the subtree")


# ---------------------------------------------------------------------------------------------
# Writing a store's shard tree (the ingest's last phase)


@dataclass(frozen=True, eq=False)
class ChunkRecord:
    """What the ingest knows of one chunk with data: its file ("" and 0: none), and its
    tiles' facts (metres, float64, (k, k) / (k, k, 1 + n_strides), NaN without data, tiles
    outside the level NaN): errors rounded up and heights outward when encoded."""

    sha256: str
    bytes: int
    errors: np.ndarray
    hmin: np.ndarray
    hmax: np.ndarray
    flags: int = 0  # `layout.EXTRA_ROW` | `layout.EXTRA_COL`


def write_tree(
    folder: Path,
    tile_n: int,
    max_level: int,
    n_strides: int,
    records: dict[tuple[int, int, int], ChunkRecord],
) -> tuple[str, str, int, int]:
    """Write every shard of a store whose chunks with data are ``records`` ((level, cy, cx)
    -> record) into ``folder`` (atomically, content-named), deepest first so each parent
    records its children's sha256; returns the top shard's (file name, sha256, bytes) and
    the number of shards written."""
    groups: dict[ShardRef, list[tuple[int, int, int]]] = {}
    for key in records:
        groups.setdefault(shard_of(*key, tile_n, max_level), []).append(key)
    top = shard_of(0, 0, 0, tile_n, max_level)
    groups.setdefault(top, [])
    # Every ancestor shard of a shard exists (it names it).
    todo = list(groups)
    while todo:
        ref = todo.pop()
        if not ref.is_top:
            parent = shard_of(ref.level - 1, ref.cy >> 1, ref.cx >> 1, tile_n, max_level)
            if parent not in groups:
                groups[parent] = []
                todo.append(parent)
    children: dict[ShardRef, list[ChildRef]] = {}
    for count, ref in enumerate(sorted(groups, key=lambda r: (-r.level, r.cy, r.cx)), 1):
        data = encode(
            _shard(ref, tile_n, n_strides, records, set(groups[ref]), children.get(ref, []))
        )
        sha = hashlib.sha256(data).hexdigest()
        name = shard_file_name(ref, sha)
        write_atomic(folder / name, data)
        if ref.is_top:
            return name, sha, len(data), count
        parent = shard_of(ref.level - 1, ref.cy >> 1, ref.cx >> 1, tile_n, max_level)
        children.setdefault(parent, []).append(ChildRef(ref.cy, ref.cx, sha, len(data)))
    raise AssertionError("no top shard")  # pragma: no cover - the top is always in groups


def add_coverage(
    folder: Path, name: str, tile_n: int, max_level: int, n_strides: int, coverage: Coverage
) -> tuple[str, str, int]:
    """Write the top shard ``name`` of the store in ``folder`` again with ``coverage``
    (content-named, atomically; the old file is left to the caller); returns the new file's
    (name, sha256, bytes)."""
    ref = shard_of(0, 0, 0, tile_n, max_level)
    shard = decode((folder / name).read_bytes(), ref, tile_n, n_strides)
    data = encode(dataclasses.replace(shard, coverage=coverage))
    sha = hashlib.sha256(data).hexdigest()
    new = shard_file_name(ref, sha)
    write_atomic(folder / new, data)
    return new, sha, len(data)


def _shard(
    ref: ShardRef,
    tile_n: int,
    n_strides: int,
    records: dict[tuple[int, int, int], ChunkRecord],
    mine: set[tuple[int, int, int]],
    children: list[ChildRef],
) -> Shard:
    slots = shard_chunks(ref, tile_n)
    present = np.array([s in mine for s in slots], dtype=bool)
    keys = [s for s in slots if s in mine]
    k = chunk_tiles(tile_n)
    recs = [records[s] for s in keys]
    # Explicit sizes: a shard may hold no chunk (an ancestor naming its children; the top
    # shard of a source too small for any node of the coarse levels), and -1 cannot be
    # inferred from an empty array.
    errors = np.array([r.errors for r in recs], dtype=np.float64).reshape(
        len(recs), k * k, n_strides + 1
    )
    return Shard(
        ref,
        tile_n,
        n_strides,
        present,
        tuple(r.sha256 for r in recs),
        np.array([r.bytes for r in recs], dtype=np.int64),
        errors,
        f32_down(np.array([r.hmin for r in recs]).reshape(len(recs), k * k)),
        f32_up(np.array([r.hmax for r in recs]).reshape(len(recs), k * k)),
        tuple(children),
        np.array([r.flags for r in recs], dtype=np.int64),
    )
