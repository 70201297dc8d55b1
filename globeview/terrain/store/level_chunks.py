"""Writing a level's chunk files and the GDAL VRT that mosaics them (store format 5).

A level raster (see `globeview.terrain.levels`) is split into chunks of C x C node intervals
(C = `schema.chunk_nodes_for`): chunk (cy, cx) holds raster rows [cy*C, (cy+1)*C) and
columns [cx*C, (cx+1)*C), clipped to the raster, and the last chunk row/column also holds
the raster's last row/column. Each chunk is a tiled GeoTIFF at its own position (readable
alone by GDAL, range-readable over HTTP); ``level_LL.vrt`` places them with relative paths,
so ``gdalinfo store/level_05.vrt`` and QGIS open the whole level, and areas without a chunk
(all-NaN chunks are not written) read as NaN (the VRT's NoDataValue).

The VRT text is built here, not by GDAL: it is deterministic (its sha256 is in the
manifest), names its sources relative to itself, and records each source's size and block
shape so opening the VRT opens no chunk file.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np
from affine import Affine
from rasterio.io import MemoryFile

from globeview.terrain.levels import LevelGrid
from globeview.terrain.store.schema import chunk_file_name, chunk_grid_shape

__all__ = ["chunk_window", "file_sha256", "write_chunk", "write_level_vrt"]

BLOCK = 256  # GeoTIFF block side of chunk files (and of the VRT band)


def chunk_window(grid: LevelGrid, chunk_nodes: int, cy: int, cx: int) -> tuple[int, int, int, int]:
    """(row0, col0, height, width) in raster nodes of chunk (cy, cx)."""
    rows, cols = chunk_grid_shape(grid, chunk_nodes)
    r0, c0 = cy * chunk_nodes, cx * chunk_nodes
    r1 = grid.height if cy == rows - 1 else r0 + chunk_nodes
    c1 = grid.width if cx == cols - 1 else c0 + chunk_nodes
    return r0, c0, r1 - r0, c1 - c0


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
    grid: LevelGrid,
    chunk_nodes: int,
    cy: int,
    cx: int,
    values: np.ndarray,
    threads: str = "ALL_CPUS",
) -> str | None:
    """Write chunk (cy, cx) of a level (``values``: its nodes, float32, the shape of
    `chunk_window`); returns its sha256, or None (no file) when every node is NaN.

    ``threads``: GDAL's compression threads ("ALL_CPUS" for one writer; "1" where many
    tasks write at once).
    """
    r0, c0, h, w = chunk_window(grid, chunk_nodes, cy, cx)
    if values.shape != (h, w):
        raise ValueError(f"chunk {cy},{cx} of level {grid.level}: shape {values.shape} != {h, w}")
    if np.isnan(values).all():
        return None
    path = folder / chunk_file_name(grid.level, cy, cx)
    transform = grid.transform @ Affine.translation(c0, r0)
    # Encoded in memory and hashed there, then written: the sha256 of the bytes written,
    # without reading the file back.
    with MemoryFile() as mem:
        with mem.open(**_profile(w, h, transform, threads)) as dst:
            dst.update_tags(AREA_OR_POINT="Point")
            dst.update_tags(1, LEVEL=str(grid.level), TILE_N=str(grid.tile_n))
            dst.write(values, 1)
        data = mem.read()
    # A new inode, never a rewrite in place: an incremental update hard-links the chunks it
    # keeps from the old store, whose files must not change.
    path.unlink(missing_ok=True)
    with path.open("xb") as f:
        f.write(data)
    return hashlib.sha256(data).hexdigest()


def write_level_vrt(
    path: Path, grid: LevelGrid, chunk_nodes: int, chunks: Sequence[tuple[int, int]]
) -> str:
    """Write the VRT of a level whose chunk files ``chunks`` ((cy, cx), row-major) exist
    next to it; returns the VRT's sha256."""
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
    for cy, cx in chunks:
        r0, c0, h, w = chunk_window(grid, chunk_nodes, cy, cx)
        name = escape(chunk_file_name(grid.level, cy, cx))
        parts += [
            "    <SimpleSource>",
            f'      <SourceFilename relativeToVRT="1">{name}</SourceFilename>',
            "      <SourceBand>1</SourceBand>",
            f'      <SourceProperties RasterXSize="{w}" RasterYSize="{h}" DataType="Float32" '
            f'BlockXSize="{BLOCK}" BlockYSize="{BLOCK}" />',
            f'      <SrcRect xOff="0" yOff="0" xSize="{w}" ySize="{h}" />',
            f'      <DstRect xOff="{c0}" yOff="{r0}" xSize="{w}" ySize="{h}" />',
            "    </SimpleSource>",
        ]
    parts += ["  </VRTRasterBand>", "</VRTDataset>", ""]
    path.write_text("\n".join(parts), encoding="utf-8")
    return file_sha256(path)
