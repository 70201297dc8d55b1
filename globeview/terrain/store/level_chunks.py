"""Writing a level's chunk files and the GDAL VRT that mosaics them (store format 7).

A level's global node grid (see `globeview.terrain.store.layout`) is split into chunks of
C x C node intervals fixed by the quadtree: chunk (cy, cx) stores global node rows
[cy*C, (cy+1)*C) and columns [cx*C, (cx+1)*C) (`layout.chunk_window`: the last chunk row also
the south pole row; column W, one turn east, is column 0 and never stored). Each chunk is a
tiled GeoTIFF at its own position (readable alone by GDAL, range-readable over HTTP), named by
its content (``chunks/LL/<cy>/<cx>-<h16>.tif``) and written atomically (a temporary name in its
folder, then `os.replace`); ``level_LL.vrt`` places them over the level's bbox with relative
paths, so ``gdalinfo store/level_05.vrt`` and QGIS open the whole level, and areas without a
chunk (no data) read as NaN (the VRT's NoDataValue).

The VRT text is built here, not by GDAL: it is deterministic (its sha256 is in the
manifest), names its sources relative to itself, and records each source's size and block
shape so opening the VRT opens no chunk file.
"""

from __future__ import annotations

import hashlib
import os
import uuid
from collections.abc import Sequence
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np
from affine import Affine
from rasterio.io import MemoryFile

from globeview.terrain.levels import LevelGrid
from globeview.terrain.store.layout import EXTRA_COL, EXTRA_ROW, chunk_file_name, chunk_window

__all__ = ["file_sha256", "write_atomic", "write_chunk", "write_level_vrt"]

BLOCK = 256  # GeoTIFF block side of chunk files (and of the VRT band)


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _profile(width: int, height: int, transform: Affine, threads: str) -> dict:
    return {
        "driver": "GTiff",
        "dtype": "float32",
        "count": 1,
        "width": width,
        "height": height,
        "crs": "EPSG:4326",
        "transform": transform,
        "nodata": float("nan"),
        "tiled": True,
        "blockxsize": BLOCK,
        "blockysize": BLOCK,
        # ZSTD level 1 with the floating-point predictor (issue #25 C5): on a 1024^2 chunk of
        # the 8192^2 benchmark store 33 vs 39-48 ms to write, 11-13 vs 18 ms to read, 2.39 vs
        # 2.44 MB, against DEFLATE level 1 (CPU, load 2.3). Writing and reading chunks is
        # the ingest's largest cost once reprojection and errors are fast; GDAL reads both,
        # so stores written with DEFLATE before stay readable. (Without the predictor: 16-20
        # ms to write, 9 ms to read, but 3.50 MB: +46 %; C8 in docs/benchmarks.md.)
        "compress": "zstd",
        "predictor": 3,
        "zstd_level": 1,
        "num_threads": threads,
        "bigtiff": "IF_SAFER",
    }


