"""Store format 7's metadata shards (terrain/store/shards.py): round trips, directed rounding,
deterministic bytes, and hostile bytes as one ShardError line."""

from __future__ import annotations

import struct
import zlib
from dataclasses import replace as dataclass_replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from globeview.terrain.store import shards as S
from globeview.terrain.store.layout import ShardRef, shard_chunks

TILE_N = 6
NS = 6
REF = ShardRef(6, 3, 5, 4)


def _shard(n_present: int = 3, seed: int = 0) -> S.Shard:
    rng = np.random.default_rng(seed)
    slots = shard_chunks(REF, TILE_N)
    present = np.zeros(len(slots), bool)
    present[rng.choice(len(slots), n_present, replace=False)] = True
    kk = 256
    errors = rng.uniform(0, 900, (n_present, kk, NS + 1))
    hmin = rng.uniform(-400, 4000, (n_present, kk)).astype(np.float32)
    hmin[:, :10] = np.nan
    errors[:, :10] = np.nan
    return S.Shard(
        REF,
        TILE_N,
        NS,
        present,
        tuple(("%064x" % (i + 1)) if i else "" for i in range(n_present)),
        np.arange(n_present, dtype=np.int64) * 1000,
        errors,
        hmin,
        hmin + np.float32(5),
        (
            S.ChildRef(3 << 4, 5 << 4, "ab" * 32, 1234),
            S.ChildRef(3 << 4, (5 << 4) + 1, "cd" * 32, 9),
        ),
    )


def test_round_trip_and_determinism() -> None:
    sh = _shard()
    data = S.encode(sh)
    assert data == S.encode(_shard())  # the same shard, the same bytes
    back = S.decode(data, REF, TILE_N, NS)
    assert (back.present == sh.present).all()
    assert back.chunk_sha256 == sh.chunk_sha256
    assert back.children == sh.children
    np.testing.assert_array_equal(back.hmin, sh.hmin)
    np.testing.assert_array_equal(back.hmax, sh.hmax)
    ok = np.isfinite(sh.errors)
    assert (back.errors[ok] >= sh.errors[ok]).all()  # errors rounded up: still bounds
    assert np.isnan(back.errors[~ok]).all()
    assert (back.errors[ok] <= sh.errors[ok] * (1 + 2**-10) + 1e-6).all()


@given(arrays(np.float64, 50, elements=st.floats(0, 60000)))
@settings(max_examples=100, deadline=None)
def test_directed_rounding(x: np.ndarray) -> None:
    assert (S.f16_up(x).astype(np.float64) >= x).all()
    assert (S.f32_down(x * 1.0001 - 500).astype(np.float64) <= x * 1.0001 - 500).all()
    assert (S.f32_up(x * 1.0001 - 500).astype(np.float64) >= x * 1.0001 - 500).all()


def _with_body(data: bytes, raw: bytes) -> bytes:
    head = bytearray(data[:64])
    z = zlib.compress(raw)
    struct.pack_into("<II", head, 28, len(z), len(raw))
    return bytes(head) + z


def _hostile() -> list[tuple[str, bytes, str]]:
    good = S.encode(_shard())
    raw = zlib.decompress(good[64:])
    bad_bits = bytearray(raw)
    bad_bits[0] ^= 0xFF  # availability no longer matches n_chunks
    neg = bytearray(raw)
    # Tile 20's error (finite) in the high byte plane (shuffled float16): make it negative.
    n = 3
    err_start = len(raw) - n * 256 * 8 - n * 256 * (NS + 1) * 2  # (after the chunk records)
    neg[err_start + n * 256 * (NS + 1) + 20 * (NS + 1)] |= 0x80
    lie = bytearray(good)
    struct.pack_into("<I", lie, 32, S.MAX_SHARD_BYTES + 1)
    return [
        ("empty", b"", "truncated"),
        ("truncated", good[:-7], "truncated"),
        ("magic", b"XXXX" + good[4:], "bad magic"),
        ("size lie", bytes(lie), "sizes do not add up"),
        ("garbage body", good[:64] + b"\x00" * (len(good) - 64), "damaged body"),
        ("bits", _with_body(good, bytes(bad_bits)), "availability"),
        ("negative", _with_body(good, bytes(neg)), "negative or infinite"),
    ]


@pytest.mark.parametrize(("name", "data", "words"), _hostile(), ids=lambda v: str(v)[:12])
def test_hostile_bytes_are_one_line(name: str, data: bytes, words: str) -> None:
    with pytest.raises(S.ShardError) as err:
        S.decode(data, REF, TILE_N, NS)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_other_subtree_or_parameters_refused() -> None:
    data = S.encode(_shard())
    with pytest.raises(S.ShardError, match="subtree"):
        S.decode(data, ShardRef(6, 3, 6, 4), TILE_N, NS)
    with pytest.raises(S.ShardError, match="tile_n"):
        S.decode(data, REF, TILE_N, NS + 1)


