"""A wheel install must carry what the source tree runs with: shaders and manifests as
package data, the embedded DEMs as data files (found under <prefix>/share/globeview/data)."""

from __future__ import annotations

import fnmatch
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_every_non_python_file_in_the_package_is_package_data() -> None:
    patterns = _pyproject()["tool"]["setuptools"]["package-data"]["globeview"]
    pkg = ROOT / "globeview"
    missing = [
        str(p.relative_to(pkg))
        for p in pkg.rglob("*")
        if p.is_file()
        and p.suffix not in (".py", ".pyc")
        and "__pycache__" not in p.parts
        and not any(fnmatch.fnmatch(p.name, pat.split("/")[-1]) for pat in patterns)
    ]
    assert not missing, f"not shipped in a wheel: {missing}"


def test_embedded_data_files_ship_with_a_wheel() -> None:
    from globeview.terrain.dem.data import embedded_dem_paths

    shipped = {
        Path(f).name
        for f in _pyproject()["tool"]["setuptools"]["data-files"]["share/globeview/data"]
    }
    for f in shipped:
        assert (ROOT / "data" / f).exists(), f
    for p in embedded_dem_paths():
        assert p.name in shipped, p.name
    assert "README.md" in shipped  # the provenance travels with the data


def test_bench_flights_ship_inside_the_package() -> None:
    # `globeview bench` once looked for its flights in the source checkout's benchmarks/,
    # so it broke after a wheel install: they are package data now.
    from globeview.bench.check import QUICK_FLIGHT, STANDARD_FLIGHT
    from globeview.bench.flight import resolve_flight, shipped_flights_dir

    flights = shipped_flights_dir()
    assert ROOT / "globeview" in flights.parents
    stems = {p.stem for p in flights.glob("*.json")}
    assert {"canyon_run", "fast_pan", "global_approach", "regional_oblique"} <= stems
    assert resolve_flight("canyon_run") == flights / "canyon_run.json"
    for name in (QUICK_FLIGHT, STANDARD_FLIGHT):
        assert (flights / name).exists(), name


def test_the_version_is_written_in_one_place() -> None:
    import globeview

    project = _pyproject()["project"]
    assert "version" not in project and "version" in project["dynamic"]
    attr = _pyproject()["tool"]["setuptools"]["dynamic"]["version"]["attr"]
    assert attr == "globeview.__version__"
    assert globeview.__version__.count(".") == 2
