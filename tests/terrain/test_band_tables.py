"""The border blend's difference tables kept in the cache between sessions (issue #27, the
window's launch): a stack that reads them back gives the very stride errors of one that
measured them, without composing a tile; a damaged file, another layer order or other terrain
code measures."""

from __future__ import annotations

import numpy as np
import pytest

import globeview.terrain.compose.band_tables as band_tables
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.quadtree import tile_bounds_arrays, tiles_covering

BOX = (-73.0, 43.0, -70.0, 46.0)  # around the N44W072 sample and its border band
LEVELS = range(3, 9)


@pytest.fixture(scope="module")
def stores():
    from globeview.terrain.embedded import embedded_stores

    return {s.path.name.split("-")[0]: s for s in embedded_stores()}


@pytest.fixture
def kept(tmp_path, monkeypatch):
    """The tables' folder, empty, in place of the user's cache."""
    monkeypatch.setattr(band_tables, "cache_dir", lambda: tmp_path)
    return tmp_path / "band-tables"


def _errors(stack: TerrainStack) -> list[np.ndarray]:
    return [stack.metadata(lv, *tiles_covering(lv, *BOX)).stride_error for lv in LEVELS]


def _stack(stores, names=("etopo20", "N44W072")) -> TerrainStack:
    return TerrainStack.from_stores([stores[n] for n in names])


def _no_composing(stack: TerrainStack, monkeypatch) -> None:
    def refuse(*args, **kwargs):
        raise AssertionError("a kept table was measured again")

    monkeypatch.setattr(stack._tiles, "compose", refuse)


def test_kept_tables_give_the_same_errors_without_composing(stores, kept, monkeypatch):
    measured = _errors(_stack(stores))
    files = sorted(kept.glob("*.npz"))
    assert files, "no table was kept"
    again = _stack(stores)
    _no_composing(again, monkeypatch)
    for a, b in zip(measured, _errors(again), strict=True):
        np.testing.assert_array_equal(a, b)  # the same bits
    assert sorted(kept.glob("*.npz")) == files


def test_a_damaged_table_is_measured_again(stores, kept):
    measured = _errors(_stack(stores))
    for f in kept.glob("*.npz"):
        f.write_bytes(b"not a table")
    for a, b in zip(measured, _errors(_stack(stores)), strict=True):
        np.testing.assert_array_equal(a, b)


def test_the_key_changes_with_the_terrain_code(stores, monkeypatch):
    upper = band_tables.store_digest(stores["N44W072"])
    assert upper is not None
    key = band_tables.tables_key(upper, [], 5, True)
    assert len(band_tables.code_digest()) == 64
    monkeypatch.setattr(band_tables, "code_digest", lambda: "edited")
    assert band_tables.tables_key(upper, [], 5, True) != key


def test_the_key_names_the_layers_below_and_the_level(stores):
    upper = band_tables.store_digest(stores["N44W072"])
    base = band_tables.store_digest(stores["etopo20"])
    other = band_tables.store_digest(stores["craterlake"])
    assert upper is not None and base is not None and other is not None
    key = band_tables.tables_key(upper, [base], 5, True)
    assert key == band_tables.tables_key(upper, [base], 5, True)
    assert key != band_tables.tables_key(upper, [other], 5, True)
    assert key != band_tables.tables_key(upper, [base, other], 5, True)
    assert key != band_tables.tables_key(upper, [base], 6, True)
    assert key != band_tables.tables_key(upper, [base], 5, False)


def test_a_table_of_another_shape_is_not_used(kept):
    shape = (2, 3)
    n = band_tables.N_STRIDES
    good = (np.ones(shape), np.ones((*shape, n)), np.zeros((*shape, n)))
    band_tables.save_tables("k", good)
    loaded = band_tables.load_tables("k", shape)
    assert loaded is not None
    for a, b in zip(good, loaded, strict=True):
        np.testing.assert_array_equal(a, b)
    assert band_tables.load_tables("k", (3, 2)) is None
    assert band_tables.load_tables("missing", shape) is None


def test_the_band_counts_only_the_tiles_it_measures(stores):
    """`_exact_level` counts the band tiles with data (those `_difference_table` measures),
    not a format-7 level grid's empty chunk tiles: counting those made N44W072's level 12
    band 1924 tiles, past DIFF_TABLE_TILES, so it was bounded from level 11 (2x triangles)."""
    st = stores["N44W072"]
    stack = _stack(stores)
    band = stack._band
    mask = stack.blend_mask(st)
    for level in range(st.max_level + 1):
        g = st.level_grid(level)
        ys, xs = np.mgrid[g.y0 : g.y0 + g.ny, g.x0 : g.x0 + g.nx]
        xs = xs % g.ncols
        brute = 0
        for x, y in zip(xs.ravel().tolist(), ys.ravel().tolist(), strict=True):
            bounds = tile_bounds_arrays(level, np.array([x]), np.array([y]))
            brute += bool(st.has_data(level, x, y)) and bool(mask.touches_band(*bounds)[0])
        band._exact_level(1, st, level)
        assert band._band_counts[(st, level)] == brute, level
    assert band._exact_level(1, st, st.max_level) == st.max_level
