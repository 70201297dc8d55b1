"""Driving a tool without a window: the host side of `Tool.place_points`.

``globeview render --tool NAME --points LON,LAT;...`` activates any enabled tool, built-in or
installed, and hands it the points a user would have clicked. A tool that implements
`Tool.place_points` takes them directly (returning True); for any other tool the host clicks
them: for each point a left press and release `PointerEvent` at the point's pixel in the
frame's view, with ``lonlat`` = (lon, lat, terrain height) and ``picked`` its ECEF position
(true coordinates, as the window's picking gives them). Every call is isolated by the
registry; a `GlobeviewError` the tool raises (points it refuses) is the user's error and
reaches the caller.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import numpy as np

from globeview.errors import GlobeviewError
from globeview.geodesy import lonlat_to_ecef
from globeview.plugins.api import PointerEvent

__all__ = ["place_points"]


def place_points(
    session: Any, tool: Any, points: Sequence[tuple[float, float]], viewport: tuple[int, int]
) -> bool:
    """Give the active tool ``tool`` of ``session`` (a `GlobeSession`) the points (lon, lat,
    degrees), by `Tool.place_points` or by clicking them in a ``viewport`` (w, h pixels)
    view of the session's camera. Returns False when the tool's plugin failed on the way
    (the registry reported it), True otherwise."""
    registry = session.registry
    failed = object()
    pts = [(float(lon), float(lat)) for lon, lat in points]
    took: Any = False
    if callable(getattr(tool, "place_points", None)):
        took = registry.invoke(tool, "place_points", pts, default=failed, user_errors=True)
    if took is failed:
        return False
    if took is True:
        return True
    view = session.view_state(viewport)
    for lon, lat in pts:
        h = _terrain_height(session, lon, lat)
        picked = np.asarray(lonlat_to_ecef(lon, lat, h), dtype=np.float64).reshape(3)
        # Where the point is drawn: exaggerated, and moved by the tool's own displacement.
        drawn = np.asarray(
            lonlat_to_ecef(lon, lat, h * float(session.settings.exaggeration)), dtype=np.float64
        ).reshape(1, 3)
        if session.displacing:  # the tool moves the terrain (compiled or not yet)
            drawn = session.tool_host.displace(drawn)
        x, y, _ = (float(v) for v in view.project(drawn)[0])
        clicks: tuple[tuple[Literal["press", "release"], frozenset[str]], ...] = (
            ("press", frozenset({"left"})),
            ("release", frozenset()),
        )
        for kind, held in clicks:
            event = PointerEvent(
                x,
                y,
                kind,
                button="left",
                buttons=held,
                picked=(float(picked[0]), float(picked[1]), float(picked[2])),
                lonlat=(lon, lat, h),
            )
            if registry.invoke(tool, "on_mouse", event, default=failed, user_errors=True) is failed:
                return False
    return True


def _terrain_height(session: Any, lon: float, lat: float) -> float:
    """The composed terrain height (m, ellipsoidal) at a point; 0 (the ellipsoid) where no
    layer has data."""
    terrain = session.terrain
    if not terrain.visible_layers:
        return 0.0
    try:
        # The finest level any layer has, as window picks and `globeview height` answer
        # (height_at alone stops at level 12: 1.7 m off over Crater Lake's level 13).
        return float(terrain.height_at(lon, lat, terrain.max_level))
    except GlobeviewError:
        return 0.0
