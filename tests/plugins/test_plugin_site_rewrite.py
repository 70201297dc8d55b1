"""`PluginSite.add` rewriting a module: the next import runs the new code, even when the
rewrite falls within the second of the last import and keeps the file's length (the bytecode
cache checks whole-second mtime and size only)."""

from __future__ import annotations

import importlib
import os
import sys

import pytest

from globeview.app.testing import PluginSite

MANIFEST = """
    name = "gvt_rewrite"
    """


def _write(site: PluginSite, value: int) -> os.stat_result:
    site.add("gvt_rewrite", MANIFEST, {"impl": f"ANSWER = {value}\n"})
    return os.stat(site.root / "gvt_rewrite" / "impl.py")


def _import(site: PluginSite) -> int:
    site.forget_modules()
    return int(importlib.import_module("gvt_rewrite.impl").ANSWER)


def test_a_module_rewritten_at_the_same_length_imports_anew(
    plugin_site: PluginSite, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(sys, "dont_write_bytecode", False)  # the cache this is about
    first = _write(plugin_site, 41)
    assert _import(plugin_site) == 41  # compiled, and its bytecode cached
    again = _write(plugin_site, 42)
    assert again.st_size == first.st_size
    # Within the same second as the cached bytecode's source, for sure.
    os.utime(
        plugin_site.root / "gvt_rewrite" / "impl.py", ns=(first.st_atime_ns, first.st_mtime_ns)
    )
    assert _import(plugin_site) == 42
