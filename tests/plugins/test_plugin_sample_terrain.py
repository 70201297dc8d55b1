"""`sample_terrain` (plugin API) keeps the shape of the points it is given (issue #29 item 8):
a scalar point gives 0-d heights (``float()`` of them works under numpy 2, where ``float`` of
a (1,) array raises and took a tool down in the window), arrays give arrays of their shape.
Oracle: the same points sampled as a flat array."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.errors import GlobeviewError
from globeview.plugins.api import sample_terrain

#: Mount Washington (White Mountains SRTM in the embedded data), and two more points.
LON, LAT = -71.3033, 44.2706
LONS = np.array([[-71.3033, -71.25], [-71.40, -71.35]])
LATS = np.array([[44.2706, 44.30], [44.20, 44.25]])


def test_scalar_point_gives_0d_heights(globeview_terrain) -> None:
    s = sample_terrain(globeview_terrain, LON, LAT)
    flat = sample_terrain(globeview_terrain, np.array([LON]), np.array([LAT]))
    for got, want in zip(
        (s.ellipsoidal, s.undulation, s.orthometric),
        (flat.ellipsoidal, flat.undulation, flat.orthometric),
        strict=True,
    ):
        assert np.shape(got) == ()
        assert float(got) == pytest.approx(float(want[0]), abs=1e-9)
    assert 1800.0 < float(s.orthometric) < 1950.0  # the summit, 1917 m a.s.l.


def test_arrays_keep_their_shape(globeview_terrain) -> None:
    s = sample_terrain(globeview_terrain, LONS, LATS)
    flat = sample_terrain(globeview_terrain, LONS.ravel(), LATS.ravel())
    assert s.ellipsoidal.shape == s.orthometric.shape == LONS.shape
    assert flat.ellipsoidal.shape == (4,)
    np.testing.assert_allclose(s.ellipsoidal.ravel(), flat.ellipsoidal, atol=1e-9)
    np.testing.assert_allclose(s.orthometric.ravel(), flat.orthometric, atol=1e-9)


def test_bare_ellipsoid_and_bad_points(globeview_terrain) -> None:
    s = sample_terrain(None, 10.0, 45.0)
    assert np.shape(s.ellipsoidal) == () and float(s.ellipsoidal) == 0.0
    assert float(s.orthometric) == pytest.approx(-float(s.undulation))
    with pytest.raises(GlobeviewError, match="latitude"):
        sample_terrain(globeview_terrain, 10.0, 95.0)
    with pytest.raises(GlobeviewError, match="latitudes"):
        sample_terrain(globeview_terrain, np.zeros(3), np.zeros(2))
