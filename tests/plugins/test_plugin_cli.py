"""`globeview plugins list/validate/enable/disable` (globeview.cli.plugins), run in-process
through its own parser until the subcommand is registered in globeview.cli."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from globeview.cli import plugins as cli_plugins


def _run(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="globeview plugins")
    cli_plugins.add_arguments(parser)
    return cli_plugins.run(parser.parse_args(list(argv)))


def test_list_table(globeview_config_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run("list") == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:5] == ["NAME", "VERSION", "KINDS", "ENABLED", "STATUS"]
    row = next(line for line in out if line.startswith("fixed-level "))
    assert row.split()[:5] == ["fixed-level", "0.1.0", "lod,tool,layer", "yes", "ok"]
    assert any(line.startswith("chunked-sse ") for line in out)


def test_list_json(globeview_config_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run("disable", "fixed-level") == 0
    assert capsys.readouterr().out.strip() == "fixed-level: disabled"
    assert _run("list", "--json") == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    fl = rows["fixed-level"]
    assert (fl["version"], fl["kinds"], fl["enabled"], fl["status"], fl["error"]) == (
        "0.1.0",
        ["lod", "tool", "layer"],
        False,
        "disabled",
        None,
    )
    assert rows["chunked-sse"]["builtin"] is True
    assert _run("enable", "fixed-level") == 0
    capsys.readouterr()
    _run("list", "--json")
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["fixed-level"]["enabled"] is True


def test_list_check_reports_failures(
    globeview_config_dir: Path, plugin_site, capsys: pytest.CaptureFixture[str]
) -> None:
    plugin_site.add(
        "gvt_cli_broken",
        """
        name = "cli-broken"
        version = "0.0.1"
        description = "fails to import"
        kinds = ["tool"]
        api_version = "1.0"
        [[contributions]]
        name = "cli-broken"
        kind = "tool"
        target = "gvt_cli_broken.impl:Tool"
        """,
        {"impl": "raise ImportError('needs libfoo')\n"},
    )
    _run("list", "--json")
    assert {r["name"]: r["status"] for r in json.loads(capsys.readouterr().out)}[
        "cli-broken"
    ] == "ok"
    _run("list", "--json", "--check")
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert rows["cli-broken"]["status"] == "failed"
    assert rows["cli-broken"]["error"] == "ImportError: needs libfoo"
    assert rows["fixed-level"]["status"] == "ok"


def test_validate_installed_name(capsys: pytest.CaptureFixture[str]) -> None:
    assert _run("validate", "fixed-level") == 0
    out = capsys.readouterr().out
    assert out.startswith("valid: fixed-level 0.1.0 (lod,tool,layer; 4 contributions")
    assert _run("validate", "fixed-level", "--import") == 0


def test_validate_path(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = Path(__file__).parents[2] / "examples/globeview-fixedlevel/globeview_fixedlevel"
    assert _run("validate", str(good / "globeview.toml")) == 0
    bad = tmp_path / "globeview.toml"
    bad.write_text(
        (good / "globeview.toml").read_text().replace('api_version = "1.1"', 'api_version = "2.0"')
    )
    capsys.readouterr()
    assert _run("validate", str(bad)) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("invalid: ") and "major versions differ" in err and "\n" not in err


def test_validate_unknown_name(capsys: pytest.CaptureFixture[str]) -> None:
    assert _run("validate", "no-such-plugin") == 2
    assert "no plugin named 'no-such-plugin'" in capsys.readouterr().err
