"""The built-in measure tool (issue #15), loaded through the registry as the window and the
CLI load it: geodesic and chord distances and azimuths against pyproj, the terrain profile
against `globeview height` (a real subprocess) over the White Mountains SRTM tile, the plot's
CSV round trip and failed exports (nothing written), settings, events and hostile input."""

from __future__ import annotations

import ast
import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pyproj import Geod, Transformer

from globeview.errors import GlobeviewError
from globeview.plugins.api import KeyEvent, Plot, PointerEvent, Polyline, read_csv_columns
from globeview.plugins.registry import PluginRegistry

REPO = Path(__file__).resolve().parents[2]
SRTM = REPO / "data" / "N44W072.hgt"
LONDON = (-0.1276, 51.5072)
NEW_YORK = (-74.0060, 40.7128)
#: Across the Presidential Range (White Mountains, NH), inside the SRTM tile N44W072.
WM_A = (-71.52, 44.21)
WM_B = (-71.16, 44.33)
GEOD = Geod(ellps="WGS84")


@pytest.fixture
def measure(globeview_registry: PluginRegistry):
    """The registry's measure tool (no terrain attached: the bare ellipsoid)."""
    tool = globeview_registry.tools()["measure"]
    assert globeview_registry.get("measure").builtin
    return tool


@pytest.fixture(scope="module")
def srtm_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("measure-cache")


@pytest.fixture
def srtm_stack(srtm_cache: Path, monkeypatch: pytest.MonkeyPatch):
    """The composed terrain of the SRTM tile alone, its store in the module's cache (the
    same store `globeview height ... data/N44W072.hgt` opens with that cache)."""
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.sources import open_source

    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(srtm_cache))
    return TerrainStack.from_stores([open_source(SRTM)], [SRTM.name])


def ecef(lon: float, lat: float, h: float) -> np.ndarray:
    """ECEF (m) by PROJ, independent of globeview's geodesy."""
    t = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    return np.array(t.transform(lon, lat, h))


def test_london_new_york_against_pyproj(measure) -> None:
    m = measure.set_points([LONDON, NEW_YORK])
    fwd, _, dist = GEOD.inv(*LONDON, *NEW_YORK)
    back, _, _ = GEOD.inv(*NEW_YORK, *LONDON)  # the azimuth at B toward A
    assert abs(m.distance_m - dist) < 1e-3
    assert 5.5e6 < m.distance_m < 5.6e6
    assert m.azimuth_deg == pytest.approx(fwd % 360.0, abs=1e-9)
    assert m.back_azimuth_deg == pytest.approx(back % 360.0, abs=1e-9)
    assert 0.0 <= m.azimuth_deg < 360.0 and 0.0 <= m.back_azimuth_deg < 360.0
    # No terrain: the chord joins the two points on the ellipsoid, through the Earth.
    chord = float(np.linalg.norm(ecef(*NEW_YORK, 0.0) - ecef(*LONDON, 0.0)))
    assert abs(m.chord_m - chord) < 1e-3
    assert m.chord_m < m.distance_m - 1e5
    # The status line says it, in the chosen unit.
    status = measure.context.renderer.status
    assert status.startswith("measure: 5,585.254 km geodesic") and "\n" not in status


def test_profile_samples_lie_on_the_geodesic(measure) -> None:
    m = measure.set_points([LONDON, NEW_YORK])
    n = measure.values["samples"]
    assert m.profile_s_m.size == n == 256
    assert (m.profile_lon[0], m.profile_lat[0]) == LONDON
    assert (m.profile_lon[-1], m.profile_lat[-1]) == NEW_YORK
    # Each sample is s from A and distance - s from B, along the same azimuth from A.
    az, _, s = GEOD.inv(np.full(n, LONDON[0]), np.full(n, LONDON[1]), m.profile_lon, m.profile_lat)
    _, _, rest = GEOD.inv(
        m.profile_lon, m.profile_lat, np.full(n, NEW_YORK[0]), np.full(n, 40.7128)
    )
    np.testing.assert_allclose(s, m.profile_s_m, atol=1e-3)
    np.testing.assert_allclose(rest, m.distance_m - m.profile_s_m, atol=1e-3)
    np.testing.assert_allclose(az[1:], az[1], atol=1e-7)
    # Without terrain the profile is the ellipsoid: H = -N (the geoid above it).
    assert np.all(np.isfinite(m.profile_h_m)) and np.all(np.abs(m.profile_h_m) < 120.0)


