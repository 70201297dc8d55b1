"""`import globeview` stays cheap (no GL, Qt, GDAL or Dask until used), and the public names
are there, documented and typed."""

from __future__ import annotations

import inspect
import subprocess
import sys

import pytest

import globeview

HEAVY = ("moderngl", "PyQt6", "rasterio", "dask", "globeview.app", "globeview.ui")


def test_import_globeview_loads_no_heavy_module():
    code = (
        "import sys, globeview\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
        "globeview.Globe\n"
        "print('PyQt6' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    first, second = out.stdout.splitlines()
    assert first == "[]"
    assert second == "False"  # the Globe is Qt-free


def test_public_names():
    assert set(globeview.__all__) >= {"Globe", "show", "CameraPose", "Profile"}
    for name in globeview.__all__:
        assert getattr(globeview, name) is not None
    assert "Globe" in dir(globeview)
    with pytest.raises(AttributeError, match="no_such_name"):
        globeview.no_such_name  # noqa: B018


def test_public_methods_are_documented_and_typed():
    cls = globeview.Globe
    public = [n for n, _ in inspect.getmembers(cls) if not n.startswith("_")]
    assert {
        "add_dem",
        "add_overlay",
        "camera",
        "fly_to",
        "lod",
        "measure",
        "render",
        "save",
    } <= set(public)
    for name in public:
        member = inspect.getattr_static(cls, name)
        fn = member.fget if isinstance(member, property) else member
        assert inspect.getdoc(fn), name
        if callable(fn):
            assert "return" in inspect.get_annotations(fn), name
    assert inspect.getdoc(globeview.show)