def test_a_zip_bomb_is_not_inflated() -> None:
    good = S.encode(_shard(1))
    bomb = zlib.compress(b"\x00" * (64 << 20))
    head = bytearray(good[:64])
    struct.pack_into("<II", head, 28, len(bomb), len(zlib.decompress(good[64:])))
    with pytest.raises(S.ShardError, match="damaged body"):
        S.decode(bytes(head) + bomb, REF, TILE_N, NS)


TOP = ShardRef(0, 0, 0, 6)


def _top(coverage: S.Coverage | None) -> S.Shard:
    slots = shard_chunks(TOP, TILE_N)
    e = np.zeros((0, 256, NS + 1))
    h = np.zeros((0, 256), np.float32)
    present = np.zeros(len(slots), bool)
    return S.Shard(TOP, TILE_N, NS, present, (), np.zeros(0, np.int64), e, h, h, (), None, coverage)


def test_the_top_shards_coverage_round_trips_and_a_shard_without_one_keeps_its_bytes() -> None:
    """The coverage (a top shard's node raster) comes back bit for bit; a shard without one
    is version 1, byte for byte what it was before coverages (stores built before read on)."""
    bits = np.random.default_rng(3).random((193, 321)) < 0.3
    data = S.encode(_top(S.Coverage(9, 1234, 70000, bits)))
    back = S.decode(data, TOP, TILE_N, NS).coverage
    assert back is not None and (back.level, back.row0, back.col0) == (9, 1234, 70000)
    np.testing.assert_array_equal(back.bits, bits)
    plain = S.encode(_top(None))
    assert struct.unpack_from("<H", plain, 4)[0] == 1 and plain[36:64] == bytes(28)
    assert S.decode(plain, TOP, TILE_N, NS).coverage is None
    assert struct.unpack_from("<H", data, 4)[0] == S.VERSION_COVERAGE


def test_hostile_coverages_are_one_line() -> None:
    good = S.encode(_top(S.Coverage(2, 0, 0, np.ones((257, 513), bool))))
    inner = S.encode(dataclass_replace(_shard(), coverage=None))
    as_inner = bytearray(inner)
    struct.pack_into("<H", as_inner, 4, S.VERSION_COVERAGE)  # only the top shard has one
    huge = bytearray(good)
    struct.pack_into("<II", huge, 45, 1 << 20, 1 << 20)  # rows, cols
    cases = [
        (good[:-3], "truncated"),
        (good + b"\x00", "padded"),
        (bytes(as_inner), "version 2"),
        (bytes(huge), "out of range"),
        (good[:64] + good[64:-8] + b"\x00" * 8, "damaged"),
    ]
    for data, words in cases:
        with pytest.raises(S.ShardError) as err:
            S.decode(data, REF if data is cases[2][0] else TOP, TILE_N, NS)
        assert words in str(err.value) and "\n" not in str(err.value), (words, err.value)
    with pytest.raises(ValueError, match="top shard"):
        S.encode(dataclass_replace(_shard(), coverage=S.Coverage(1, 0, 0, np.ones((2, 2), bool))))


def test_a_store_with_no_chunk_in_the_top_shard_writes_its_shards(tmp_path) -> None:
    """A source too small for any node of the coarse levels (a 4 km 1 m DTM has none of
    levels 0..5, whose nodes lie 7-80 km apart) leaves the top shard without a chunk; the
    tree is still written (it crashed on an empty array's reshape) and the top names the
    chain down to the chunks."""
    max_level = 18
    kk = 256
    records = {
        (lv, cy, cx): S.ChunkRecord(
            "%064x" % (lv + 1),
            100 + lv,
            np.full((16, 16, NS + 1), 0.5),
            np.zeros((16, 16)),
            np.ones((16, 16)),
        )
        for lv, cy, cx in ((6, 1, 2), (7, 2, 4), (11, 32, 77), (15, 519, 1235))
    }
    name, _sha, _size, count = S.write_tree(tmp_path, TILE_N, max_level, NS, records)
    assert count == 5  # the top and one shard a root level (6, 7, 11, 15)
    top = S.decode((tmp_path / name).read_bytes(), ShardRef(0, 0, 0, 6), TILE_N, NS)
    assert not top.present.any() and top.errors.shape == (0, kk, NS + 1)
    assert [(c.cy, c.cx) for c in top.children] == [(1, 2)]
