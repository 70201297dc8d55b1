"""Manifest-declared tool commands (``[[contributions.commands]]``): parsed without importing
the plugin, each fault a one-line `ManifestError`, and `plugins validate` reports it as one
line (exit 2), never a traceback."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import globeview.plugins.builtin as builtin_pkg
from globeview.plugins.manifest import (
    Command,
    ManifestError,
    normalize_shortcut,
    parse_manifest,
    read_manifest,
)

TOOL = """
name = "pins"
version = "0.1.0"
description = "Drops pins."
kinds = ["tool", "lod"]
api_version = "1.0"

[[contributions]]
name = "pins"
kind = "tool"
target = "pins_pkg.tool:PinTool"

[[contributions.commands]]
name = "clear"
label = "Clear pins"
shortcut = "shift+ctrl+x"
method = "clear"

[[contributions.commands]]
name = "undo"
method = "undo"

[[contributions]]
name = "pins-lod"
kind = "lod"
target = "pins_pkg.lod:Provider"
"""


def _with_command(**fields) -> dict:
    """The TOOL manifest with its first command's fields changed (None: removed)."""
    data = tomllib.loads(TOOL)
    cmd = data["contributions"][0]["commands"][0]
    for k, v in fields.items():
        if v is None:
            cmd.pop(k, None)
        else:
            cmd[k] = v
    return data


def test_commands_parse_with_canonical_shortcuts_and_default_labels() -> None:
    m = parse_manifest(tomllib.loads(TOOL))
    tool = m.contribution("pins")
    assert tool.commands == (
        Command("clear", "Clear pins", "clear", "Ctrl+Shift+X"),
        Command("undo", "undo", "undo", ""),
    )
    assert m.contribution("pins-lod").commands == ()


def test_builtin_collapse_declares_its_c_and_e_commands() -> None:
    path = Path(builtin_pkg.__file__).parent / "collapse" / "manifest.toml"
    (tool,) = read_manifest(path).contributions
    assert {c.shortcut: c.method for c in tool.commands} == {"C": "collapse", "E": "expand"}


@pytest.mark.parametrize(
    ("text", "canonical"),
    [
        ("c", "C"),
        ("alt+shift+ctrl+meta+F5", "Ctrl+Shift+Alt+Meta+F5"),
        ("Ctrl++", "Ctrl++"),
        ("+", "+"),
        ("pgup", "PgUp"),
        ("Shift+1", "Shift+1"),
    ],
)
def test_shortcut_spellings_are_normalised(text: str, canonical: str) -> None:
    assert normalize_shortcut(text) == canonical


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"shortcut": "Ctrl+Shift"}, "'Shift' is not one key"),
        ({"shortcut": "Ctrl+"}, "'' is not one key"),
        ({"shortcut": "Hyper+X"}, "'Hyper' is not one of Ctrl, Shift, Alt, Meta"),
        ({"shortcut": "Ctrl+Ctrl+X"}, "Ctrl given twice"),
        ({"shortcut": "Escape"}, "Escape is reserved"),
        ({"shortcut": "Ctrl+é"}, "is not one key"),
        ({"shortcut": "C, D"}, "is not one key"),
        ({"shortcut": 3}, "field 'shortcut' must be a string"),
        ({"method": None}, "missing required field 'method'"),
        ({"method": "_private"}, "must be the name of a public method"),
        ({"method": "a.b"}, "must be the name of a public method"),
        ({"name": "Bad Name"}, "must be lower-case letters"),
        ({"name": "undo"}, "duplicate command name 'undo'"),
        ({"label": "x" * 201}, "field 'label' is 201 characters"),
        ({"label": "two\nlines"}, "field 'label' must be one line"),
        ({"args": [1]}, "unknown field 'args'"),
    ],
)
def test_bad_commands_are_one_line_errors(fields: dict, message: str) -> None:
    with pytest.raises(ManifestError, match=r"contribution 1: command [12]: ") as info:
        parse_manifest(_with_command(**fields))
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_commands_belong_to_tools_and_are_bounded() -> None:
    data = tomllib.loads(TOOL)
    data["contributions"][1]["commands"] = [{"name": "x", "method": "x"}]
    with pytest.raises(ManifestError, match="only tool contributions declare commands, not lod"):
        parse_manifest(data)
    data = tomllib.loads(TOOL)
    data["contributions"][0]["commands"] = {"name": "x", "method": "x"}
    with pytest.raises(ManifestError, match="must be an array of tables"):
        parse_manifest(data)
    data["contributions"][0]["commands"] = [{"name": f"c{i}", "method": "m"} for i in range(33)]
    with pytest.raises(ManifestError, match="33 commands"):
        parse_manifest(data)
    data["contributions"][0]["commands"] = ["clear"]
    with pytest.raises(ManifestError, match="command 1: must be a table"):
        parse_manifest(data)


@pytest.mark.slow
def test_plugins_validate_reports_a_bad_shortcut_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "globeview.toml"
    path.write_text(TOOL.replace('"shift+ctrl+x"', '"Ctrl+Banana"'), encoding="utf-8")
    proc = subprocess.run(
        [sys.executable, "-m", "globeview", "plugins", "validate", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert "command 1: shortcut 'Ctrl+Banana': 'Banana' is not one key" in lines[0]
