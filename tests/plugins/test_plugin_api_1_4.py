"""Plugin API 1.4 (issue #27 item 1): the flat selection, seen from a plugin.

- the facade exports `SelectionState` and `TreeRows`;
- a `PolicyProvider` whose policy is `LodPolicy.per_tile` (a `ScreenSpaceErrorPolicy`
  subclass that leaves how it judges tiles alone) keeps a selection state and selects as a
  walk from nothing does, and `reset` forgets the state;
- a subclass that overrides how tiles are judged is not per tile: it walks level by level
  (its state stays empty), as a 1.3 policy did.
"""

from __future__ import annotations

import numpy as np

from globeview.app.testing import make_view


def test_new_names_are_in_the_facade() -> None:
    import globeview.plugins.api as api

    for name in ("SelectionState", "TreeRows"):
        assert name in api.__all__ and getattr(api, name) is not None


def test_a_per_tile_policy_provider_keeps_a_state(globeview_terrain) -> None:
    from globeview.plugins.api import PolicyProvider, ScreenSpaceErrorPolicy, traverse

    class Finer(ScreenSpaceErrorPolicy):  # only the settings differ: still per tile
        def __init__(self, tau_px: float | None = None) -> None:
            super().__init__(tau_px, texel_px=1.0)

    class Judging(ScreenSpaceErrorPolicy):  # judges tiles its own way: not per tile
        def error_px(self, tiles, *a, **k):
            return super().error_px(tiles, *a, **k) * 1.5

    class FinerProvider(PolicyProvider):
        name = "finer"
        policy = Finer

    class JudgingProvider(PolicyProvider):
        name = "judging"
        policy = Judging

    assert Finer().per_tile and not Judging().per_tile
    finer, judging = FinerProvider(), JudgingProvider()
    for i in range(4):
        view = make_view(-71.3, 44.15, 9000.0, 0.01 * i, -30.0, viewport=(640, 360))
        for provider, cls in ((finer, Finer), (judging, Judging)):
            got = provider.select(view, globeview_terrain)
            want = traverse(view, globeview_terrain, cls())
            assert np.array_equal(got.keys, want.keys), (cls.__name__, i)
            assert got.error_px.tobytes() == want.error_px.tobytes(), (cls.__name__, i)
            # The flat walk's counts are in the stats of a per-tile policy's frames only.
            assert ("lod_rounds" in got.stats) == (cls is Finer), (cls.__name__, i)
    assert finer._selection_state is not None and finer._selection_state.rows > 0
    assert judging._selection_state is not None and judging._selection_state.rows == 0
    finer.reset()
    assert finer._selection_state.rows == 0
