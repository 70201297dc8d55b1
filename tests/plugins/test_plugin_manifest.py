"""Manifest parsing and validation: every invalid case gets its own one-line error."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import globeview.plugins.builtin as builtin_pkg
from globeview.plugins.api import API_VERSION, PluginKind
from globeview.plugins.manifest import (
    ManifestError,
    check_api_version,
    locate_manifest,
    parse_manifest,
    read_manifest,
)

VALID = """
name = "demo"
version = "1.2.3"
description = "A demo plugin."
kinds = ["lod", "tool"]
api_version = "1.0"

[[contributions]]
name = "demo-lod"
kind = "lod"
target = "demo_pkg.lod:Provider"
label = "Demo LOD"

[[contributions]]
name = "demo-tool"
kind = "tool"
target = "demo_pkg.tools:make_tool"
"""


def _data(**changes) -> dict:
    d = tomllib.loads(VALID)
    for k, v in changes.items():
        if v is None:
            d.pop(k, None)
        else:
            d[k] = v
    return d


def test_valid_manifest_parses() -> None:
    m = parse_manifest(_data())
    assert m.name == "demo" and m.version == "1.2.3"
    assert m.kinds == (PluginKind.LOD, PluginKind.TOOL)
    assert [c.name for c in m.contributions] == ["demo-lod", "demo-tool"]
    lod = m.contribution("demo-lod")
    assert (lod.module, lod.attribute, lod.label) == ("demo_pkg.lod", "Provider", "Demo LOD")
    assert m.contribution("demo-tool").label == "demo-tool"  # label defaults to the name


@pytest.mark.parametrize("field", ["name", "version", "description", "kinds", "api_version"])
def test_missing_field(field: str) -> None:
    with pytest.raises(ManifestError, match=f"missing required field '{field}'"):
        parse_manifest(_data(**{field: None}))


def test_missing_contributions() -> None:
    with pytest.raises(ManifestError, match="missing required field 'contributions'"):
        parse_manifest(_data(contributions=None))


def test_bad_kind_in_plugin() -> None:
    with pytest.raises(ManifestError, match="unknown kind 'renderer'"):
        parse_manifest(_data(kinds=["lod", "renderer"]))


def test_bad_kind_in_contribution() -> None:
    d = _data()
    d["contributions"][0]["kind"] = "shader"
    with pytest.raises(ManifestError, match="contribution 1: unknown kind 'shader'"):
        parse_manifest(d)


def test_contribution_kind_not_declared() -> None:
    d = _data(kinds=["lod"])
    with pytest.raises(ManifestError, match="contribution 2: kind 'tool' is not among"):
        parse_manifest(d)


@pytest.mark.parametrize(
    "target", ["demo_pkg.lod.Provider", "demo_pkg:", ":Provider", "demo-pkg:Provider", "a:b:c"]
)
def test_bad_target_syntax(target: str) -> None:
    d = _data()
    d["contributions"][0]["target"] = target
    with pytest.raises(ManifestError, match="is not 'module:attribute'"):
        parse_manifest(d)


def test_missing_target() -> None:
    d = _data()
    del d["contributions"][1]["target"]
    with pytest.raises(ManifestError, match="contribution 2: missing required field 'target'"):
        parse_manifest(d)


def test_duplicate_contribution_name() -> None:
    d = _data()
    d["contributions"][1]["name"] = "demo-lod"
    with pytest.raises(ManifestError, match="duplicate contribution name 'demo-lod'"):
        parse_manifest(d)


def test_bad_plugin_name() -> None:
    with pytest.raises(ManifestError, match="plugin name 'Demo Plugin'"):
        parse_manifest(_data(name="Demo Plugin"))


def test_wrong_field_type() -> None:
    with pytest.raises(ManifestError, match="field 'version' must be a string"):
        parse_manifest(_data(version=1))


def test_api_major_mismatch() -> None:
    major = int(API_VERSION.split(".")[0])
    with pytest.raises(ManifestError, match="major versions differ"):
        parse_manifest(_data(api_version=f"{major + 1}.0"))


def test_api_newer_minor_rejected_older_accepted() -> None:
    major, minor = (int(p) for p in API_VERSION.split("."))
    with pytest.raises(ManifestError, match="newer than"):
        check_api_version(f"{major}.{minor + 1}")
    check_api_version(f"{major}.0")  # an older minor of the same major loads
    with pytest.raises(ManifestError, match=r"not MAJOR\.MINOR"):
        check_api_version("one")


def test_errors_are_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nversion = \n', encoding="utf-8")
    with pytest.raises(ManifestError) as info:
        read_manifest(bad)
    msg = str(info.value)
    assert "\n" not in msg and str(bad) in msg and "not valid TOML" in msg
    with pytest.raises(ManifestError, match="cannot read manifest"):
        read_manifest(tmp_path / "absent.toml")


def test_read_manifest_file_names_the_file(tmp_path: Path) -> None:
    p = tmp_path / "m.toml"
    p.write_text(VALID.replace('kinds = ["lod", "tool"]', 'kinds = ["lod", "raster"]'))
    with pytest.raises(ManifestError, match=r"m\.toml: unknown kind 'raster'"):
        read_manifest(p)


def test_builtin_chunked_sse_manifest() -> None:
    path = locate_manifest("globeview.plugins.builtin.chunked:manifest.toml")
    assert path == Path(builtin_pkg.__file__).parent / "chunked" / "manifest.toml"
    m = read_manifest(path)
    assert m.name == "chunked-sse" and m.kinds == (PluginKind.LOD,)
    assert m.contribution("chunked-sse").target == (
        "globeview.plugins.builtin.chunked.provider:ChunkedSseProvider"
    )


def test_locate_manifest_errors() -> None:
    with pytest.raises(ManifestError, match=r"must be 'package:manifest\.toml'"):
        locate_manifest("globeview.plugins.builtin:ChunkedSse")
    with pytest.raises(ManifestError, match="is not installed"):
        locate_manifest("no_such_package_xyz:globeview.toml")
    with pytest.raises(ManifestError, match="not found in package"):
        locate_manifest("globeview.plugins.builtin:absent.toml")


@pytest.mark.slow
def test_locating_and_reading_imports_no_plugin_code() -> None:
    """In a fresh interpreter: reading every manifest leaves the plugins' modules unimported."""
    code = (
        "import sys\n"
        "from globeview.plugins.registry import PluginRegistry\n"
        "from globeview.plugins.settings import MemorySettings\n"
        "reg = PluginRegistry(MemorySettings()).discover()\n"
        "print(sorted(reg.records))\n"
        "print([m for m in sys.modules if m.startswith('globeview_fixedlevel')\n"
        "       or m.startswith('globeview.plugins.builtin.')])\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    names, imported = r.stdout.strip().splitlines()
    assert "'fixed-level'" in names and "'chunked-sse'" in names
    assert imported == "[]"
