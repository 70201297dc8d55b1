"""Tiles a layer cannot serve now (a remote store's tile that failed with HTTP 500, or one not
fetched yet on the window's UI thread, `TileNotReady`) never fail the stack's metadata, so
never the LOD selection (issue #18): the border band's difference tables bound those tiles
from the height ranges (never below the measured bound) and measure them once they can be
read; tiles finer than the layer's data keep their ancestors' bound until the ancestor can be
read. Fault injection: a real store whose reads raise `StoreError` for chosen tiles."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from globeview.errors import StoreError
from globeview.terrain.compose import band_errors
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.store.tile_store import TileStore

DATA = Path(__file__).resolve().parents[2] / "data"


class FlakyStore(TileStore):
    """A local store whose reads of the tiles in ``failing`` raise StoreError (as a remote
    store's do while its server answers 500 or the tile is not fetched yet)."""

    failing: set[tuple[int, int, int]]

    def heights_padded(self, key):
        if tuple(int(v) for v in key) in getattr(self, "failing", set()):
            raise StoreError(f"tile {tuple(key)}: HTTP 500 (injected)")
        return super().heights_padded(key)


@pytest.fixture(scope="module")
def vancouver_store(tmp_path_factory) -> Path:
    from globeview.terrain.ingest.driver import ingest

    out = tmp_path_factory.mktemp("stores") / "vancouver"
    ingest([DATA / "topobathy_vancouver.tif"], out)
    return out


def _stack(vancouver_store: Path, failing: set) -> tuple[TerrainStack, FlakyStore]:
    from globeview.terrain.embedded import embedded_stores

    base = embedded_stores()[0]  # etopo20, the bottom layer the window always has
    top = FlakyStore.open(vancouver_store)
    stack = TerrainStack.from_stores([base, top], ["etopo20", "vancouver"])
    # The blend mask is read whole before the layer is used (the window's loader thread does
    # it for a remote store: globeview.ui.loading.warm_remote_store).
    stack.blend_weight(1, np.zeros(1), np.zeros(1))
    top.failing = set(failing)
    return stack, top


def _band_tiles(st: TileStore, level: int) -> tuple[np.ndarray, np.ndarray]:
    grid = st.level_grid(level)
    ys, xs = np.mgrid[grid.y0 : grid.y0 + grid.ny, grid.x0 : grid.x0 + grid.nx]
    xs, ys = xs.ravel() % grid.ncols, ys.ravel()
    keep = st.has_data(level, xs, ys)
    return xs[keep], ys[keep]


@pytest.mark.slow
def test_unreadable_band_tiles_are_bounded_then_measured(vancouver_store, monkeypatch):
    ref_stack, top = _stack(vancouver_store, set())
    level = top.max_level
    xs, ys = _band_tiles(top, level)
    ref = ref_stack.metadata(level, xs, ys).stride_error
    failing = {(level, int(x), int(y)) for x, y in zip(xs[::2], ys[::2], strict=True)}
    assert len(failing) >= 2
    monkeypatch.setattr(band_errors, "DIFF_RETRY_S", 0.0)  # retried at every call
    stack, top = _stack(vancouver_store, failing)
    got = stack.metadata(level, xs, ys).stride_error  # no StoreError escapes
    assert np.all(np.isfinite(got))
    assert np.all(got >= ref - 1e-9), "an unread tile's bound must never be below the measured"
    assert np.any(got > ref + 1e-6), "the unread tiles were bounded from their height ranges"
    # Still failing: tried again, bounded again (no exception).
    assert np.all(stack.metadata(level, xs, ys).stride_error >= ref - 1e-9)
    # The server serves them again: the next call measures them, as if none had failed.
    top.failing.clear()
    stack._tiles.clear()
    np.testing.assert_array_equal(stack.metadata(level, xs, ys).stride_error, ref)


@pytest.mark.slow
def test_unreadable_ancestors_of_virtual_tiles_keep_the_ancestor_bound(vancouver_store):
    ref_stack, top = _stack(vancouver_store, set())
    lm = top.max_level
    level = lm + 2  # finer than the layer's data: errors measured on the ancestors' nodes
    ax, ay = _band_tiles(top, lm)
    xs = np.concatenate([(ax << 2) + dx for dx in range(4)])
    ys = np.concatenate([(ay << 2) + 1 for _ in range(4)])
    ref = ref_stack.metadata(level, xs, ys).stride_error
    failing = {(lm, int(x), int(y)) for x, y in zip(ax, ay, strict=True)}
    stack, top = _stack(vancouver_store, failing)
    got = stack.metadata(level, xs, ys).stride_error
    assert np.all(np.isfinite(got)) and np.all(got >= ref - 1e-9)
    top.failing.clear()  # readable again: measured (nothing unmeasured was kept)
    stack._tiles.clear()
    np.testing.assert_array_equal(stack.metadata(level, xs, ys).stride_error, ref)


def test_drape_leaves_points_on_unreadable_tiles_undrawn() -> None:
    """Vector and point overlays drape on the drawn tiles' heights on the UI thread: a tile
    that cannot be read now leaves its points undrawn instead of failing the frame."""
    from globeview.terrain.vectors import drape_heights

    keys = np.array([[1, 0, 0], [1, 1, 0]])  # two level-1 tiles: west of -90 and -90..0, north

    def heights(key):
        if tuple(key) == (1, 1, 0):
            raise StoreError("tile (1, 1, 0): not loaded yet (injected)")
        return np.full((65, 65), 100.0, np.float32)

    lon = np.array([-135.0, -45.0])
    lat = np.array([45.0, 45.0])
    h, drawn, tile = drape_heights(heights, keys, np.array([1, 1]), lon, lat)
    assert drawn.tolist() == [True, False] and tile.tolist() == [0, -1]
    assert h[0] == pytest.approx(100.0)
