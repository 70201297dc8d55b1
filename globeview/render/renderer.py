"""`GlobeRenderer`: draws a render set of terrain tiles into any moderngl framebuffer.

The same code draws into the Qt widget's framebuffer and into an offscreen one from an EGL
standalone context (tests, `globeview render`, benchmarks).

One frame is one multi-draw call: every resident tile lives in a slot of the shared vertex
buffer and texture arrays (tile_pool.py); per draw, an instanced attribute carries the tile's
centre relative to the eye (computed in float64 on the CPU, then rounded to float32: the
relative-to-centre scheme), its texture-array layer and its coast scale (tile_pool.py); a
per-frame indirect command buffer (count, first index, base vertex, base instance) is built
with numpy. No GL object is created per frame in steady state.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import moderngl
import numpy as np

from globeview.geodesy import WGS84, ecef_to_lonlat
from globeview.lod.block_strides import WHOLE_FROM, choose_block_strides
from globeview.lod.render_set import (
    FrameStats,
    RenderSet,
    clean_provider_stats,
    level_histogram,
)
from globeview.lod.stitching import plain_stride_idx, stitch_tile_edges
from globeview.lod.tile_indices import IndexVariant
from globeview.lod.view_state import INV_AXES2, ViewState
from globeview.model.display import DisplaySettings
from globeview.render.colour_ramp import coast_ramp
from globeview.render.gpu_objects import gpu_objects
from globeview.render.overlay_imagery import OverlaySet  # overlays:
from globeview.render.shader_source import build_shader, explain_sources
from globeview.render.tile_build import ReadyTile, TileBuilder, bake
from globeview.render.tile_loader import (
    BytesWarmer,
    TileLoader,
    coarse_standins,
    substitute_missing,
    tile_priority,
)
from globeview.render.tile_mesh import FLOATS_PER_VERTEX, TileMesh
from globeview.render.tile_pool import IndexPool, TilePool, key_codes
from globeview.render.tile_workers import ProcessBuilder, TerrainRecipe, default_loader
from globeview.terrain.compose.stack import TerrainStack
from globeview.terrain.quadtree import tile_bounds

#: Pixels that tile edges reach past their neighbours' (the terrain shader's
#: ``gv_edge_push``): edges stitched without skirts overlap instead of leaving float32
#: rounding slivers between them.
EDGE_PUSH_PX = 0.05
#: Loader threads when a visible layer is remote (`GlobeRenderer.load_workers`): four builds
#: overlap four round trips (issue #25 item 4); at most the store's `max_requests`.
REMOTE_LOAD_WORKERS = 4


@dataclass
class DisplacementHook:
    """GLSL a tool plugin injects into the terrain vertex shader (see docs/plugins.md).

    ``glsl`` defines ``vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 center_rel)`` that
    returns the displaced eye-relative position; it replaces the identity chunk
    shaders/displace.glsl, verbatim. Its ``gv_u_*`` uniforms come with each frame
    (`draw_terrain`'s ``uniforms``: the tool's `displacement_uniforms`), not stored here.
    """

    owner: str
    glsl: str


class GlobeRenderer:
    """Draws terrain tiles of a `TerrainStack`.

    Args:
        ctx: the moderngl context (EGL standalone or the Qt widget's).
        terrain: the composed DEM layers.
        capacity: tiles resident on the GPU at once (also the max tiles per frame).
    """

    def __init__(self, ctx: moderngl.Context, terrain: TerrainStack, capacity: int = 768) -> None:
        self.ctx = ctx
        self.terrain = terrain
        self.settings = DisplaySettings()
        self.size = terrain.tile_size
        self.pool = TilePool(ctx, self.size, capacity)
        self.indices = IndexPool(ctx, self.size)
        self.indices.on_realloc = self._build_vao
        # The last frame's block strides (`block_strides`): CPU ms of the choice, tiles.
        self.last_block_ms = 0.0
        self.last_block_tiles = 0
        self.last_blocks: np.ndarray | None = None  # the last frame's, when any tile had them
        self._terrain_version = terrain.version
        self.builder = TileBuilder(terrain)
        self._hook: DisplacementHook | None = None
        # imagery, hillshade, fog, tilt, wireframe (TERRAIN_FEATURES)
        self._features = (False, False, True, False, False)
        self.program = self._compile(None, self._features)
        self.instances = gpu_objects(ctx).buffer(reserve=capacity * 9 * 4, dynamic=True)
        self.commands = gpu_objects(ctx).buffer(reserve=capacity * 5 * 4, dynamic=True)
        # Providers that triangulate each tile themselves (quadtree-clod) write their indices
        # here every frame; the buffer only grows (rarely), it is never created per frame.
        self.custom_ibo = gpu_objects(ctx).buffer(reserve=1 << 22, dynamic=True)
        self.custom_commands = gpu_objects(ctx).buffer(reserve=capacity * 5 * 4, dynamic=True)
        self.vao, self.custom_vao = self._make_vaos(self.program)
        self._variants = {self._features: (self.program, self.vao, self.custom_vao)}
        self.last_view: ViewState | None = None
        #: The render set the last frame drew (`load`'s: stand-ins included), or None.
        self.last_drawn: RenderSet | None = None
        self._draw_thread: int | None = None  # the thread that ran `load` last
        self._warmer: BytesWarmer | None = None  # remote layers' byte prefetch (`_warm`)
        # Interactive use (the window) loads tiles on worker threads and uploads at most
        # upload_budget per frame; headless renders load everything before drawing.
        self.async_loading = False
        # Uploading a finished tile is a few buffer writes (~0.1 ms): a frame takes every
        # finished tile up to this many, so a view completes in few frames (it was 12, which
        # made a 355-tile view wait ~30 frames after its tiles were built).
        self.upload_budget = 256
        # Background builds (`default_loader`): on 2 cores one thread (the build is
        # GIL-bound: one thread built 355 tiles in 0.47 s, two in 0.92 s, and two also took
        # GIL time from the frames: White Mountains Go to -> complete 0.90-0.98 s with one,
        # 1.05-1.33 s with two; benchmarks/bench_goto.py --workers, load 2.2-2.6); with more
        # cores worker processes, all but two cores (render/tile_workers.py).
        # A visible remote layer gets `REMOTE_LOAD_WORKERS` threads instead (`load_workers`).
        self.load_kind, self._base_workers = default_loader()
        #: Workers set by hand (a benchmark, a test); None: chosen by `load_workers`.
        self._workers_set: int | None = None
        # Tiles per background build call (one metadata call and one vectorised pass per
        # batch); small, so the nearest tiles come back first.
        self.load_batch = 4 if self.load_kind == "thread" else 8
        self.loader: TileLoader | None = None
        #: Called on a worker thread when a background tile finished (the window schedules a
        #: frame through it); None: nothing is told.
        self.on_tile_ready: Callable[[], None] | None = None
        # overlays: imagery drape (texture array parallel to the pool), vectors, point objects.
        self.overlays = OverlaySet(ctx, capacity)
        # psygnal holds the bound method weakly: the stack does not keep the renderer alive.
        terrain.changed.connect(self._terrain_changed)

    # -- shader program and displacement hooks --------------------------------------------
    # The terrain shaders' optional parts (imagery drape, hillshade, fog, the exaggeration
    # tilt, the hook's shade factor) are compiled in or out with #defines rather than switched
    # by uniforms: llvmpipe shades a 4x4 block for both sides of a uniform branch, so a
    # disabled drape still cost its texture fetch (about a third of a full-screen frame).
    # Variants are compiled on first use and kept (`_use_features`).
    def _compile(
        self, hook: DisplacementHook | None, features: tuple[bool, ...]
    ) -> moderngl.Program:
        # The hook's text replaces the identity chunk displace.glsl (shaders/terrain.vert).
        replace = {"displace.glsl": hook.glsl} if hook is not None else None
        defines = terrain_defines(features, hook is not None)
        vert = build_shader("terrain.vert", replace=replace, defines=defines)
        frag = build_shader("terrain.frag", defines=defines)
        try:
            return gpu_objects(self.ctx).program(vertex_shader=vert.text, fragment_shader=frag.text)
        except moderngl.Error as exc:  # say which piece (a hook: its own line numbers) failed,
            # first: reports of a plugin's failure keep only the first 300 characters.
            where = explain_sources(str(exc), vertex=vert, fragment=frag)
            raise moderngl.Error(f"[{where}] {exc}") from exc

    def _use_features(self, features: tuple[bool, ...]) -> None:
        if features == self._features:
            return
        cached = self._variants.get(features)
        if cached is None:
            program = self._compile(self._hook, features)
            cached = (program, *self._make_vaos(program))
            self._variants[features] = cached
        self.program, self.vao, self.custom_vao = cached
        self._features = features

    @property
    def displacement_hook(self) -> DisplacementHook | None:
        """The displacement hook compiled into the terrain program, or None (read-only:
        install one with `set_displacement_hook`)."""
        return self._hook

    def set_displacement_hook(self, hook: DisplacementHook | None) -> None:
        """Install (or remove, with None) a vertex displacement hook. Raises
        moderngl.Error if the hook's GLSL does not compile (naming the piece and line), or
        ShaderSourceError if the loader refuses its text; the previous program stays."""
        program = self._compile(hook, self._features)
        self._release_variants()
        self._hook = hook
        self.program = program
        self.vao, self.custom_vao = self._make_vaos(program)
        self._variants = {self._features: (self.program, self.vao, self.custom_vao)}

    def _release_variants(self) -> None:
        for program, vao, custom_vao in self._variants.values():
            vao.release()
            custom_vao.release()
            program.release()
        self._variants = {}

    def _make_vaos(self, program: moderngl.Program):
        content = [
            (self.pool.vbo, "3f 1f 2f", "in_pos", "in_h", "in_uv"),
            (
                self.instances,
                "3f 3f 1f 1f 1f/i",
                "in_center_rel",
                "in_center",
                "in_layer",
                "in_coast_scale",
                "in_edge_push",
            ),
        ]
        # skip_errors: a shader variant may not use every attribute.
        vao = gpu_objects(self.ctx).vertex_array(
            program,
            content,
            index_buffer=self.indices.buffer,
            index_element_size=4,
            skip_errors=True,
        )
        custom_vao = gpu_objects(self.ctx).vertex_array(
            program,
            content,
            index_buffer=self.custom_ibo,
            index_element_size=4,
            skip_errors=True,
        )
        return vao, custom_vao

    def _build_vao(self) -> None:
        """Rebuild the vertex arrays after an index buffer was reallocated."""
        for key, (program, vao, custom_vao) in list(self._variants.items()):
            vao.release()
            custom_vao.release()
            self._variants[key] = (program, *self._make_vaos(program))
        self.program, self.vao, self.custom_vao = self._variants[self._features]

    def _write_custom_indices(self, idx: np.ndarray) -> None:
        data = idx.astype(np.uint32).tobytes()
        if len(data) > self.custom_ibo.size:
            self.custom_ibo.release()
            self.custom_ibo = gpu_objects(self.ctx).buffer(reserve=2 * len(data), dynamic=True)
            self._build_vao()
        self.custom_ibo.write(data)

    # -- tile loading ----------------------------------------------------------------------
    # Building tiles is `TileBuilder`'s (render/tile_build.py, no GL): these are its entries.
    def build_mesh(self, key: tuple[int, int, int]) -> TileMesh:
        """Build one tile's mesh (thread-safe)."""
        return self.builder.mesh(key)

    def skirt_depths(self, keys: np.ndarray) -> np.ndarray:
        """(N,) metres the skirts of tiles ``keys`` (N, 3) hang below their edges."""
        return self.builder.skirt_depths(keys)

    def build_meshes(self, keys: np.ndarray) -> dict[tuple[int, int, int], TileMesh]:
        """Meshes of tiles ``keys`` (N, 3), by key tuple, built in one batch."""
        return self.builder.meshes(keys)

    # The background threads' builds: meshes with their texels baked there, off the render
    # thread (through build_mesh/build_meshes, which tests may slow down).
    def _build_ready(self, key: tuple[int, int, int]) -> ReadyTile:
        return ReadyTile.from_mesh(self.build_mesh(key))

    def _build_ready_many(self, keys: np.ndarray) -> dict[tuple[int, int, int], ReadyTile]:
        meshes = self.build_meshes(keys)
        return dict(zip(meshes, bake(list(meshes.values())), strict=True))

    @property
    def load_workers(self) -> int:
        """Background build workers: set by hand, else `default_loader`'s; with threads and
        a visible layer read over a network (`TileStore.is_remote`), `REMOTE_LOAD_WORKERS`
        (at most the store's `max_requests`), so builds overlap their round trips: a build
        waits a round trip (20 ms on a far server) for each run of chunk pages it lacks, with
        the GIL released."""
        if self._workers_set is not None:
            return self._workers_set
        if self.load_kind != "thread":
            return self._base_workers
        return max(self._base_workers, remote_workers(self.terrain))

    @load_workers.setter
    def load_workers(self, workers: int | None) -> None:
        self._workers_set = None if workers is None else int(workers)

    def _check_terrain_version(self) -> None:
        if self.terrain.version != self._terrain_version:
            # Retired, not forgotten: the window draws the old tiles where the new layers'
            # have not loaded yet (`_load_async`) instead of a blank view.
            self.pool.retire()
            if self.loader is not None:
                if self.loader.processes is not None:
                    # The workers opened the old layers: new ones for the new recipe.
                    self.loader.shutdown()
                    self.loader = None
                elif self.loader.workers != self.load_workers:
                    # A remote layer came, went or was hidden (`load_workers`): a new loader;
                    # the old threads end after the build under way (its result dropped),
                    # not waited for here (a build may be waiting on a slow server).
                    self.loader.shutdown(timeout_s=0.0)
                    self.loader = None
                else:
                    self.loader.cancel_all()
            self._terrain_version = self.terrain.version

    def _terrain_changed(self) -> None:
        """The layers changed (`TerrainStack.changed`, on the thread that changed them). On
        the thread that draws, with tiles loading in the background: retire the pool's
        tiles and ask at once for the coarse stand-ins of the view last drawn
        (`coarse_standins`), so they build while the next frame selects its tiles (the first
        selection over a new layer reads its metadata: seconds over a network at load)."""
        last = self.last_drawn
        if not self.async_loading or last is None or not len(last.keys):
            return
        if threading.get_ident() != self._draw_thread:
            return  # another thread's change: the next frame sees it (`load`)
        self._check_terrain_version()
        ahead = coarse_standins(last.keys, lambda k: self.pool.slots_of(k) >= 0)
        if len(ahead) and len(last) + len(ahead) <= self.pool.capacity:
            # No byte prefetch here: the loader's threads read the few stand-ins' bytes
            # themselves, and starting the prefetch's threads (~0.4 s at load 20) would hold
            # up the frame; the frame's `_load_async` hands it the view's tiles.
            self._ensure_loader().request(np.empty((0, 3), np.int64), ahead=ahead)

    def ensure_resident(self, keys: np.ndarray) -> int:
        """Upload the tiles of ``keys`` that are not on the GPU yet; returns how many."""
        self._check_terrain_version()
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        missing = np.unique(keys[self.pool.slots_of(keys) < 0], axis=0)
        if not len(missing):
            return 0
        return self.pool.load(keys, self._build_ready_many(missing).__getitem__)

    def _tile_ready(self) -> None:
        callback = self.on_tile_ready
        if callback is not None:
            callback()

    def _ensure_loader(self) -> TileLoader:
        if self.loader is None:
            # Batches through `build_meshes` where the renderer has it (one metadata call per
            # level for the batch instead of one per tile).
            if self.load_kind == "process":
                procs = ProcessBuilder(
                    TerrainRecipe.of(self.terrain),
                    self.load_workers,
                    fallback=self._build_ready_many,  # workers that cannot open the terrain
                )
                self.loader = TileLoader(
                    procs.build,
                    workers=self.load_workers,
                    on_ready=self._tile_ready,
                    build_many=procs.build_many,
                    batch=self.load_batch,
                    processes=procs,
                )
            else:
                self.loader = TileLoader(
                    self._build_ready,
                    workers=self.load_workers,
                    on_ready=self._tile_ready,
                    build_many=self._build_ready_many,
                    batch=self.load_batch,
                )
        return self.loader

    def _load_async(
        self, render_set: RenderSet, extra: dict[str, float] | None = None
    ) -> tuple[RenderSet, int, int]:
        """Upload the finished tiles (up to ``upload_budget``), stand in ancestors for the
        missing ones (resident ones, else the retired tiles of the layers before a change:
        the view is never blanked by a layer change) and queue them nearest the eye first,
        after a few coarse ancestors where the view has none (`coarse_standins`: see
        tile_loader.py). Returns the render set to draw, tiles uploaded, tiles loading;
        ``extra`` (the frame's ``FrameStats.extra``) gets ``upload_ms`` (wall milliseconds of
        the uploads), ``tiles_missing`` (tiles of the set not resident), ``tiles_standin``
        (ancestors drawn for them), ``tiles_stale`` (retired tiles among those drawn),
        ``tiles_ahead`` (coarse ancestors queued before the view's tiles) and
        ``tiles_failed`` (missing tiles whose build failed: they stay stood in until the
        layers change)."""
        self._check_terrain_version()
        loader = self._ensure_loader()
        t_upload = time.perf_counter()
        ready = loader.take_ready(self.upload_budget)
        if ready:
            meshes = dict(ready)
            ready_keys = np.array([k for k, _ in ready], dtype=np.int64)
            # partial: near the pool's capacity, finished tiles that do not fit wait (they
            # are requested again) rather than failing the frame.
            self.pool.load(ready_keys, meshes.__getitem__, protect=render_set.keys, partial=True)
        upload_ms = (time.perf_counter() - t_upload) * 1e3
        pool = self.pool

        def resident(keys: np.ndarray) -> np.ndarray:
            return pool.slots_of(keys) >= 0

        def stale(keys: np.ndarray) -> np.ndarray:
            return pool.stale_slots_of(keys) >= 0

        drawn, missing = substitute_missing(
            render_set, resident, stale if pool.stale_count else None
        )
        if not len(missing):
            pool.forget_stale()  # the view is the new layers' own: the old tiles are done
        # Nearest first, from the last frame's eye (this frame's view is made after loading);
        # the first frame has none: coarse first.
        eye = None if self.last_view is None else self.last_view.eye
        priority = None if eye is None or not len(missing) else tile_priority(missing, eye)
        missing_keys, priority, n_failed = self._with_failed_ancestors(loader, missing, priority)
        # A view whose tiles have no resident ancestor near them (a layer added, a jump):
        # a few coarse ancestors first, drawn while the view's own tiles load.
        ahead = coarse_standins(missing, resident)
        if len(render_set) + len(ahead) > pool.capacity:
            ahead = ahead[:0]  # no room: they would push out the view's own tiles
        loader.request(missing_keys, priority, ahead=ahead)
        if len(missing_keys):
            # Remote layers: the missing tiles' bytes, several requests at once (the loader
            # builds one tile at a time), the stand-ins first, then nearest first.
            order = np.argsort(priority, kind="stable") if priority is not None else slice(None)
            self._warm(np.concatenate([ahead, missing_keys[order]]))
        if extra is not None:
            extra["upload_ms"] = upload_ms
            extra["tiles_missing"] = len(missing)
            # Stand-ins: drawn tiles the provider did not ask for (ancestors).
            asked = key_codes(render_set.keys)
            extra["tiles_standin"] = int(np.count_nonzero(~np.isin(key_codes(drawn.keys), asked)))
            extra["tiles_stale"] = int(np.count_nonzero(pool.slots_of(drawn.keys) < 0))
            extra["tiles_ahead"] = len(ahead)
            extra["tiles_failed"] = n_failed
        return drawn, len(ready), loader.pending

    def _warm(self, keys: np.ndarray) -> None:
        """Hand ``keys`` (N, 3) to the terrain's byte prefetch (`TerrainStack.prefetch_bytes`)
        on the `BytesWarmer`'s thread, made when a visible layer is remote."""
        warm = getattr(self.terrain, "prefetch_bytes", None)  # (a TerrainStack's)
        if warm is None:
            return
        if self._warmer is None:
            if not any(ly.store.is_remote for ly in self.terrain.visible_layers):
                return  # nothing to prefetch: no thread
            self._warmer = BytesWarmer(warm)
        self._warmer.submit(keys)

    def _with_failed_ancestors(
        self, loader: TileLoader, missing: np.ndarray, priority: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None, int]:
        """The tiles to request for ``missing`` (with their ``priority``), and how many of
        them failed: a tile that cannot be built would stay a hole where no ancestor is
        resident, so its nearest ancestor that has not failed is asked for too (a loop over
        the few failed tiles, not over the frame's)."""
        failed = loader.failed
        bad = [tuple(k) for k in missing.tolist() if tuple(k) in failed] if failed else []
        if not bad:
            return missing, priority, 0
        up = set()
        for level, x, y in bad:
            while level > 0 and (level, x, y) in failed:
                level, x, y = level - 1, x >> 1, y >> 1
            if (level, x, y) not in failed:
                up.add((level, x, y))
        extra_keys = np.array(sorted(up), dtype=np.int64).reshape(-1, 3)
        extra_keys = extra_keys[self.pool.slots_of(extra_keys) < 0]
        if priority is not None:
            priority = np.concatenate([priority, np.zeros(len(extra_keys))])
        return np.concatenate([missing, extra_keys]), priority, len(bad)

    def prefetch(self, render_set: RenderSet, eye: np.ndarray) -> int:
        """Build the tiles of ``render_set`` that are not resident ahead of any frame's
        request (a camera flight's destination, ``eye`` its ECEF position in m), nearest
        first; replaces the previous prefetch. Only with ``async_loading``. Returns how many
        tiles were queued."""
        if not self.async_loading:
            return 0
        self._check_terrain_version()
        keys = render_set.keys
        if len(keys) > self.pool.capacity:
            keys = coarsen_to_fit(render_set, self.pool.capacity)[0].keys
        missing = keys[self.pool.slots_of(keys) < 0]
        self._ensure_loader().prefetch(missing, tile_priority(missing, eye))
        return len(missing)

    def _fit_pool(self, render_set: RenderSet, stats: FrameStats) -> RenderSet:
        """The render set itself when the pool holds all its tiles; otherwise a coarser one
        that fits (`coarsen_to_fit`), with the degrade stated in the frame's stats
        (``degraded``: a sentence; ``tiles_coarsened``: tiles replaced by ancestors)."""
        capacity = self.pool.capacity
        wanted = len(render_set)
        if wanted <= capacity:
            return render_set
        fitted, replaced = coarsen_to_fit(render_set, capacity)
        stats.extra["degraded"] = (
            f"tile pool: {wanted} tiles wanted, {capacity} slots; drew coarser tiles "
            f"({len(fitted)} tiles)"
        )
        stats.extra["tiles_coarsened"] = replaced
        return fitted

    # -- drawing -----------------------------------------------------------------------------
    # A frame's renderer steps, in the order `FramePipeline.run` calls them: `load` (fit the
    # pool, tile loading, upload), `draw_terrain`, `draw_overlays`, `finish_stats`.
    def load(self, render_set: RenderSet, stats: FrameStats) -> RenderSet:
        """Make the tiles of ``render_set`` resident: coarsen it to the pool's capacity
        (`_fit_pool`), then upload every missing tile (headless) or a budget of finished
        ones, standing in ancestors for the rest (``async_loading``, the window). Returns the
        render set to draw; sets ``stats.tiles_uploaded`` and ``stats.tiles_loading``."""
        self._draw_thread = threading.get_ident()
        render_set = self._fit_pool(render_set, stats)
        if self.async_loading:
            render_set, stats.tiles_uploaded, stats.tiles_loading = self._load_async(
                render_set, stats.extra
            )
        else:
            stats.tiles_uploaded = self.ensure_resident(render_set.keys)
        self.last_drawn = render_set
        return render_set

    def draw_terrain(
        self,
        view: ViewState,
        render_set: RenderSet,
        target: moderngl.Framebuffer,
        uniforms: dict[str, object] | None = None,
    ) -> int:
        """Clear ``target`` and draw the (resident) tiles of ``render_set`` in one multi-draw
        call, with the imagery drape; ``uniforms``: the displacement hook's for this frame
        (names ``gv_u_*``). Returns the triangles drawn."""
        slots = self.pool.drawable_slots(render_set.keys)  # stand-ins may be retired tiles
        # Draw near tiles first so the depth test rejects hidden fragments early.
        order = np.argsort(np.linalg.norm(self.pool.centers[slots] - view.eye, axis=1))
        self.pool.touch(slots)
        n = len(slots)

        blocks = self.block_strides(view, render_set, slots)
        edges = None
        push = np.zeros(n)
        if render_set.block_tau_px is not None and n:
            # The default provider's tiles: edges shared with a same-level neighbour stitched
            # instead of skirted (issue #27 item 3), and pushed to overlap (`EDGE_PUSH_PX`).
            tile_edges = stitch_tile_edges(render_set, blocks)
            blocks, edges = tile_edges.blocks, tile_edges.edges
            push = tile_edges.stitched @ np.array([1.0, 2.0, 4.0, 8.0])
            render_set = dataclasses.replace(
                render_set, variant_ids=tile_edges.variant_ids, variants=tile_edges.variants
            )
        patterned = np.empty(0, np.int64)
        if blocks is not None:
            patterned = np.flatnonzero(blocks[:, 0, 0] >= 0)
            # Before the variants: room for new patterns may start the index pool afresh.
            p_first, p_count = self.indices.patterns(
                blocks[patterned], None if edges is None else edges[patterned]
            )
        self.last_block_tiles = len(patterned)
        self.last_blocks = blocks if len(patterned) else None
        table = np.array(
            [self.indices.get(v) for v in render_set.variants], dtype=np.int64
        ).reshape(-1, 2)
        # What each tile draws, counted as the plugin API's `triangle_count` counts it.
        counts = render_set.index_counts(self.size)
        firsts = table[render_set.variant_ids, 0] if n else np.empty(0, np.int64)
        if len(patterned):
            counts = counts.copy()
            counts[patterned] = p_count
            firsts = firsts.copy()
            firsts[patterned] = p_first
        custom = np.zeros(n, dtype=bool)
        custom_cmds = None
        if render_set.custom_indices:
            rows = np.array(sorted(render_set.custom_indices), dtype=np.int64)
            custom[rows] = True
            chunks = [np.asarray(render_set.custom_indices[int(r)], np.uint32) for r in rows]
            starts = np.concatenate([[0], np.cumsum(counts[rows])[:-1]])
            self._write_custom_indices(np.concatenate(chunks))
            custom_cmds = (rows, starts)

        verts = self.pool.verts_per_tile
        base_inst = np.arange(n)
        cmds = np.stack(
            [counts, np.ones(n, np.int64), firsts, slots * verts, base_inst], axis=1
        ).astype(np.uint32)
        cmds_sorted = cmds[order]
        custom_sorted = custom[order]
        centers = self.pool.centers[slots]
        inst = np.concatenate(
            [
                centers - view.eye,
                centers,
                slots[:, None].astype(np.float64),
                self.pool.coast_scale[slots, None],
                push[:, None],
            ],
            axis=1,
        ).astype(np.float32)
        n_var = int(np.count_nonzero(~custom))
        if n:
            self.instances.write(inst.tobytes())
            self.commands.write(cmds_sorted[~custom_sorted].tobytes())
        if custom_cmds is not None:
            rows, starts = custom_cmds
            ccmds = cmds[rows].copy()
            ccmds[:, 2] = starts
            self.custom_commands.write(ccmds.tobytes())

        self._use_features(
            (
                self.overlays.imagery.active,
                bool(self.settings.hillshade),
                bool(self.settings.fog),
                float(self.settings.exaggeration) != 1.0,  # 1: the normals need no tilt
                False,
            )
        )
        self._set_uniforms(view, uniforms)
        target.use()
        bg = self.settings.background
        target.clear(bg[0], bg[1], bg[2], 1.0, depth=1.0)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE)
        self.ctx.depth_func = "<"
        self.pool.albedo_tex.use(0)
        self.pool.normal_tex.use(1)
        # overlays: upload stale imagery slots, bind the drape, set its uniforms.
        self.overlays.prepare(self.program, self.pool, slots, render_set.keys)
        passes = [0, 1] if self.settings.wireframe else [0]
        for mode in passes:
            if mode == 1:
                # The wire overlay is its own variant (one colour, no fetch): a uniform
                # switch in the shaded program cost ~8 % of every shaded frame on llvmpipe.
                self._use_features((False, False, False, False, True))
                self._set_uniforms(view, uniforms)
            if "u_depth_bias" in self.program:
                self.program["u_depth_bias"].value = 2e-6 if mode == 1 else 0.0
            self.ctx.wireframe = mode == 1
            self.ctx.depth_func = "<=" if mode == 1 else "<"
            if n_var:
                self.vao.render_indirect(self.commands, moderngl.TRIANGLES, count=n_var)
            if custom_cmds is not None:
                self.custom_vao.render_indirect(
                    self.custom_commands, moderngl.TRIANGLES, count=len(custom_cmds[0])
                )
        self.ctx.wireframe = False
        self.ctx.depth_func = "<"
        return int(counts.sum() // 3)

    def block_strides(
        self, view: ViewState, render_set: RenderSet, slots: np.ndarray | None = None
    ) -> np.ndarray | None:
        """(N, 8, 8) int8 block strides the tiles of ``render_set`` are drawn with, or None
        (all by their variants): the set's own ``block_strides``, or where it asks for them
        (``block_tau_px``) those `lod.block_strides.choose_block_strides` finds from the
        resident tiles' block facts (tiles drawn by a plain, unstitched, non-pole variant at
        a stride under 8, and not by custom indices). ``slots``: the tiles' pool slots.
        Sets ``last_block_ms`` (CPU time of the choice, ms)."""
        self.last_block_ms = 0.0
        if render_set.block_strides is not None:
            return render_set.block_strides
        tau = render_set.block_tau_px
        n = len(render_set)
        if tau is None or not n:
            return None
        t0 = time.process_time()
        if slots is None:
            slots = self.pool.drawable_slots(render_set.keys)
        # A plain variant's stride index, where blocks may go coarser; else past their range.
        stride_idx = plain_stride_idx(render_set)
        stride_idx = np.where(stride_idx >= 0, stride_idx, WHOLE_FROM)
        out = choose_block_strides(
            self.pool.block_facts,
            slots,
            render_set.keys[:, 0],
            stride_idx,
            view,
            float(tau),
            self.size,
        )
        self.last_block_ms = (time.process_time() - t0) * 1e3
        return out

    def draw_overlays(self, view: ViewState, render_set: RenderSet) -> dict[str, float]:
        """Draw the overlay layers' vectors and point objects, depth-tested against the
        terrain just drawn; returns their figures for ``FrameStats.extra``."""
        if self.last_blocks is not None and len(self.last_blocks) == len(render_set):
            # The overlays drape over the mesh drawn: with its block strides.
            render_set = dataclasses.replace(render_set, block_strides=self.last_blocks)
        return self.overlays.draw(view, render_set, self.terrain, self.settings)

    def finish_stats(
        self,
        stats: FrameStats,
        view: ViewState,
        render_set: RenderSet,
        triangles: int,
        t0: float,
    ) -> FrameStats:
        """Fill ``stats`` for the frame that drew ``render_set`` (``t0``: `time.perf_counter`
        when loading began; draw_ms runs from there to now, after ``ctx.finish()``)."""
        stats.triangles = int(triangles)
        stats.tiles_drawn = len(render_set)
        stats.draw_ms = (time.perf_counter() - t0) * 1e3
        stats.lod_ms = float(render_set.stats.get("lod_ms", 0.0))
        stats.frame_ms = stats.draw_ms + stats.lod_ms
        stats.tiles_culled_frustum = int(render_set.stats.get("tiles_culled_frustum", 0))
        stats.tiles_culled_horizon = int(render_set.stats.get("tiles_culled_horizon", 0))
        stats.levels = level_histogram(render_set.keys)
        stats.provider_stats, stats.provider_stats_dropped = clean_provider_stats(render_set.stats)
        if render_set.error_px is not None:
            finite = render_set.error_px[np.isfinite(render_set.error_px)]
            stats.max_sse_px = float(finite.max()) if len(finite) else 0.0
        if render_set.block_tau_px is not None or render_set.block_strides is not None:
            stats.extra["block_ms"] = self.last_block_ms
            stats.extra["tiles_blocked"] = self.last_block_tiles
        self.last_view = view
        return stats

    def _set_uniforms(self, view: ViewState, extra: dict[str, object] | None = None) -> None:
        s = self.settings
        uni: dict[str, object] = {}
        uni["u_rot"] = view.rotation.T.astype("f4").tobytes()
        uni["u_proj"] = view.proj.T.astype("f4").tobytes()
        uni["u_exag"] = float(s.exaggeration)
        uni["u_inv_axes2"] = INV_AXES2
        uni["u_albedo"] = 0
        uni["u_normals"] = 1
        for name, rgb in COAST_RAMP.items():
            uni[f"u_{name}"] = rgb
        # A light from behind the viewer's upper left keeps the visible side lit and relief
        # readable at every scale.
        right, up, back = view.rotation
        light = 0.55 * back + 0.6 * up - 0.55 * right
        light = light / np.linalg.norm(light)
        uni["u_light"] = tuple(float(v) for v in light)
        uni["u_log_far"] = 1.0 / math.log2(1.0 + view.far)
        h = max(float(ecef_to_lonlat(view.eye)[2]), 1.0)
        horizon = math.sqrt(h * (2 * WGS84.a + h))
        uni["u_fog_start"] = 0.6 * horizon if s.fog else 1e30
        uni["u_fog_end"] = 1.6 * horizon if s.fog else 2e30
        uni["u_fog_color"] = (0.70, 0.78, 0.90)
        uni["u_wire_color"] = tuple(s.wire_color)
        uni["u_edge_push"] = (EDGE_PUSH_PX / view.sse_factor, 1.0 / self.size)
        if extra:
            uni.update(extra)
        p = self.program
        for name, value in uni.items():
            # The GLSL compiler drops uniforms a shader variant does not use.
            if name in p:
                if isinstance(value, bytes):
                    p[name].write(value)
                else:
                    p[name].value = value

    def release(self) -> None:
        self.terrain.changed.disconnect(self._terrain_changed, missing_ok=True)
        self._release_variants()
        for obj in (
            self.instances,
            self.commands,
            self.custom_ibo,
            self.custom_commands,
            # The tile pool and the index pool: ~100 MB that would outlive the session in a
            # context that is kept (a window, a script rendering many globes).
            self.pool.vbo,
            self.pool.albedo_tex,
            self.pool.normal_tex,
            self.indices.buffer,
        ):
            obj.release()
        self.overlays.release()  # overlays:
        if self.loader is not None:
            self.loader.shutdown()
        if self._warmer is not None:
            self._warmer.shutdown()


#: The ramp near sea level, as the terrain shader's coast uniforms (u_coast_jump, u_coast_t).
COAST_RAMP = coast_ramp()

#: The terrain shaders' feature defines, in the order of GlobeRenderer's features tuple.
TERRAIN_FEATURES = ("GV_IMAGERY", "GV_HILLSHADE", "GV_FOG", "GV_TILT", "GV_WIREFRAME")


def remote_workers(terrain: TerrainStack) -> int:
    """Loader threads for the visible remote layers of ``terrain``: `REMOTE_LOAD_WORKERS`,
    at most the smallest `TileStore.max_requests` of them; 1 without remote layers."""
    bounds = [ly.store.max_requests for ly in terrain.visible_layers if ly.store.is_remote]
    return max(1, min([REMOTE_LOAD_WORKERS, *bounds])) if bounds else 1


def terrain_defines(features: tuple[bool, ...], hook: bool) -> dict[str, bool]:
    """The #defines of a terrain program variant (both stages get the same): the features
    (imagery drape, hillshade, fog, exaggeration tilt, the wireframe overlay's pass) and
    GV_SHADE where a displacement hook is installed (only a hook sets a shade factor)."""
    return {**dict(zip(TERRAIN_FEATURES, features, strict=True)), "GV_SHADE": hook}


def coarsen_to_fit(render_set: RenderSet, capacity: int) -> tuple[RenderSet, int]:
    """A render set of at most ``capacity`` tiles covering what ``render_set`` covers, made by
    replacing groups of sibling tiles by their parent, deepest level first and, within a
    level, the groups drawn with the smallest screen-space error first (they lose the least).

    A view can want more tiles than the GPU pool has slots (tiny tau, a huge window, a strong
    exaggeration): drawing coarser is better than failing the frame. Replacing the deepest
    tiles by their parents never makes tiles overlap (no tile of the set lies below them).
    Parents are drawn at full resolution with skirts (their own index variant); their
    ``error_px`` is estimated as twice their children's largest (one level coarser roughly
    doubles the geometric error). Returns the new set and how many of the input's tiles were
    replaced (are drawn through an ancestor).
    """
    keys = render_set.keys
    n = len(keys)
    err = (
        np.asarray(render_set.error_px, dtype=np.float64).copy()
        if render_set.error_px is not None and len(render_set.error_px) == n
        else np.zeros(n)
    )
    err = np.where(np.isfinite(err), err, 0.0)
    rows = np.arange(n)  # row in the input set, -1 for a parent made here
    while len(keys) > capacity:
        level = int(keys[:, 0].max())
        if level == 0:
            break  # cannot happen for a pool of more than two slots
        at = np.nonzero(keys[:, 0] == level)[0]
        parents = np.stack([keys[at, 0] - 1, keys[at, 1] >> 1, keys[at, 2] >> 1], axis=1)
        uniq, group = np.unique(parents, axis=0, return_inverse=True)
        group = group.reshape(-1)
        counts = np.bincount(group, minlength=len(uniq))
        group_err = np.zeros(len(uniq))
        np.maximum.at(group_err, group, err[at])
        # Cheapest first: smallest error, then the most tiles saved.
        order = np.lexsort((-counts, group_err))
        need = len(keys) - capacity
        saved = np.cumsum(counts[order] - 1)
        if saved[-1] >= need:
            chosen = order[: int(np.searchsorted(saved, need)) + 1]
            chosen = chosen[counts[chosen] > 1]
        else:
            chosen = order  # the whole level goes; the next pass coarsens the level above
        take = np.zeros(len(uniq), dtype=bool)
        take[chosen] = True
        drop = at[take[group]]
        keep = np.ones(len(keys), dtype=bool)
        keep[drop] = False
        keys = np.concatenate([keys[keep], uniq[take]])
        err = np.concatenate([err[keep], 2.0 * group_err[take]])
        rows = np.concatenate([rows[keep], np.full(int(take.sum()), -1)])
    replaced = n - int(np.count_nonzero(rows >= 0))
    return _rebuild_render_set(render_set, keys, rows, err), replaced


def _rebuild_render_set(
    render_set: RenderSet, keys: np.ndarray, rows: np.ndarray, err: np.ndarray
) -> RenderSet:
    """The render set of ``keys``: rows taken from ``render_set`` (``rows`` >= 0) keep their
    variant and custom indices; new parent tiles (``rows`` == -1) get a full-resolution
    variant with skirts and the pole fans their position needs."""
    variants = list(render_set.variants)
    variant_ids = np.zeros(len(keys), dtype=np.int64)
    old = rows >= 0
    variant_ids[old] = render_set.variant_ids[rows[old]]
    new = np.nonzero(~old)[0]
    if len(new):
        lv, y = keys[new, 0], keys[new, 2]
        pole_code = (y == 0).astype(np.int64) + 2 * (y == (1 << lv) - 1)
        poles = (None, "north", "south", "both")
        for code in np.unique(pole_code):
            variant = IndexVariant(stride=1, skirts=True, pole=poles[int(code)])
            if variant not in variants:
                variants.append(variant)
            variant_ids[new[pole_code == code]] = variants.index(variant)
    # Kept tiles' own index lists follow them to their new rows (a loop over the lists, not
    # over every tile: each old row appears at most once in ``rows``).
    new_of_old = np.full(len(render_set.keys), -1, dtype=np.int64)
    new_of_old[rows[old]] = np.nonzero(old)[0]
    custom = {
        int(new_of_old[r]): idx
        for r, idx in render_set.custom_indices.items()
        if new_of_old[int(r)] >= 0
    }
    blocks = render_set.block_strides
    if blocks is not None:  # new parents are drawn by their variants
        kept = np.full((len(keys), 8, 8), -1, dtype=np.int8)
        kept[old] = blocks[rows[old]]
        blocks = kept
    return RenderSet(
        keys,
        variant_ids,
        variants,
        custom_indices=custom,
        error_px=err if render_set.error_px is not None else None,
        stats=dict(render_set.stats),
        block_strides=blocks,
        block_tau_px=render_set.block_tau_px,
    )


def tile_bounds_tuple(key: tuple[int, int, int]) -> tuple[float, float, float, float]:
    from globeview.terrain.quadtree import TileKey

    return tuple(float(v) for v in tile_bounds(TileKey(*key)))  # type: ignore[return-value]


__all__ = [
    "FLOATS_PER_VERTEX",
    "DisplacementHook",
    "GlobeRenderer",
    "IndexVariant",
]
