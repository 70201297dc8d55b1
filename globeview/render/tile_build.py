"""Building terrain tiles for upload, many at a time (issue #27, item 2).

A tile's build is: its composed heights and, for its normals, the apron (one node of the
neighbours around it) or its data level's normals (`tile_normals`: tiles finer than their
data); the skirt depth from the stack's per-tile metadata; vertices and normals
(`tile_mesh`); then the texels the shaders sample (`colour_ramp`: albedo, coast codes). Each
step is a few dozen numpy calls on 65 x 65 arrays, so a tile built alone pays ~600 calls'
dispatch (most of its CPU, and all of it holding the GIL). `TileBuilder` builds a batch: the
metadata in one call per level, the meshes, normals and texels of the whole batch in one
pass (element by element what a tile alone computes: the same bits). The heights are still
composed tile by tile by the stack.

`TileBuilder` holds no GL: the renderer builds with it on its own thread (headless) or on
the loader's threads, and each process worker of `tile_workers` has one of its own.

Units: heights and skirts in metres, bounds in degrees, centres ECEF metres.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from globeview.geodesy import WGS84
from globeview.lod.block_strides import block_height_stats
from globeview.render.colour_ramp import tile_texels_batch
from globeview.render.heap import keep_freed_heap
from globeview.render.tile_mesh import TileMesh, build_tile_meshes
from globeview.render.tile_normals import DataLevelNormals
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.quadtree import tile_bounds_arrays

Key = tuple[int, int, int]


@dataclass
class ReadyTile:
    """A tile as the GPU takes it (`TilePool` writes these arrays into a slot as they are).

    Attributes:
        center: (3,) float64 ECEF metres of the tile's centre on the ellipsoid.
        vertices: (V, 6) float32 vertices relative to the centre (`tile_mesh` layout).
        albedo: (size, size, 4) uint8 RGBA: the ramp colour of each node, alpha the coast
            blend (`colour_ramp.tile_texels`).
        normal: (size, size, 4) uint8 RGBA: the unit ECEF normal as n * 127.5 + 127.5, alpha
            the node's coast code.
        coast_scale: metres of the coast codes' scale (`colour_ramp.coast_texels`).
        release: frees the memory the arrays live in (a shared-memory slot of a process
            worker) once uploaded; None when they are ordinary arrays.
        blocks: (64, 5) float64 per 8 x 8-cell block its height error at strides 2, 4, 8
            and min and max height (m, `lod.block_strides.block_height_stats`), or None
            (not measured: the tile is drawn by its index variant).
    """

    center: np.ndarray
    vertices: np.ndarray
    albedo: np.ndarray
    normal: np.ndarray
    coast_scale: float
    release: Callable[[], None] | None = field(default=None, repr=False, compare=False)
    blocks: np.ndarray | None = field(default=None, repr=False, compare=False)

    @classmethod
    def from_mesh(cls, mesh: TileMesh) -> ReadyTile:
        """The texels of one mesh baked (what an upload of a bare mesh does)."""
        (tile,) = bake([mesh])
        return tile


def bake(meshes: list[TileMesh]) -> list[ReadyTile]:
    """The upload form of ``meshes`` (all of one size): their albedo and normal texels baked
    in one pass over the batch."""
    if not meshes:
        return []
    heights = np.stack([m.heights for m in meshes])
    albedo, coast, scale = tile_texels_batch(heights)
    scaled = np.stack([m.normals for m in meshes])  # a copy: scaled in place below
    np.multiply(scaled, np.float32(127.5), out=scaled)
    scaled += np.float32(127.5)
    np.rint(scaled, out=scaled)  # unit normals: 0..255
    nrm8 = np.empty((*heights.shape, 4), dtype=np.uint8)
    nrm8[..., :3] = scaled
    nrm8[..., 3] = coast
    level_err = np.array([m.level_error for m in meshes])
    blocks = block_height_stats(heights, level_err) if heights.shape[1] == 65 else None
    return [
        ReadyTile(
            m.center,
            m.vertices,
            albedo[i],
            nrm8[i],
            float(scale[i]),
            blocks=None if blocks is None or not np.isfinite(level_err[i]) else blocks[i],
        )
        for i, m in enumerate(meshes)
    ]


class TileBuilder:
    """Builds the tiles of a terrain stack: meshes (`meshes`, `mesh`) and upload-ready tiles
    (`ready`). Thread-safe; caches (skirt depths, data-level normals) follow the stack's
    version.

    Args:
        terrain: the composed DEM layers.
    """

    def __init__(self, terrain: TerrainStack) -> None:
        keep_freed_heap()  # batches reuse their freed temporaries (`heap`)
        self.terrain = terrain
        self._data_normals = DataLevelNormals(terrain)
        # Skirt depths of one-tile builds ({key: depth} for one terrain version; bounded).
        self._skirt_cache: dict[Key, tuple[float, float]] = {}
        self._skirt_version = -1
        self._skirt_lock = threading.Lock()

    # -- skirts --------------------------------------------------------------------------------
    def skirt_depths(self, keys: np.ndarray) -> np.ndarray:
        """(N,) metres the skirts of tiles ``keys`` (N, 3) hang below their edges, from one
        vectorised metadata call per level (per tile it cost ~0.5 ms, more than the mesh)."""
        return self._tile_facts(keys)[0]

    def _tile_facts(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) skirt depths (`skirt_depths`) and (N,) level errors (m: the store's stride-1
        error of each tile, what its blocks' errors start from) of tiles ``keys``."""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        out = np.empty(len(keys))
        level_err = np.empty(len(keys))
        for level in np.unique(keys[:, 0]):
            rows = np.nonzero(keys[:, 0] == level)[0]
            meta = self.terrain.metadata(int(level), keys[rows, 1], keys[rows, 2])
            west, _, east, _ = tile_bounds_arrays(int(level), keys[rows, 1], keys[rows, 2])
            edge_m = np.radians(east - west) * WGS84.a
            # Skirts must reach below any neighbour drawn at another level or stride: a few
            # times this tile's coarsest height error plus a little of its size.
            out[rows] = 3.0 * np.nanmax(meta.stride_error, axis=1) + 0.01 * edge_m + 10.0
            # Down to the bottom of the tile's height range, which holds the bare ellipsoid
            # (`TileMetadata.hmin` <= 0): past a layer's data edge the surface drops to the
            # ellipsoid within a node spacing, and a neighbour of another level or without
            # data meets this tile's edge up to that whole wall lower (issue #25: background
            # showed between the raised land and the ground).
            wall = np.where(meta.covered, meta.hmax - np.minimum(meta.hmin, 0.0), 0.0)
            out[rows] = np.maximum(out[rows], np.nan_to_num(wall, nan=0.0) + 10.0)
            level_err[rows] = meta.stride_error[:, 0]
        return out, level_err

    def skirt_depth(self, key: Key) -> float:
        return self._one_tile_facts(key)[0]

    def _one_tile_facts(self, key: Key) -> tuple[float, float]:
        """`_tile_facts` of one tile, computed with its aligned 4 x 4 block and cached: one
        metadata call cost ~0.2 ms a tile (a fifth of a build), a call for the block ~0.3 ms,
        and one-tile builds come for neighbouring tiles together."""
        version = self.terrain.version
        with self._skirt_lock:
            if self._skirt_version != version:
                self._skirt_cache, self._skirt_version = {}, version
            hit = self._skirt_cache.get(key)
        if hit is not None:
            return hit
        level, x, y = key
        xs = (x & ~3) + np.arange(4)
        ys = (y & ~3) + np.arange(4)
        xs, ys = xs[xs < (2 << level)], ys[ys < (1 << level)]
        block = np.stack(
            [np.full(len(xs) * len(ys), level), np.tile(xs, len(ys)), np.repeat(ys, len(xs))],
            axis=1,
        )
        depths, errs = self._tile_facts(block)
        with self._skirt_lock:
            if self._skirt_version == version:
                if len(self._skirt_cache) > 1 << 16:
                    self._skirt_cache.clear()
                for k, d, e in zip(block.tolist(), depths.tolist(), errs.tolist(), strict=True):
                    self._skirt_cache[(k[0], k[1], k[2])] = (d, e)
        row = np.nonzero((block[:, 1] == x) & (block[:, 2] == y))[0]
        if not len(row):  # a key off the level's grid: as the batch path computes it
            one_d, one_e = self._tile_facts(np.array([key]))
            return float(one_d[0]), float(one_e[0])
        return float(depths[int(row[0])]), float(errs[int(row[0])])

    # -- meshes --------------------------------------------------------------------------------
    def mesh(self, key: Key) -> TileMesh:
        """One tile's mesh (skirt depth from its cached 4 x 4 block)."""
        key = (int(key[0]), int(key[1]), int(key[2]))
        depth, err = self._one_tile_facts(key)
        return self._meshes([key], np.array([depth]), np.array([err]))[0]

    def meshes(self, keys: np.ndarray) -> dict[Key, TileMesh]:
        """Meshes of tiles ``keys`` (N, 3), by key tuple in the keys' order: the metadata in
        one call per level, the heights per tile, the meshes in one batch."""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        tuples = [(k[0], k[1], k[2]) for k in keys.tolist()]
        if not tuples:
            return {}
        depths, errs = self._tile_facts(keys)
        return dict(zip(tuples, self._meshes(tuples, depths, errs), strict=True))

    def ready(self, keys: np.ndarray) -> dict[Key, ReadyTile]:
        """Upload-ready tiles of ``keys`` (N, 3): `meshes` with their texels baked."""
        meshes = self.meshes(keys)
        return dict(zip(meshes, bake(list(meshes.values())), strict=True))

    def _meshes(self, keys: list[Key], skirts: np.ndarray, level_err: np.ndarray) -> list[TileMesh]:
        """The meshes of ``keys`` with skirt depths ``skirts`` (m) and level errors
        ``level_err`` (m, `_tile_facts`), in one batch.

        A tile finer than its data shades with its data level's normals, interpolated
        (`tile_normals`: its own would draw the bilinear surface's creases, a lattice).
        Otherwise the apron (one node of the same-level neighbours around the tile) makes
        edge normals equal on both sides of a tile edge: no shading seams (issue #16)."""
        terrain = self.terrain
        size = terrain.tile_size
        heights = np.empty((len(keys), size, size), dtype=np.float32)
        aprons = np.zeros((len(keys), size + 2, size + 2), dtype=np.float32)
        normals = self._data_normals.normals_many(keys)
        for i, key in enumerate(keys):
            heights[i] = terrain.heights(key)
            if normals[i] is None:
                aprons[i] = terrain.heights_apron(key)
        karr = np.array(keys, dtype=np.int64)
        bounds = np.empty((len(keys), 4))
        for level in np.unique(karr[:, 0]):
            rows = np.nonzero(karr[:, 0] == level)[0]
            bounds[rows] = np.stack(
                tile_bounds_arrays(int(level), karr[rows, 1], karr[rows, 2]), axis=1
            )
        meshes = build_tile_meshes(bounds, heights, skirts, apron=aprons, normals=normals)
        return [replace(m, level_error=float(e)) for m, e in zip(meshes, level_err, strict=True)]
