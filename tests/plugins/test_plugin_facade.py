"""The plugin facade (issue #15, "Built-ins dogfood the API"): `globeview.plugins.api` is
the one module a plugin imports, the built-ins and the example plugin import nothing else of
globeview, and the host never imports a built-in directly. The import-linter contracts in
pyproject.toml hold that in ./test; the tests here show those contracts really fail when
someone breaks the rule (planted imports in a copy of the tree)."""

from __future__ import annotations

import ast
import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import globeview.plugins.api as api

ROOT = Path(__file__).resolve().parents[2]
BUILTIN = ROOT / "globeview/plugins/builtin"
EXAMPLE = ROOT / "examples/globeview-fixedlevel/globeview_fixedlevel"
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")

BUILTIN_CONTRACT = "Built-in plugins import only the plugin API (globeview.plugins.api)"
EXAMPLE_CONTRACT = "The example plugin imports only the plugin API (globeview.plugins.api)"
HOST_CONTRACT = "The host never imports globeview.plugins.builtin"


def test_every_exported_name_resolves() -> None:
    missing = [n for n in api.__all__ if getattr(api, n, None) is None]
    assert not missing
    assert sorted(api.__all__) == sorted(set(api.__all__))
    assert set(api._REEXPORTS) <= set(api.__all__)
    assert set(api._REEXPORTS) <= set(dir(api))


def test_reexports_are_the_host_objects() -> None:
    """A re-export is the host's own object (isinstance checks and RenderSet validation
    in the host see the class the plugin built)."""
    for name, module in api._REEXPORTS.items():
        assert getattr(api, name) is getattr(importlib.import_module(module), name), name


def test_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no_such_name"):
        api.no_such_name  # noqa: B018
    assert not hasattr(api, "select_tiles")  # an internal of a built-in is not API


@pytest.mark.slow
def test_reading_the_api_loads_no_renderer_or_terrain() -> None:
    """Manifests import the API module (API_VERSION): discovery must stay light."""
    code = (
        "import sys, globeview.plugins.api, globeview.plugins.manifest\n"
        "print(sorted(m for m in sys.modules if m.startswith(('globeview.render',"
        " 'globeview.terrain', 'moderngl', 'rasterio', 'PyQt6'))))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def _globeview_imports(path: Path) -> list[str]:
    """Every globeview module ``path`` imports, at any depth of the file (functions too)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append(node.module)
        elif isinstance(node, ast.Import):
            found.extend(a.name for a in node.names)
    return [m for m in found if m == "globeview" or m.startswith("globeview.")]


@pytest.mark.parametrize(
    "path",
    sorted(BUILTIN.glob("*.py")) + sorted(EXAMPLE.glob("*.py")),
    ids=lambda p: f"{p.parent.name}/{p.name}",
)
def test_plugin_modules_import_only_the_facade(path: Path) -> None:
    """Also the imports inside functions, which import-linter sees too but a reader may
    miss: only the facade, and for built-ins their own package."""
    allowed = ("globeview.plugins.api",)
    own = "globeview.plugins.builtin"
    bad = [
        m
        for m in _globeview_imports(path)
        if m not in allowed and not (path.parent == BUILTIN and m.startswith(own))
    ]
    assert not bad, f"{path.name} imports {bad}"


# -- the import-linter contracts fail when the rule is broken ------------------------------
def _lint(tree: Path) -> str:
    env = dict(
        os.environ,
        COLUMNS="200",
        PYTHONPATH=f"{tree}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
    )
    res = subprocess.run(
        [str(LINT_IMPORTS), "--no-cache"],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
    )
    return res.stdout + res.stderr


def _copy_tree(dest: Path) -> Path:
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(ROOT / "globeview", dest / "globeview", ignore=ignore)
    shutil.copytree(EXAMPLE, dest / "globeview_fixedlevel", ignore=ignore)
    shutil.copy(ROOT / "pyproject.toml", dest / "pyproject.toml")
    return dest


def _status(report: str, contract: str) -> str:
    line = next(ln for ln in report.splitlines() if ln.startswith(contract))
    return "KEPT" if " KEPT" in line else "BROKEN"


@pytest.mark.slow
@pytest.mark.skipif(not LINT_IMPORTS.exists(), reason="import-linter not installed")
def test_contracts_kept_here_and_broken_by_planted_imports(tmp_path: Path) -> None:
    clean = _copy_tree(tmp_path / "clean")
    report = _lint(clean)
    for contract in (BUILTIN_CONTRACT, EXAMPLE_CONTRACT, HOST_CONTRACT):
        assert _status(report, contract) == "KEPT", report

    planted = _copy_tree(tmp_path / "planted")
    plants = {
        "globeview/plugins/builtin/_planted.py": "from globeview.lod.culling import chord_sag\n",
        "globeview_fixedlevel/_planted.py": "from globeview.terrain.quadtree import level_shape\n",
        "globeview/ui/_planted.py": "from globeview.plugins.builtin import layers\n",
        "globeview/plugins/_planted_host.py": "import globeview.plugins.builtin.chunked.provider\n",
    }
    for rel, src in plants.items():
        (planted / rel).write_text(src, encoding="utf-8")
    report = _lint(planted)
    for contract in (BUILTIN_CONTRACT, EXAMPLE_CONTRACT, HOST_CONTRACT):
        assert _status(report, contract) == "BROKEN", report
    assert "globeview.plugins.builtin._planted -> globeview.lod.culling" in report
    assert "globeview_fixedlevel._planted -> globeview.terrain.quadtree" in report
    assert "globeview.ui._planted -> globeview.plugins.builtin" in report
    assert "globeview.plugins._planted_host -> globeview.plugins.builtin.chunked.provider" in report


def test_docs_list_every_public_name() -> None:
    """docs/plugins.md's table of the API lists exactly the names of ``__all__`` (the
    facade is "one documented module"; a name added without docs fails here)."""
    import re

    text = (ROOT / "docs/plugins.md").read_text(encoding="utf-8")
    start = text.index("| group | names |")
    table = text[start : text.index("\n\n", start)]
    names = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", table))
    stack_methods = {"metadata", "heights", "height_at", "max_level", "tile_size", "version"}
    assert sorted(names - stack_methods - set(api.__all__)) == []
    assert sorted(set(api.__all__) - names) == []


def test_builtin_manifests_target_the_hosts_api_version() -> None:
    # The built-ins are the proof that the current API is enough: they declare it, as a
    # third-party plugin using its newer names must.
    import tomllib
    from pathlib import Path

    import globeview.plugins.builtin as builtin
    from globeview.plugins.api import API_VERSION

    manifests = sorted(Path(builtin.__file__).parent.glob("*/manifest.toml"))
    assert len(manifests) >= 7
    for path in manifests:
        assert tomllib.loads(path.read_text())["api_version"] == API_VERSION, path.parent.name


def test_a_tool_reaches_the_hosts_redraw_and_status_through_its_base_class() -> None:
    from globeview.plugins.api import NullRendererHooks, PluginContext, Tool

    hooks = NullRendererHooks()
    tool = Tool(PluginContext(name="t", renderer=hooks))
    tool.request_redraw()
    tool.set_status("measure: A picked")
    assert (hooks.redraws, hooks.status) == (1, "measure: A picked")
    # Made without a context (tests, scripts) or with hooks lacking a method: nothing happens.
    Tool().request_redraw()
    Tool(PluginContext(name="t", renderer=object())).set_status("ignored")