def write_chunk(
    folder: Path,
    level: int,
    tile_n: int,
    cy: int,
    cx: int,
    values: np.ndarray,
    threads: str = "ALL_CPUS",
    flags: int = 0,
) -> tuple[str, int] | None:
    """Write chunk (cy, cx) of a level (``values``: its stored nodes, float32, the shape of
    `layout.chunk_window`) under its content name; returns (sha256, bytes), or None (no
    file) when every node is NaN.

    ``threads``: GDAL's compression threads ("ALL_CPUS" for one writer; "1" where many
    tasks write at once); ``flags``: `layout.EXTRA_ROW` / `EXTRA_COL` (it stores its closing
    row / column).
    """
    gr0, gc0, h, w = chunk_window(
        level, tile_n, cy, cx, bool(flags & EXTRA_ROW), bool(flags & EXTRA_COL)
    )
    if values.shape != (h, w):
        raise ValueError(f"chunk {level}/{cy}/{cx}: shape {values.shape} != {h, w}")
    if np.isnan(values).all():
        return None
    grid = LevelGrid(level, tile_n, 0, 0, 1 << (level + 1), 1 << level)
    transform = grid.transform @ Affine.translation(gc0, gr0)
    # Encoded in memory and hashed there, then written: the sha256 of the bytes written,
    # without reading the file back.
    with MemoryFile() as mem:
        with mem.open(**_profile(w, h, transform, threads)) as dst:
            dst.update_tags(AREA_OR_POINT="Point")
            dst.update_tags(1, LEVEL=str(level), TILE_N=str(tile_n))
            dst.write(values, 1)
        data = mem.read()
    sha = hashlib.sha256(data).hexdigest()
    write_atomic(folder / chunk_file_name(level, cy, cx, sha), data)
    return sha, len(data)


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary name in its folder and `os.replace`: a
    reader never sees a half-written file, and a content-named file rewritten by a retried
    task (the same bytes) replaces its twin harmlessly (always a new inode: an incremental
    update hard-links the files it keeps from the old store, which must not change)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp-{uuid.uuid4().hex[:12]}")
    try:
        with tmp.open("xb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_level_vrt(
    path: Path, grid: LevelGrid, chunks: Sequence[tuple[int, int, str, int]]
) -> str:
    """Write the VRT of a level over ``grid`` (its bbox) whose chunk files ``chunks``
    ((cy, cx, file name relative to the store, `layout.EXTRA_ROW` | `EXTRA_COL` flags),
    row-major) exist beside it; returns the
    VRT's sha256. On a bbox all the way round, the chunks of column 0 are placed again as
    the raster's last column (lon +180)."""
    t = grid.transform
    gt = ", ".join(repr(float(v)) for v in (t.c, t.a, t.b, t.f, t.d, t.e))
    parts = [
        f'<VRTDataset rasterXSize="{grid.width}" rasterYSize="{grid.height}">',
        "  <SRS>EPSG:4326</SRS>",
        f"  <GeoTransform>{gt}</GeoTransform>",
        '  <Metadata><MDI key="AREA_OR_POINT">Point</MDI></Metadata>',
        f'  <VRTRasterBand dataType="Float32" band="1" blockXSize="{BLOCK}" blockYSize="{BLOCK}">',
        "    <NoDataValue>nan</NoDataValue>",
        f'    <Metadata><MDI key="LEVEL">{grid.level}</MDI>'
        f'<MDI key="TILE_N">{grid.tile_n}</MDI></Metadata>',
    ]
    turn = grid.ncols * grid.tile_nodes
    for cy, cx, name, flags in chunks:
        gr0, gc0, h, w = chunk_window(
            grid.level, grid.tile_n, cy, cx, bool(flags & EXTRA_ROW), bool(flags & EXTRA_COL)
        )
        r0, c0 = gr0 - grid.gr0, (gc0 - grid.gc0) % turn
        places = [(c0, 0, w)]
        if grid.global_lon and gc0 == 0:
            places.append((turn, 0, 1))  # column W repeats column 0
        for dst_c, src_c, width in places:
            if r0 < 0 or r0 + h > grid.height or dst_c + width > grid.width:
                continue  # outside the bbox (never, for a bbox of the level's chunks)
            parts += [
                "    <SimpleSource>",
                f'      <SourceFilename relativeToVRT="1">{escape(name)}</SourceFilename>',
                "      <SourceBand>1</SourceBand>",
                f'      <SourceProperties RasterXSize="{w}" RasterYSize="{h}" DataType="Float32" '
                f'BlockXSize="{BLOCK}" BlockYSize="{BLOCK}" />',
                f'      <SrcRect xOff="{src_c}" yOff="0" xSize="{width}" ySize="{h}" />',
                f'      <DstRect xOff="{dst_c}" yOff="{r0}" xSize="{width}" ySize="{h}" />',
                "    </SimpleSource>",
            ]
    parts += ["  </VRTRasterBand>", "</VRTDataset>", ""]
    write_atomic(path, "\n".join(parts).encode("utf-8"))
    return file_sha256(path)