@pytest.mark.slow
def test_profile_across_white_mountains_equals_globeview_height(
    globeview_registry: PluginRegistry, srtm_stack, srtm_cache: Path
) -> None:
    globeview_registry.attach(terrain=srtm_stack)
    tool = globeview_registry.tools()["measure"]
    globeview_registry.configure(tool, {"samples": 9})
    m = tool.set_points([WM_A, WM_B])
    assert m.profile_h_m.size == 9
    assert m.profile_h_m.max() > 1200.0  # it crosses the range, not the valley floor
    points = [
        f"{float(lo)!r},{float(la)!r}" for lo, la in zip(m.profile_lon, m.profile_lat, strict=True)
    ]
    env = {**os.environ, "GLOBEVIEW_CACHE_DIR": str(srtm_cache)}
    r = subprocess.run(
        [sys.executable, "-m", "globeview", "height", *points, str(SRTM), "--json"],
        capture_output=True, text=True, timeout=300, env=env, cwd=REPO,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)
    assert [row["layer"] for row in rows] == [SRTM.name] * 9
    np.testing.assert_allclose(m.profile_h_m, [row["orthometric_m"] for row in rows], atol=1e-6)
    np.testing.assert_allclose(
        m.profile_ellipsoidal_m, [row["ellipsoidal_m"] for row in rows], atol=1e-6
    )
    # The chord joins the terrain points (ellipsoidal heights at A and B).
    chord = np.linalg.norm(
        ecef(*WM_B, rows[-1]["ellipsoidal_m"]) - ecef(*WM_A, rows[0]["ellipsoidal_m"])
    )
    assert abs(m.chord_m - chord) < 1e-3


def test_plot_and_csv_round_trip(measure, tmp_path: Path) -> None:
    assert measure.plot() is None  # nothing measured yet
    measure.set_points([LONDON, NEW_YORK])
    plot = measure.plot()
    assert isinstance(plot, Plot) and measure.plot() is plot  # same object: unchanged
    assert plot.x_label == "distance from A (km)" and plot.y_label.endswith("(m)")
    np.testing.assert_allclose(plot.x[-1], measure.measurement.distance_m / 1000.0)
    out = plot.write_csv(tmp_path / "profile.csv")
    with out.open(newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["distance_m", "lon", "lat", "height_m"]
    got = np.array(rows[1:], dtype=np.float64)
    m = measure.measurement
    want = np.stack([m.profile_s_m, m.profile_lon, m.profile_lat, m.profile_h_m], axis=1)
    assert np.array_equal(got, want)  # exact: floats written in their shortest exact form
    back = read_csv_columns(out)
    assert list(back) == ["distance_m", "lon", "lat", "height_m"]
    assert np.array_equal(back["height_m"], m.profile_h_m)


def test_csv_keeps_gaps_and_odd_names(tmp_path: Path) -> None:
    p = Plot("t", [0.0, 1.0, 2.0], [1.5, np.nan, -2.0], "d, (km)", 'h "m"')
    text = p.csv_text()
    assert text.splitlines()[0] == '"d, (km)","h ""m"""'
    back = read_csv_columns(p.write_csv(tmp_path / "gap.csv"))
    assert np.array_equal(back['h "m"'], p.y, equal_nan=True)


@pytest.mark.parametrize("fault", ["erofs", "enospc", "eacces"])
def test_failed_export_is_one_line_and_writes_nothing(
    measure, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fault: str
) -> None:
    measure.set_points([LONDON, NEW_YORK])
    target = tmp_path / "profile.csv"
    target.write_text("the user's file\n")
    monkeypatch.setenv("GLOBEVIEW_FAULT_WRITE", fault)
    with pytest.raises(GlobeviewError) as info:
        measure.plot().write_csv(target)
    assert "\n" not in str(info.value) and str(target) in str(info.value)
    assert target.read_text() == "the user's file\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["profile.csv"]  # no temporary left


def test_export_onto_a_folder_or_into_a_missing_one(measure, tmp_path: Path) -> None:
    measure.set_points([LONDON, NEW_YORK])
    for bad, words in ((tmp_path, "directory"), (tmp_path / "no" / "p.csv", "does not exist")):
        with pytest.raises(GlobeviewError, match=words):
            measure.plot().write_csv(bad)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "args",
    [
        ([0, 1], [1, 2, 3]),  # lengths differ
        ([], []),  # empty
        ([[0, 1]], [[1, 2]]),  # 2-D
        ([0, np.inf], [1, 2]),  # x not finite
        (["a", "b"], [1, 2]),  # not numbers
    ],
)
def test_malformed_plot_is_refused(args) -> None:
    with pytest.raises(ValueError, match="plot"):
        Plot("bad", *args)
    with pytest.raises(ValueError, match="column"):
        Plot("bad", [0, 1], [1, 2], columns={"a": [1, 2, 3]})


