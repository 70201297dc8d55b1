"""What the host keeps of a provider's free-form ``RenderSet.stats`` (issue #15 item 7):
`clean_provider_stats` never raises and keeps only bounded JSON scalars; `FrameStats.as_dict`
namespaces them under "provider" beside the level histogram, so the JSON always dumps."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from globeview.lod.render_set import (
    MAX_PROVIDER_STATS,
    FrameStats,
    clean_provider_stats,
    level_histogram,
)


class Hostile(dict):
    """A dict whose own accessors raise (a plugin's subclass)."""

    def items(self):
        raise RuntimeError("items")

    def __iter__(self):
        raise RuntimeError("iter")

    def __len__(self):
        raise RuntimeError("len")


class Sneaky(str):
    def __str__(self) -> str:
        raise RuntimeError("str")


def test_keeps_json_scalars_and_drops_the_rest() -> None:
    stats = {
        "n": 3,
        "f": 1.5,
        "b": True,
        "s": "x" * 1000,
        "k" * 500: 1,
        "np_f": np.float64(2.5),
        "np_i": np.int64(4),
        "np_b": np.bool_(False),
        "nan": math.nan,
        "inf": -math.inf,
        "huge": 10**40,
        "arr": np.arange(3),
        "list": [1, 2],
        "none": None,
        7: "int key",
        Sneaky("sneaky"): 1,
    }
    kept, dropped = clean_provider_stats(stats)
    assert kept == {
        "n": 3,
        "f": 1.5,
        "b": True,
        "s": "x" * 200,
        "k" * 64: 1,
        "np_f": 2.5,
        "np_i": 4,
        "np_b": False,
    }
    assert dropped == len(stats) - len(kept)
    assert all(type(v) in (int, float, bool, str) for v in kept.values())
    json.dumps(kept, allow_nan=False)


def test_bounded_and_never_raises() -> None:
    kept, dropped = clean_provider_stats({f"k{i}": i for i in range(10**5)})
    assert len(kept) == MAX_PROVIDER_STATS and dropped == 10**5 - MAX_PROVIDER_STATS
    assert clean_provider_stats(Hostile(a=1)) == ({"a": 1}, 0)  # dict's own accessors
    assert clean_provider_stats("not a dict") == ({}, 0)
    assert clean_provider_stats(None) == ({}, 0)


def test_as_dict_namespaces_provider_stats_and_levels() -> None:
    keys = np.array([[7, 0, 0], [7, 1, 0], [9, 5, 3], [8, 2, 2]], np.int64)
    st = FrameStats(triangles=10, lod_provider="mine")
    st.levels = level_histogram(keys)
    st.provider_stats, st.provider_stats_dropped = clean_provider_stats(
        {"triangles": -1, "x": object()}
    )
    d = json.loads(json.dumps(st.as_dict(), allow_nan=False))
    assert d["triangles"] == 10  # the plugin's "triangles" did not overwrite the host's
    assert d["levels"] == {"7": 2, "8": 1, "9": 1}
    assert d["provider"] == {"name": "mine", "stats": {"triangles": -1}, "stats_dropped": 1}
    assert level_histogram(np.empty((0, 3), np.int64)) == {}


@pytest.mark.slow
def test_only_a_bounded_prefix_is_examined() -> None:
    """A provider handing over 10^6 garbage entries each frame must not make the host walk
    them all: entries past the first `MAX_STATS_EXAMINED` are dropped unexamined."""
    from globeview.lod.render_set import MAX_STATS_EXAMINED

    stats: dict = {f"junk{i}": object() for i in range(MAX_STATS_EXAMINED - 1)}
    stats["last_examined"] = 1
    stats["first_not_examined"] = 2
    stats.update({f"more{i}": object() for i in range(10**6)})
    kept, dropped = clean_provider_stats(stats)
    assert kept == {"last_examined": 1} and dropped == len(stats) - 1
