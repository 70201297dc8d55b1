"""File dispatch over all enabled layer types, built-in and installed (issue #15 item 1):
an explicit TYPE:FILE first, then declared extensions (installed plugins before built-ins),
then content sniffing; the Open Overlay filter lists every type's patterns; an unknown file's
error names the installed types. Plugins are real distributions on sys.path (PluginSite)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from globeview.app.layer_dispatch import (
    choose_layer_type,
    layer_type_infos,
    overlay_file_filter,
    parse_layer_spec,
)
from globeview.app.testing import PluginSite
from globeview.errors import GlobeviewError
from globeview.plugins.registry import PluginRegistry
from globeview.plugins.settings import MemorySettings

ZEBRA_MANIFEST = """
    name = "zebra"
    version = "0.1.0"
    description = "a layer type with a file format of its own"
    kinds = ["layer"]
    api_version = "1.0"

    [[contributions]]
    name = "zebra"
    kind = "layer"
    target = "gvt_zebra.impl:ZebraType"
    label = "Zebra stripes"
    extensions = [".zebra"]
    """

#: A .zebra file: first line "ZEBRA", then "parallel LAT", "meridian LON" lines.
ZEBRA_IMPL = """
    from pathlib import Path

    import numpy as np

    from globeview.plugins.api import GlobeviewError, Lines

    class ZebraType:
        name = "zebra"
        label = "Zebra stripes"
        extensions = (".zebra",)

        def __init__(self, context=None):
            self.context = context

        def sniff(self, path):
            with open(path, "rb") as fh:
                return fh.read(5) == b"ZEBRA"

        def open(self, path):
            lines = Path(path).read_text().splitlines()
            if not lines or lines[0].strip() != "ZEBRA":
                raise GlobeviewError(f"{Path(path).name}: not a zebra file")
            return Lines([np.array([[-40.0, 30.0], [40.0, 30.0]])], interpolation="rhumb")
    """

GREEDY_MANIFEST = """
    name = "greedy"
    version = "0.1.0"
    description = "claims GeoJSON"
    kinds = ["layer"]
    api_version = "1.0"

    [[contributions]]
    name = "greedy"
    kind = "layer"
    target = "gvt_greedy.impl:Greedy"
    extensions = [".geojson"]
    """

GREEDY_IMPL = """
    class Greedy:
        name = "greedy"
        label = "Greedy GeoJSON"
        extensions = (".geojson",)

        def __init__(self, context=None):
            self.context = context

        def sniff(self, path):
            return "greedy" in open(path, encoding="utf-8").read()

        def open(self, path):
            raise AssertionError("not opened in these tests")
    """


def _registry() -> PluginRegistry:
    return PluginRegistry(MemorySettings()).discover()


@pytest.fixture
def zebra_site(plugin_site: PluginSite) -> PluginSite:
    plugin_site.add("gvt_zebra", ZEBRA_MANIFEST, {"impl": ZEBRA_IMPL})
    return plugin_site


def _geojson(path: Path, text_extra: str = "") -> Path:
    doc = {
        "type": "Feature",
        "properties": {"note": text_extra},
        "geometry": {"type": "LineString", "coordinates": [[0, 0], [10, 10]]},
    }
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path


def test_builtins_by_extension_and_content() -> None:
    reg = _registry()
    data = Path(__file__).resolve().parents[2] / "data"
    assert choose_layer_type(reg, data / "bluemarble_2048x1024.tif") == "imagery"
    assert choose_layer_type(reg, data / "etopo20.tif") == "thematic"
    assert choose_layer_type(reg, data / "ne_110m_countries.geojson") == "vector"
    assert choose_layer_type(reg, data / "ne_cities.geojson") == "points"


def test_plugin_extension_declared_in_the_manifest(zebra_site, tmp_path) -> None:
    f = tmp_path / "stripes.ZEBRA"  # suffixes match case-insensitively
    f.write_text("ZEBRA\n")
    reg = _registry()
    infos = {i.name: i for i in layer_type_infos(reg, load=False)}
    assert infos["zebra"].extensions == (".zebra",) and not infos["zebra"].builtin
    assert choose_layer_type(reg, f) == "zebra"


def test_content_sniffing_when_no_extension_claims(zebra_site, tmp_path) -> None:
    f = tmp_path / "stripes.txt"
    f.write_text("ZEBRA\n")
    assert choose_layer_type(_registry(), f) == "zebra"
    g = _geojson(tmp_path / "line.dat")  # GeoJSON under another name: the built-in sniffs it
    assert choose_layer_type(_registry(), g) == "vector"


def test_installed_plugins_before_builtins_then_sniff_decides(plugin_site, tmp_path) -> None:
    plugin_site.add("gvt_greedy", GREEDY_MANIFEST, {"impl": GREEDY_IMPL})
    reg = _registry()
    mine = _geojson(tmp_path / "mine.geojson", "greedy")
    plain = _geojson(tmp_path / "plain.geojson")
    assert choose_layer_type(reg, mine) == "greedy"  # both claim .geojson: the plugin first
    assert choose_layer_type(reg, plain) == "vector"  # its sniff said no: the built-in
    # An explicit choice beats both.
    assert choose_layer_type(reg, mine, "vector") == "vector"


def test_explicit_type_spec() -> None:
    assert parse_layer_spec("zebra:/tmp/x.zebra") == ("zebra", "/tmp/x.zebra")
    assert parse_layer_spec("C:\\maps\\x.tif") == (None, "C:\\maps\\x.tif")  # a drive letter
    assert parse_layer_spec("plain.geojson") == (None, "plain.geojson")
    # a relative FILE::LAYER is a file's layer, not TYPE "wm.gpkg" with file ":trails"
    assert parse_layer_spec("wm.gpkg::trails") == (None, "wm.gpkg::trails")
    assert parse_layer_spec("gis:wm.gpkg::trails") == ("gis", "wm.gpkg::trails")


def test_existing_file_with_a_colon_is_a_path(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    _geojson(tmp_path / "vector:odd.geojson")
    assert parse_layer_spec("vector:odd.geojson") == (None, "vector:odd.geojson")


def test_unknown_file_names_the_installed_types(zebra_site, tmp_path) -> None:
    f = tmp_path / "notes.xyz"
    f.write_bytes(b"\x00\x01 nothing anyone reads")
    with pytest.raises(GlobeviewError) as info:
        choose_layer_type(_registry(), f)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("notes.xyz: no layer type opens this file")
    for name in ("imagery", "thematic", "vector", "points", "zebra (.zebra)"):
        assert name in msg


def test_unknown_explicit_type_names_the_installed_types(zebra_site, tmp_path) -> None:
    f = tmp_path / "a.zebra"
    f.write_text("ZEBRA\n")
    with pytest.raises(GlobeviewError, match=r"no enabled layer type named 'gpx'.*zebra"):
        choose_layer_type(_registry(), f, "gpx")


def test_broken_file_of_a_known_format_keeps_its_precise_error(tmp_path) -> None:
    f = tmp_path / "broken.geojson"
    f.write_text('{"type": "FeatureCollection", "features": [', encoding="utf-8")
    with pytest.raises(GlobeviewError, match=r"broken\.geojson: not valid GeoJSON"):
        choose_layer_type(_registry(), f)


def test_missing_file_and_directory(tmp_path) -> None:
    with pytest.raises(GlobeviewError, match=r"nope\.geojson: no such file"):
        choose_layer_type(_registry(), tmp_path / "nope.geojson")
    with pytest.raises(GlobeviewError, match="is a directory"):
        choose_layer_type(_registry(), tmp_path)


def test_a_crashing_sniff_fails_only_that_type(plugin_site, tmp_path) -> None:
    plugin_site.add(
        "gvt_greedy",
        GREEDY_MANIFEST,
        {"impl": GREEDY_IMPL.replace('return "greedy" in', "raise ZeroDivisionError #")},
    )
    reg = _registry()
    plain = _geojson(tmp_path / "plain.geojson")
    assert choose_layer_type(reg, plain) == "vector"
    rec = reg.get("greedy")
    assert rec.status == "failed" and "ZeroDivisionError" in rec.error
    assert choose_layer_type(reg, plain) == "vector"  # asked once, then left out


def test_a_type_disabled_by_its_sniff_is_named_as_such_with_why(plugin_site, tmp_path) -> None:
    """Nobody takes the file after a sniff crashed (issue #29 item 9): the line no longer
    lists the crashed type as installed; it says the type was disabled and why."""
    plugin_site.add(
        "gvt_greedy",
        GREEDY_MANIFEST,
        {"impl": GREEDY_IMPL.replace('return "greedy" in', "raise ZeroDivisionError('zz') #")},
    )
    f = tmp_path / "notes.xyz"
    f.write_bytes(b"\x00\x01 nothing anyone reads")
    with pytest.raises(GlobeviewError) as info:
        choose_layer_type(_registry(), f)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("notes.xyz: no layer type opens this file")
    installed = msg.split("(installed: ", 1)[1].split(";", 1)[0]
    assert "greedy" not in installed and "vector (.geojson .json)" in installed
    assert msg.endswith("; disabled: greedy (its sniff failed: ZeroDivisionError: zz))")


def test_open_overlay_filter_lists_every_type(zebra_site) -> None:
    flt = overlay_file_filter(_registry())
    entries = flt.split(";;")
    assert entries[0].startswith("Overlays (") and "*.zebra" in entries[0]
    assert "*.geojson" in entries[0] and "*.tif" in entries[0]
    assert "Zebra stripes (*.zebra)" in entries
    assert entries[-1] == "All files (*)"


def test_a_type_without_manifest_extensions_is_asked_for_its_attribute(
    plugin_site, tmp_path
) -> None:
    plugin_site.add(
        "gvt_zebra", ZEBRA_MANIFEST.replace('extensions = [".zebra"]', ""), {"impl": ZEBRA_IMPL}
    )
    f = tmp_path / "s.zebra"
    f.write_text("ZEBRA\n")
    reg = _registry()
    assert choose_layer_type(reg, f) == "zebra"
    assert "*.zebra" in overlay_file_filter(reg)


def test_an_empty_file_says_so_whatever_its_name(tmp_path) -> None:
    for name in ("empty.geojson", "empty.tif", "empty.xyz"):
        f = tmp_path / name
        f.write_bytes(b"  \n")
        with pytest.raises(GlobeviewError, match=rf"^{name}: the file is empty$"):
            choose_layer_type(_registry(), f)


def test_a_fifo_is_refused_without_being_read(tmp_path) -> None:
    import os

    fifo = tmp_path / "pipe.geojson"
    os.mkfifo(fifo)  # opening it to sniff would block forever
    with pytest.raises(GlobeviewError, match=r"^pipe\.geojson: not a regular file$"):
        choose_layer_type(_registry(), fifo)


def test_a_geojson_file_is_parsed_once_while_unchanged(tmp_path, monkeypatch) -> None:
    # Opening a file dispatches twice (the dialog, then the session) and each GeoJSON type
    # sniffs it: five parses of the whole file on the window's thread before.
    import json
    import shutil

    import globeview.plugins.builtin.layers.types as layers
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.terrain.dem.data import EMBEDDED_DATA_DIR

    reg = PluginRegistry(MemorySettings()).discover()
    src = tmp_path / "cities.geojson"
    shutil.copyfile(EMBEDDED_DATA_DIR / "ne_cities.geojson", src)
    calls = []
    real = json.loads
    monkeypatch.setattr(layers.json, "loads", lambda *a, **k: calls.append(1) or real(*a, **k))
    for _ in range(2):
        assert choose_layer_type(reg, src) == "points"
    assert len(calls) == 1
    # An edited file is read again.
    src.write_text('{"type": "LineString", "coordinates": [[0, 0], [1, 1]]}')
    assert choose_layer_type(reg, src) == "vector" and len(calls) == 2
