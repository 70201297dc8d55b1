"""The collapse tool's behaviour without GL: discovery, the pick-A-pick-B state machine, keys,
the host-driven animation, overlays and the displacement hook's contract."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.geodesy import lonlat_to_ecef
from globeview.plugins.api import KeyEvent, Marker, PointerEvent, Polyline

CRATER = (-122.1, 42.99)
SALISH = (-122.4, 48.2)


def press(lon: float, lat: float, button: str = "left") -> PointerEvent:
    p = tuple(float(v) for v in lonlat_to_ecef(lon, lat, 100.0))
    return PointerEvent(10, 10, "press", button, picked=p, lonlat=(lon, lat, 100.0))


@pytest.fixture
def tool(globeview_registry):
    rec = globeview_registry.get("collapse")
    assert rec.enabled and rec.status == "ok"
    t = globeview_registry.tools()["collapse"]
    t.configure({"ratio": 0.25})
    return t


def test_pick_a_then_b_collapses_with_animation(globeview_registry, tool) -> None:
    reg = globeview_registry
    assert not reg.invoke(tool, "on_mouse", press(*CRATER, button="right"))
    assert reg.invoke(tool, "on_mouse", press(*CRATER))
    assert tool.state == "a_set" and tool.frame() is None
    assert reg.invoke(tool, "on_mouse", press(*SALISH))
    assert tool.state == "collapsing" and tool.effective_ratio == 1.0
    assert reg.invoke(tool, "animate", 100.0)  # the first call fixes the origin
    assert reg.invoke(tool, "animate", 100.25)
    assert 0.25 < tool.effective_ratio < 1.0
    assert not reg.invoke(tool, "animate", 100.6)
    assert tool.state == "collapsed" and tool.effective_ratio == 0.25
    # 'e' expands back (animated), Escape then clears everything.
    assert reg.invoke(tool, "on_key", KeyEvent("e"))
    reg.invoke(tool, "animate", 5.0)
    assert not reg.invoke(tool, "animate", 5.5)
    assert tool.state == "expanded" and tool.effective_ratio == 1.0
    assert reg.invoke(tool, "on_key", KeyEvent("Escape"))
    assert tool.state == "idle" and not reg.invoke(tool, "on_key", KeyEvent("Escape"))
    assert reg.get("collapse").status == "ok"


def test_set_points_and_the_hook_contract(globeview_registry, tool, headless_view) -> None:
    reg = globeview_registry
    pts = lonlat_to_ecef(np.array([-122.0, -122.3]), np.array([45.0, 47.0]), 500.0)
    assert np.array_equal(reg.invoke(tool, "displacement_numpy", pts), pts)  # nothing set
    reg.invoke(tool, "set_points", *CRATER, *SALISH, 0.2)
    assert tool.state == "collapsed"
    moved = reg.invoke(tool, "displacement_numpy", pts)
    assert np.all(np.linalg.norm(moved - pts, axis=1) > 10e3)
    back = reg.invoke(tool, "displacement_inverse_numpy", moved)
    assert np.max(np.abs(back - pts)) < 1e-3
    view = headless_view(-122.3, 45.5, 3e5)
    uni = reg.invoke(tool, "displacement_uniforms", view)
    assert uni and all(k.startswith("gv_u_") for k in uni)
    m_rel = np.array(uni["gv_u_m_rel"])
    assert np.allclose(m_rel + view.eye, tool.frame().m_ecef, atol=1e-6)
    assert "vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 tile_center_rel)" in (
        reg.invoke(tool, "displacement_glsl")
    )
    with pytest.raises(ValueError, match="degrees apart"):
        tool.set_points(0.0, 0.0, 179.9, 0.0)
    assert reg.get("collapse").status == "ok"


def test_overlay_marks_a_b_and_the_fold_lines(globeview_registry, tool, headless_view) -> None:
    reg = globeview_registry
    reg.invoke(tool, "set_points", *CRATER, *SALISH, 0.2)
    prims = reg.invoke(tool, "overlay", headless_view(-122.3, 45.5, 3e5))
    markers = [p for p in prims if isinstance(p, Marker)]
    lines = [p for p in prims if isinstance(p, Polyline)]
    assert [m.label for m in markers] == ["A", "B"]
    assert np.allclose(markers[0].position, lonlat_to_ecef(*CRATER, 0.0))
    assert len(lines) == 3  # two fold lines and the axis
    f = tool.frame()
    for line, sign in zip(lines[:2], (-1.0, 1.0), strict=True):
        psi, c = f.axis_angles(line.points)
        assert np.allclose(psi, sign * f.psi0, atol=1e-9)
        assert c.min() < 0.0 < c.max()  # the line crosses the axis
    # Deactivating the tool leaves nothing collapsed.
    reg.invoke(tool, "deactivate")
    assert tool.state == "idle" and reg.invoke(tool, "overlay", None) == []
