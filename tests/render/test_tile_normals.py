"""Normals of tiles finer than their data (issue #29, item 6; `render/tile_normals.py`): the
data level's normals interpolated with Catmull-Rom cubics, without the bilinear surface's
creases, and equal on both sides of every tile edge, across ancestors and across levels."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.render.renderer import tile_bounds_tuple
from globeview.render.tile_mesh import build_tile_mesh
from globeview.render.tile_normals import DataLevelNormals, catmull_rom_weights, data_level
from globeview.terrain.quadtree import key_for_lonlat

#: White Mountains (SRTM3, the store's level 12): rough terrain.
LON, LAT = -71.3, 44.25


@pytest.fixture
def stack():
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores

    return TerrainStack.from_stores(embedded_stores())


def _key(level: int, lon: float = LON, lat: float = LAT) -> tuple[int, int, int]:
    kx, ky = key_for_lonlat(level, np.array([lon]), np.array([lat]))
    return (level, int(np.ravel(kx)[0]), int(np.ravel(ky)[0]))


@pytest.mark.parametrize(("f", "d"), [(1, 0), (1, 1), (2, 3), (4, 9)])
def test_catmull_rom_weights_are_exact_for_quadratics(f, d):
    w = catmull_rom_weights(65, f, d)
    x = np.arange(-1.0, 66.0)  # the apron grid's node positions in ancestor nodes
    pos = (d * 64 + np.arange(65)) / 2**f
    for k in range(3):
        np.testing.assert_allclose(w @ x**k, pos**k, atol=1e-9)
    on_node = pos == np.round(pos)  # descendant nodes on ancestor nodes take their values
    np.testing.assert_array_equal(w[on_node], np.eye(67)[np.round(pos[on_node]).astype(int) + 1])
    assert not w.flags.writeable


@pytest.mark.slow
def test_data_level_is_the_finest_layer_here(stack):
    assert data_level(stack, _key(14)) == 12  # SRTM3's store ends at level 12
    assert data_level(stack, _key(9)) == 9  # within the data: the tile's own
    assert data_level(stack, _key(8, -40.0, 30.0)) == 3  # mid-Atlantic: etopo20's level 3
    normals = DataLevelNormals(stack)
    assert normals.normals(_key(12)) is None  # at its data level: its own normals
    assert normals.normals(_key(14)).shape == (65, 65, 3)


@pytest.mark.slow
def test_no_creases_at_the_data_node_lines(stack):
    """The tile's own triangles put nearly all of the normals' change across a data node line
    in the two cells beside it (the bilinear surface's crease); interpolated, it is spread."""
    key = _key(14)
    ph = ((key[1] & 3) * 64 + np.arange(65)) % 4  # columns' offsets from the data's nodes
    beside = (ph[:-1] == 0) | (ph[1:] == 0)

    def crease_ratio(n: np.ndarray) -> float:
        change = np.linalg.norm(np.diff(n, axis=1), axis=-1).mean(axis=0)
        return float(change[beside].mean() / change[~beside].mean())

    bounds = tile_bounds_tuple(key)
    own = build_tile_mesh(bounds, stack.heights(key), 10.0, stack.heights_apron(key))
    assert crease_ratio(own.normals) > 3.0  # 4.9
    new = DataLevelNormals(stack).normals(key)
    assert 0.8 < crease_ratio(new) < 1.25  # 0.98
    np.testing.assert_allclose(np.linalg.norm(new, axis=-1), 1.0, atol=1e-6)
    # The same surface: 1.2 degrees from the own normals on average, 8.3 at most (creases).
    angle = np.degrees(np.arccos(np.clip((new * own.normals).sum(-1), -1.0, 1.0)))
    assert angle.mean() < 2.0 and angle.max() < 10.0


@pytest.mark.slow
def test_edges_agree_across_ancestors(stack):
    """Two level-14 tiles on either side of a level-12 tile's edge (different ancestors)."""
    level, x, y = _key(14)
    x |= 3  # the last column of tiles under its level-12 ancestor
    normals = DataLevelNormals(stack)
    west, east = normals.normals((level, x, y)), normals.normals((level, x + 1, y))
    np.testing.assert_allclose(west[:, -1], east[:, 0], atol=2e-6)


@pytest.mark.slow
def test_edges_agree_across_levels(stack):
    """A level-12 tile (its own normals, which the texture interpolates linearly) and the
    level-13 and -14 tiles east of it agree on their shared edge's nodes."""
    normals = DataLevelNormals(stack)
    level, x, y = _key(12)
    coarse = build_tile_mesh(
        tile_bounds_tuple((level, x, y)),
        stack.heights((level, x, y)),
        10.0,
        stack.heights_apron((level, x, y)),
    ).normals[:, -1]
    for f in (1, 2):
        for dy in range(2**f):
            fine = normals.normals((level + f, (x + 1) << f, (y << f) + dy))[:, 0]
            rows = dy * 64 + np.arange(65)  # the fine nodes in coarse node units * 2^f
            on = rows % 2**f == 0
            np.testing.assert_allclose(fine[on], coarse[rows[on] >> f], atol=2e-6)
            # Between them: the cubic along the edge, near the coarse tile's linear one (1.2
            # degrees at most here: the seam a level change leaves).
            i = np.minimum(rows >> f, 63)
            t = rows / 2**f - i
            lin = coarse[i] * (1 - t)[:, None] + coarse[i + 1] * t[:, None]
            lin /= np.linalg.norm(lin, axis=-1, keepdims=True)
            assert np.degrees(np.arccos(np.clip((fine * lin).sum(-1), -1, 1))).max() < 2.0


@pytest.mark.slow
def test_normals_follow_the_terrain_version(stack):
    normals = DataLevelNormals(stack)
    key = _key(14)
    before = normals.normals(key)
    stack.set_visible(stack.layers[1].name, False)  # SRTM hidden: etopo20's level 3 is left
    assert data_level(stack, key) == 3
    after = normals.normals(key)
    assert np.abs(after - before).max() > 0.05
