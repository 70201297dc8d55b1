"""Blend masks kept in the cache between sessions (issue #27, the window's launch): a mask read
back has the very weights and interpolation errors of one built from the coverage, without
reading the coverage or measuring; a damaged file, another store or other terrain code builds
and measures again."""

from __future__ import annotations

import numpy as np
import pytest

import globeview.terrain.compose.blend as blend
import globeview.terrain.compose.mask_cache as mask_cache


@pytest.fixture(scope="module")
def stores(embedded_cache):
    from globeview.terrain.embedded import embedded_stores

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GLOBEVIEW_CACHE_DIR", str(embedded_cache))
        return {s.path.name.split("-")[0]: s for s in embedded_stores()}


@pytest.fixture
def kept(tmp_path, monkeypatch):
    """The masks' folder, empty, in place of the user's cache."""
    monkeypatch.setattr(mask_cache, "cache_dir", lambda: tmp_path)
    return tmp_path / "blend-masks"


CELLS = (2, 4, 16)  # cell sizes in raster steps


def _built(st) -> tuple[np.ndarray, list[float]]:
    mask = blend.BlendMask(st)
    return mask.w, [blend.interpolation_error(mask, m * mask.step) for m in CELLS]


def _refuse(*args, **kwargs):
    raise AssertionError("a kept mask was built or measured again")


def test_a_kept_mask_is_read_back_without_building_or_measuring(stores, kept, monkeypatch):
    st = stores["craterlake"]
    w, errors = _built(st)
    assert sorted(p.name for p in kept.iterdir()) == sorted(
        [f"{blend.BlendMask(st).cache_key}.npz", f"{blend.BlendMask(st).cache_key}-interp.json"]
    )
    monkeypatch.setattr(type(st), "coverage", _refuse)
    monkeypatch.setattr(blend, "interp_axis", _refuse)
    again, again_errors = _built(st)
    np.testing.assert_array_equal(again, w)  # the same bits
    assert again.dtype == np.float32
    np.testing.assert_array_equal(blend.BlendMask(st)._partial, _partial(w))
    assert again_errors == errors


def test_damaged_files_are_built_and_measured_again(stores, kept):
    st = stores["craterlake"]
    w, errors = _built(st)
    for f in kept.iterdir():
        f.write_bytes(b"not a mask")
    again, again_errors = _built(st)
    np.testing.assert_array_equal(again, w)
    assert again_errors == errors


def _partial(w: np.ndarray) -> np.ndarray:
    return np.pad((w < 1.0).astype(np.int64), ((1, 0), (1, 0))).cumsum(0).cumsum(1)


def test_a_mask_of_another_shape_or_range_is_not_used(kept):
    w = np.full((3, 4), 0.5, np.float32)
    mask_cache.save_weights("k", w, _partial(w))
    assert mask_cache.load_weights("k", (3, 4)) is not None
    assert mask_cache.load_weights("k", (4, 3)) is None
    mask_cache.save_weights("k", w, _partial(w) + 1)  # not the integral of w < 1
    assert mask_cache.load_weights("k", (3, 4)) is None
    w = np.full((3, 4), 2.0, np.float32)
    mask_cache.save_weights("k", w, _partial(w))
    assert mask_cache.load_weights("k", (3, 4)) is None
    mask_cache.save_interp_errors("e", {2: 0.5, 4: 1.5})
    assert mask_cache.load_interp_errors("e") == {}


def test_the_key_names_the_store_and_the_terrain_code(stores, monkeypatch):
    key = mask_cache.mask_key(stores["craterlake"])
    assert key is not None
    assert key != mask_cache.mask_key(stores["N44W072"])
    monkeypatch.setattr(mask_cache, "code_digest", lambda: "edited")
    assert mask_cache.mask_key(stores["craterlake"]) != key
    monkeypatch.setattr(mask_cache, "store_digest", lambda st: None)  # a remote store
    assert mask_cache.mask_key(stores["craterlake"]) is None
