"""`PolicyProvider` reuses its last selection while the view is unchanged (issue #14).

A repaint with the same view (window expose, overlay redraw) must not walk the quadtree again
for any provider built on `PolicyProvider` (chunked-sse, distance-regions, wavelet); anything
a policy reads - the camera, a setting, the terrain, the navigation speed - selects afresh,
and so does every frame with a tool displacement.
"""

from __future__ import annotations

import dataclasses
import gc
import weakref

import numpy as np
import pytest

from globeview.app.testing import make_view
from globeview.plugins.builtin.chunked.provider import ChunkedSseProvider
from globeview.plugins.builtin.regions.provider import DistanceRegionsProvider
from globeview.plugins.builtin.wavelet.provider import WaveletProvider
from globeview.terrain.compose.stack import TerrainStack


@pytest.fixture
def stack(globeview_terrain) -> TerrainStack:
    """A terrain of its own (the tests change its layers)."""
    return TerrainStack.from_stores([ly.store for ly in globeview_terrain.layers])


def _fresh(rs) -> bool:
    """The render set was selected now (not handed out again)."""
    return "lod_cached" not in rs.stats and rs.stats["lod_ms"] > 0.0


@pytest.mark.slow
@pytest.mark.parametrize("cls", [ChunkedSseProvider, DistanceRegionsProvider, WaveletProvider])
def test_an_unchanged_view_reuses_the_last_selection(cls, stack) -> None:
    provider = cls()
    view = make_view(-71.3, 44.27, 3.0e5, 10.0, -40.0)
    first = provider.select(view, stack)
    assert _fresh(first) and len(first) > 0
    keys = first.keys.copy()
    again = provider.select(make_view(-71.3, 44.27, 3.0e5, 10.0, -40.0), stack)  # equal view
    assert again is first and np.array_equal(again.keys, keys)
    assert again.stats["lod_cached"] == 1.0 and again.stats["lod_ms"] == 0.0
    provider.reset()
    assert _fresh(provider.select(view, stack))


@pytest.mark.slow
@pytest.mark.parametrize("cls", [ChunkedSseProvider, DistanceRegionsProvider, WaveletProvider])
def test_a_change_selects_afresh(cls, stack) -> None:
    provider = cls()
    view = make_view(-71.3, 44.27, 3.0e5, 10.0, -40.0)
    provider.select(view, stack)
    moved = make_view(-71.3, 44.27, 2.9e5, 10.0, -40.0)  # the camera 10 km lower
    assert _fresh(provider.select(moved, stack))
    assert provider.select(moved, stack).stats["lod_cached"] == 1.0
    turned = make_view(-71.3, 44.27, 2.9e5, 12.0, -40.0)  # same eye, turned
    assert _fresh(provider.select(turned, stack))
    sized = make_view(-71.3, 44.27, 2.9e5, 12.0, -40.0, viewport=(640, 480))
    assert _fresh(provider.select(sized, stack))
    # a setting: the tile budget (every built-in has one)
    provider.configure({**provider.values, "max_tiles": provider.values["max_tiles"] - 1})
    assert _fresh(provider.select(sized, stack))
    # the terrain: a layer hidden bumps its version
    stack.set_visible(stack.layers[-1].name, False)
    hidden = provider.select(sized, stack)
    assert _fresh(hidden)
    # another terrain object equal in every key (version 0 again, same view)
    other = TerrainStack.from_stores([ly.store for ly in stack.layers])
    assert _fresh(provider.select(sized, other))
    # a tool displacement can change between frames with the same view: never reused
    bent = dataclasses.replace(sized, displace=lambda p: p)
    assert _fresh(provider.select(bent, other))
    assert _fresh(provider.select(bent, other))


@pytest.mark.slow
def test_regions_reselects_for_another_speed(stack) -> None:
    """Rishe's speed factor coarsens the regions: the speed is part of what is reused under."""
    provider = DistanceRegionsProvider()
    slow = provider.select(make_view(-71.3, 44.15, 9.0e3, 0.0, -30.0), stack)
    again = provider.select(make_view(-71.3, 44.15, 9.0e3, 0.0, -30.0), stack)
    assert again is slow
    fast = provider.select(make_view(-71.3, 44.15, 9.0e3, 0.0, -30.0, speed_mps=3000.0), stack)
    assert _fresh(fast) and fast is not slow
    assert len(fast) != len(slow) or not np.array_equal(fast.keys, slow.keys)


def test_the_reuse_does_not_keep_a_terrain_alive(globeview_terrain) -> None:
    provider = ChunkedSseProvider()
    terrain = TerrainStack.from_stores([globeview_terrain.layers[0].store])
    provider.select(make_view(-71.3, 44.27, 3.0e5), terrain)
    gone = weakref.ref(terrain)
    del terrain
    gc.collect()
    assert gone() is None
