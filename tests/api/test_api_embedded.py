"""`Globe(embedded=True)`: the shipped DEMs and borders, as the window opens with (the
user's cache, as the window tests use it)."""

from __future__ import annotations

import numpy as np
import pytest

import globeview

pytestmark = pytest.mark.gl


def test_embedded_globe_has_the_shipped_dems_and_borders(registry):
    globe = globeview.Globe(embedded=True, registry=registry)
    try:
        assert "etopo20" in globe.dems and "N44W072" in globe.dems
        assert [ly.name for ly in globe.overlays] == ["ne_110m_countries.geojson"]
        assert 1800.0 < globe.height_at(-71.3036, 44.2705) < 1960.0  # Mount Washington
        rgba = globe.render((160, 120))  # the whole globe from 20 000 km
        assert (rgba[60, 80, :3].astype(int) - rgba[2, 2, :3].astype(int)).any()
        assert np.unique(rgba[..., :3].reshape(-1, 3), axis=0).shape[0] > 100
    finally:
        globe.close()
