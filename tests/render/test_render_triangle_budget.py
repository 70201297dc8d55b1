"""The frame's triangle count stays within the interactive budget (~100 k at 1280x720, tau
2 px) at views over the regional DEMs. A count, not a timing: it only changes when the LOD's
errors change. (A layer-blend error bound once made the 174 km view over the SRTM tile draw
1.5 M triangles instead of 24 k, with every test still green.)"""

from __future__ import annotations

import pytest

from globeview.model.camera import Camera

pytestmark = pytest.mark.gl

SIZE = (1280, 720)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "pose", "budget"),
    [
        ("SRTM White Mountains, nadir from 174 km", (-71.5, 44.5, 174_000.0, 0.0, -90.0), 60_000),
        ("Crater Lake, oblique from 45 km", (-122.15, 42.6, 45_000.0, 0.0, -35.0), 100_000),
        ("Salish Sea topobathy, nadir from 300 km", (-123.2, 49.2, 300_000.0, 0.0, -90.0), 60_000),
    ],
)
def test_views_over_regional_dems_stay_within_the_triangle_budget(
    scene, targets, gv, name: str, pose: tuple[float, ...], budget: int
) -> None:
    scene.tau_px = 2.0
    _, result = gv.render(scene, targets, Camera.from_lonlat(*pose), SIZE)
    st = result.stats
    assert st.tiles_drawn > 0, name
    assert st.triangles <= budget, f"{name}: {st.triangles} triangles (budget {budget})"
    assert st.max_sse_px <= 2.0 + 1e-6, name