def test_settings_units_samples_and_chord(globeview_registry: PluginRegistry) -> None:
    tool = globeview_registry.tools()["measure"]
    tool.set_points([LONDON, NEW_YORK])
    km = tool.plot()
    lines = [p for p in tool.overlay(None) if isinstance(p, Polyline)]
    assert len(lines) == 1 and len(lines[0].points) == 256
    globeview_registry.configure(tool, {"units": "mi", "samples": 11, "show_chord": True})
    mi = tool.plot()
    assert mi is not km and mi.x_label == "distance from A (mi)" and mi.x.size == 11
    np.testing.assert_allclose(mi.x[-1], tool.measurement.distance_m / 1609.344)
    assert " mi geodesic" in tool.context.renderer.status
    lines = [p for p in tool.overlay(None) if isinstance(p, Polyline)]
    # 11 samples cut corners through the Earth: the drawn line stays denser; plus the chord.
    assert [len(p.points) for p in lines] == [65, 2]
    # A bad stored value keeps the default (settings never break the tool).
    globeview_registry.configure(tool, {"samples": "many", "units": "furlongs"})
    assert tool.values["samples"] == 256 and tool.values["units"] == "km"


def test_geodesic_line_is_drawn_on_the_surface(measure) -> None:
    from types import SimpleNamespace

    measure.set_points([LONDON, NEW_YORK])
    line = next(p for p in measure.overlay(None) if isinstance(p, Polyline))
    t = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    _, _, h = t.transform(*np.asarray(line.points).T)
    np.testing.assert_allclose(h, 30.0, atol=1e-3)  # the ellipsoid, lifted 30 m
    # Exaggerated terrain: the line follows it (here no terrain, so only the lift stays).
    line2 = next(
        p for p in measure.overlay(SimpleNamespace(exaggeration=3.0)) if isinstance(p, Polyline)
    )
    assert np.allclose(line2.points, line.points)


def press(lon: float, lat: float, button: str = "left") -> PointerEvent:
    return PointerEvent(100.0, 100.0, "press", button=button, lonlat=(lon, lat, 0.0))


