"""Layer contributions declare the file suffixes they open in their manifest (read without
importing the plugin), so file dispatch and the Open Overlay filter need no plugin code."""

from __future__ import annotations

import pytest

from globeview.plugins.manifest import ManifestError, parse_manifest


def _data(**contribution: object) -> dict:
    base = {"name": "grat", "kind": "layer", "target": "gvt_grat.impl:Graticule"}
    return {
        "name": "grat",
        "version": "1.0",
        "description": "d",
        "kinds": ["layer", "tool"],
        "api_version": "1.0",
        "contributions": [base | contribution],
    }


def test_layer_extensions_are_read_lower_case() -> None:
    m = parse_manifest(_data(extensions=[".Graticule", ".grat", ".tar.gz"]))
    assert m.contributions[0].extensions == (".graticule", ".grat", ".tar.gz")


def test_extensions_default_to_none() -> None:
    assert parse_manifest(_data()).contributions[0].extensions == ()


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("graticule", "must be a list"),
        (["graticule"], "is not a file suffix"),
        ([".a b"], "is not a file suffix"),
        ([3], "is not a file suffix"),
        ([f".e{i}" for i in range(40)], "at most 32"),
    ],
)
def test_bad_extensions_fail_in_one_line(value: object, message: str) -> None:
    with pytest.raises(ManifestError, match=message) as info:
        parse_manifest(_data(extensions=value))
    assert "\n" not in str(info.value)


def test_extensions_only_on_layers() -> None:
    with pytest.raises(ManifestError, match="layer contributions only"):
        parse_manifest(_data(kind="tool", extensions=[".x"]))
