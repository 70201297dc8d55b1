"""The store manifest's typed schema: one definition written by ingest and read by the store;
round trips, and refusals of other versions and malformed manifests in one line."""

from __future__ import annotations

import io
import json
import shutil
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from globeview.errors import StoreError
from globeview.terrain.ingest.driver import STRIDES, ingest
from globeview.terrain.store.identify import MANIFEST_NAME
from globeview.terrain.store.schema import (
    FORMAT_VERSION,
    STORE_FORMAT,
    Extent,
    FileRef,
    IngestParams,
    LevelRecord,
    ManifestError,
    PoleHeights,
    ShardsRecord,
    SourceRecord,
    StoreHeader,
    StoreManifest,
)
from globeview.terrain.store.tile_store import TileStore

DATA = Path(__file__).resolve().parents[2] / "data"
SMALL = DATA / "craterlake-elev-16bit-30m.tif"


def _level(level: int, nx: int, ny: int, rng: np.random.Generator) -> LevelRecord:
    """A level summary over the whole level."""
    return LevelRecord(
        level=level,
        node_spacing_deg=180.0 / 2**level / 4,
        file=f"level_{level:02d}.vrt",
        sha256="ab" * 32,
        chunks=1 + level,
        tiles=nx * ny - 1,
        bytes=int(rng.integers(1000, 5000)),
        bbox=Extent(0, 0, nx, ny),
        level_error=float(rng.uniform(0.0, 5.0)),
        pole_heights=PoleHeights(north=12.5, south=None),
    )


def _manifest() -> StoreManifest:
    rng = np.random.default_rng(14)
    levels = (_level(0, 2, 1, rng), _level(1, 4, 2, rng))
    source = SourceRecord(
        path="/data/dem.tif",
        size=1234,
        sha256="cd" * 32,
        crs="EPSG:4326",
        bounds=(-180.0, -90.0, 180.0, 90.0),
        res_deg=(0.5, 0.5),
        vertical_datum="egm96",
        vertical_datum_source="assumed",
        heights="converted",
    )
    return StoreManifest(
        header=StoreHeader.current(),
        sources=(source,),
        params=IngestParams(tile_n=2, max_level=None, wavelet="bior2.2", crs=None, vdatum=None),
        tile_n=2,
        tile_size=5,
        chunk_tiles=256,
        wavelet="bior2.2",
        max_level=1,
        strides=STRIDES,
        bounds=(-180.0, -90.0, 180.0, 90.0),
        levels=levels,
        shards=ShardsRecord(
            roots=(), count=1, top=FileRef("meta/top-" + "12" * 8 + ".gvm", "12" * 32, 99)
        ),
        pole_heights=PoleHeights(north=12.5, south=None),
    )


def _text(m: StoreManifest) -> str:
    f = io.StringIO()
    m.write(f)
    return f.getvalue()


def test_round_trip_is_exact() -> None:
    m = _manifest()
    text = _text(m)
    back = StoreManifest.from_json(json.loads(text))
    assert _text(back) == text
    assert back.header == m.header and back.sources == m.sources and back.params == m.params
    assert back.levels == m.levels and back.shards == m.shards


def test_json_keys_are_the_field_names() -> None:
    """The schema's fields are the format: nothing else names a key."""
    raw = json.loads(_text(_manifest()))
    top = {f.name for f in fields(StoreManifest) if f.name != "header"}
    assert set(raw) == top | {f.name for f in fields(StoreHeader)}
    assert set(raw["levels"][0]) == {f.name for f in fields(LevelRecord)}
    assert set(raw["sources"][0]) == {f.name for f in fields(SourceRecord)}
    assert raw["format"] == STORE_FORMAT and raw["format_version"] == FORMAT_VERSION


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("schema") / "store"
    ingest([SMALL], out)
    return out


@pytest.mark.slow
def test_store_written_by_ingest_reads_back_to_the_same_bytes(store: Path) -> None:
    with TileStore.open(store) as ts:
        assert _text(ts.manifest) == (store / MANIFEST_NAME).read_text()
        assert ts.manifest.sources[0].vertical_datum in ("egm96", "ellipsoid")
        assert ts.manifest.sources[0].sha256 and ts.manifest.levels[-1].sha256
        assert ts.bounds == ts.manifest.bounds