def test_two_clicks_measure_third_restarts_escape_clears(measure) -> None:
    assert measure.on_mouse(press(*LONDON)) and measure.state == "a_set"
    assert measure.plot() is None
    assert not measure.on_mouse(press(*NEW_YORK, button="right"))  # only left clicks
    assert not measure.on_mouse(PointerEvent(1, 1, "press", button="left"))  # sky: ignored
    assert measure.on_mouse(press(*NEW_YORK)) and measure.state == "measured"
    assert measure.plot() is not None
    labels = [getattr(p, "label", None) for p in measure.overlay(None)]
    assert labels[:2] == ["A", "B 5,585.25 km"]
    assert measure.on_mouse(press(10.0, 50.0)) and measure.state == "a_set"
    assert measure.a == (10.0, 50.0) and measure.plot() is None
    assert measure.on_key(KeyEvent("Escape")) and measure.state == "idle"
    assert not measure.on_key(KeyEvent("Escape"))  # nothing to clear: the host leaves the tool


@pytest.mark.parametrize(
    ("points", "words"),
    [
        ([LONDON, NEW_YORK, LONDON], "1 or 2 points"),
        ([], "1 or 2 points"),
        ([(0.0, 91.0), LONDON], "latitude"),
        ([(float("nan"), 0.0), LONDON], "finite"),
        ([("x", 0.0), LONDON], "not two numbers"),
        ([(1.0,), LONDON], "1 or 2 points"),
    ],
)
def test_hostile_points_are_one_line_errors(measure, points, words) -> None:
    measure.set_points([LONDON, NEW_YORK])
    with pytest.raises(ValueError, match=words) as info:
        measure.set_points(points)
    assert "\n" not in str(info.value)
    assert measure.state == "measured"  # the old measurement stands


def test_degenerate_pairs(measure) -> None:
    same = measure.set_points([LONDON, LONDON])
    assert same.distance_m == 0.0 and same.chord_m == 0.0
    assert np.all(measure.plot().x == 0.0)
    anti = measure.set_points([(0.0, 0.0), (180.0, 0.0)])  # antipodal: a geodesic over a pole
    assert anti.distance_m == pytest.approx(GEOD.inv(0.0, 0.0, 180.0, 0.0)[2], abs=1e-3)
    pole = measure.set_points([(0.0, 90.0), (0.0, -90.0)])
    assert pole.distance_m == pytest.approx(GEOD.inv(0.0, 90.0, 0.0, -90.0)[2], abs=1e-3)
    assert np.all(np.isfinite(measure.plot().y))
    # Across the antimeridian the short way (~110 km), also with a longitude given as 539.5.
    for lon_a in (179.5, 539.5):
        across = measure.set_points([(lon_a, 10.0), (-179.5, 10.0)])
        assert across.distance_m == pytest.approx(GEOD.inv(179.5, 10, -179.5, 10)[2], abs=1e-3)
        assert np.all(np.abs(np.diff(measure.plot().x)) < 1.0)  # km steps, no jump round


def test_measure_imports_only_the_facade() -> None:
    """The built-in is written as a third party would: from globeview only the facade."""
    src = (REPO / "globeview" / "plugins" / "builtin" / "measure" / "tool.py").read_text()
    mods = set()
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.ImportFrom) and node.module:
            mods.add(node.module)
        elif isinstance(node, ast.Import):
            mods.update(a.name for a in node.names)
    assert {m for m in mods if m.startswith("globeview")} == {"globeview.plugins.api"}
    assert mods <= {"globeview.plugins.api", "__future__", "collections.abc", "dataclasses",
                    "typing", "numpy"}  # fmt: skip


def test_profile_follows_the_terrain_drawn_now(
    globeview_registry: PluginRegistry, srtm_stack
) -> None:
    """Hiding (or opening) a DEM after measuring: the next plot is measured on the terrain
    as it is now, not the one at the click."""
    globeview_registry.attach(terrain=srtm_stack)
    tool = globeview_registry.tools()["measure"]
    tool.set_points([WM_A, WM_B])
    before = tool.plot()
    assert tool.plot() is before and np.nanmax(before.y) > 1200.0
    srtm_stack.set_visible(SRTM.name, False)
    after = tool.plot()
    assert after is not before and np.all(np.abs(after.y) < 40.0)  # the ellipsoid: H = -N
    srtm_stack.set_visible(SRTM.name, True)
    assert np.array_equal(tool.plot().y, before.y)