def _rewrite(store: Path, tmp_path: Path, change) -> Path:
    s = tmp_path / "copy"
    shutil.copytree(store, s)
    raw = json.loads((s / MANIFEST_NAME).read_text())
    change(raw)
    (s / MANIFEST_NAME).write_text(json.dumps(raw))
    return s


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        (
            lambda m: m.update(format_version=FORMAT_VERSION + 1),
            f"version {FORMAT_VERSION + 1} is not supported",
        ),
        (lambda m: m.update(format_version=4), "format version 4 is not supported"),
        (lambda m: m.update(format_version="4"), "version 4 is not supported"),
        (lambda m: m.update(format_version=True), "version True is not supported"),
        (
            lambda m: m.update(format_version=float(FORMAT_VERSION)),  # == the int, not one
            f"format_version {float(FORMAT_VERSION)} is not supported",
        ),
        (lambda m: m.update(format_version=3), "built before vertical datums"),
        (lambda m: m["levels"][0]["bbox"].pop("nx"), "levels[0].bbox.nx is missing"),
        (lambda m: m["levels"][0]["bbox"].update(nx=3), "levels[0].bbox.nx must be in 1..2"),
        (lambda m: m["levels"][1].update(level_error="x"), "levels[1].level_error must be a"),
        (lambda m: m["sources"][0].update(size=1.5), "sources[0].size must be an integer"),
        (lambda m: m["sources"][0].update(vertical_datum="egm84"), "vertical_datum 'egm84'"),
        (lambda m: m["params"].pop("vdatum"), "params.vdatum is missing"),
        (lambda m: m.update(tile_size=66), "tile_size 66 is not 2^tile_n + 1"),
        (lambda m: m.update(chunk_tiles=8), "chunk_tiles 8 is not 16"),
        (lambda m: m["shards"].update(roots=[5]), "shards.roots"),
        (lambda m: m["shards"]["top"].update(file="../../etc/passwd"), "not a store file name"),
        (lambda m: m["shards"]["top"].update(sha256="x"), "shards.top.sha256"),
        (lambda m: m["levels"][2].update(chunks=-1), "levels[2].chunks must be in"),
        (lambda m: m.update(bounds=[0, 0, 1]), "bounds must be 4 numbers"),
        (lambda m: m["levels"][2].update(level_error=-1.0), "levels[2]: negative"),
        (lambda m: m["levels"][2].update(file="../x.tif"), "is not its level file"),
        (lambda m: m.update(levels=[[[[[[[]]]]]]]), "levels[0] must be an object"),
        (lambda m: m.update(format_version=6), "format version 6 (dense levels"),
        (lambda m: m.update(format_version=5), "rebuild it with globeview ingest --force"),
    ],
)
def test_malformed_or_other_version_is_one_store_error(
    store: Path, tmp_path: Path, change, needle: str
) -> None:
    s = _rewrite(store, tmp_path, change)
    with pytest.raises(StoreError) as exc:
        TileStore.open(s)
    msg = str(exc.value)
    assert needle in msg and "\n" not in msg and len(msg) < 400, msg


@pytest.mark.slow
def test_deeply_nested_json_is_one_error() -> None:
    raw = json.loads(_text(_manifest()))
    deep: list = []
    for _ in range(50_000):
        deep = [deep]
    raw["levels"][0]["bbox"] = deep
    with pytest.raises(ManifestError) as exc:
        StoreManifest.from_json(raw)
    assert "\n" not in str(exc.value)


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=20,
)


@settings(max_examples=200, deadline=None)
@given(
    path=st.lists(
        st.sampled_from(["levels", 0, 1, "bbox", "sources", "params", "x0", "shards", "top"])
    ),
    value=_json,
)
@pytest.mark.slow
def test_any_json_anywhere_is_refused_only_by_manifest_error(path: list, value: object) -> None:
    """Put an arbitrary JSON value at an arbitrary place: from_json accepts it or raises
    ManifestError, never anything else."""
    raw = json.loads(_text(_manifest()))
    node: object = raw
    for i, key in enumerate(path):
        in_dict = isinstance(node, dict) and isinstance(key, str) and key in node
        in_list = isinstance(node, list) and isinstance(key, int) and key < len(node)
        if not (in_dict or in_list):
            break
        if i == len(path) - 1:
            node[key] = value  # type: ignore[index]
        node = node[key]  # type: ignore[index]
    try:
        StoreManifest.from_json(raw)
    except ManifestError as exc:
        assert "\n" not in str(exc)  # noqa: PT017  a mutation may also be accepted
