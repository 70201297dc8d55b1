"""`quadtree-clod`: real-time adaptive quadtree continuous LOD inside each tile (Wang thesis
ch. 4-5, after Lindstrom et al. 1996 and Ulrich 2002).

Which tiles to draw, and at which quadtree level, is the default provider's choice: the shared
quadtree traversal (`traverse`: frustum + horizon culling, the per-terrain tile cache) with the
screen-space-error policy (`ScreenSpaceErrorPolicy`, chunked-sse's); this provider
then decides the mesh *inside* each tile with the thesis' vertex errors, box test and vertex
dependencies, and hands the renderer one triangle list per tile (`RenderSet.custom_indices`).
The per-tile mathematics is in `mesh.py`.

Thresholds. The thesis enables a vertex when ``E_v / d >= tau'`` (eq. 4.1) and refines a block
when ``E_max / (d - s) >= tau'`` (eq. 4.2), a dimensionless ratio (its experiments: 0.0001 to
0.003). A vertex error e at distance d covers ``e * K / d`` pixels (K = view.sse_factor), so a
threshold of tau pixels is ``tau' = tau / K``: at 720 px and 45 degrees (K = 869) the default
2 px is tau' = 0.0023; the thesis' 0.0001..0.003 are 0.09..2.6 px there.

Caching. A tile's vertex errors, block maxima and radii are computed at its first use and kept
(per exaggeration: errors are 3-D deviations of exaggerated positions, so exaggeration scales
the height part of every error) in slot arrays (`tile_data.ClodTiles`: a frame reads the few
nodes it visits in place; nothing per tile is stacked per frame). The whole frame's result is
reused while the tile set, the settings and the view's projection are unchanged, the view
direction turned by less than ``reuse_turn_deg`` and the eye moved by less than
``reuse_fraction`` of its distance to the nearest tile: the same index arrays are handed on
(``stats["clod_cache_hits"]`` counts).

Displacement (a tool's ``view.displace``, e.g. the terrain collapse). The collapse is not affine
at its fold lines: a long edge across a fold is drawn as a straight chord while a finer
neighbour follows the fold, and a gap opens. The tiles come from the shared traversal, which
already adds the fold's bend to each tile's error; inside the tiles, the CLOD data are
then built from the *displaced* nodes (`mesh.tile_clod`), so a vertex's error includes
the bend and blocks a fold crosses refine until the chord error projects below tau. Those
tiles are cached per displacement (`displacement_key`: the tool's key and where the
displacement moves a fixed set of probe points, the traversal's own cache key); with no
displacement nothing changes and nothing extra is computed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from globeview.plugins.api import (
    TAU_OVERRIDE,
    TEXEL_SIZE,
    TILE_BUDGET,
    LodProvider,
    PluginContext,
    RenderSet,
    ScreenSpaceErrorPolicy,
    SelectionState,
    Setting,
    TerrainStack,
    ViewState,
    displacement_key,
    traverse,
)
from globeview.plugins.builtin.clod.mesh import (
    ClodFrame,
    TileClod,
    clod_frame,
    tile_clods,
    triangulate,
)
from globeview.plugins.builtin.clod.tile_data import ClodTiles

#: Tiles whose CLOD data stays cached (about 170 kB each for 65 x 65 tiles).
TILE_CACHE = 1500
#: Tiles whose CLOD data is built in one pass (bounds the pass's temporaries, ~1 MB a tile).
BUILD_BATCH = 64


class QuadtreeClodProvider(LodProvider):
    """Quadtree CLOD meshes inside chunked-selected tiles (see the module docstring)."""

    name = "quadtree-clod"
    label = "Quadtree CLOD (Lindstrom/Ulrich)"
    settings = (
        replace(
            TAU_OVERRIDE,
            help="vertex / box test threshold in pixels; tau' = tau / K. 0 = the view's tau",
        ),
        TEXEL_SIZE,  # the tile selection's, as chunked-sse's
        TILE_BUDGET,
        Setting(
            "cull_blocks",
            "bool",
            True,
            label="quadtree culling",
            help="do not refine blocks outside the view frustum (thesis §5.2)",
        ),
        Setting(
            "reuse_fraction",
            "float",
            0.01,
            min=0.0,
            max=0.2,
            label="reuse below eye move (fraction)",
            help="reuse last frame's meshes while the eye moved less than this fraction of "
            "its distance to the nearest tile",
        ),
        Setting(
            "reuse_turn_deg",
            "float",
            0.05,
            min=0.0,
            max=5.0,
            label="reuse below turn (degrees)",
        ),
    )

    def __init__(self, context: PluginContext | None = None) -> None:
        super().__init__(context)
        self._tiles = ClodTiles(TILE_CACHE)
        self._terrain_id: tuple[int, int] | None = None
        self._last: dict | None = None
        self.cache_hits = 0
        self.last_frame: ClodFrame | None = None
        # The base traversal's flat-walk state (the tiles chosen as chunked-sse's plain walk
        # would, from last frame's candidate tree).
        self._lod_state = SelectionState()

    def reset(self) -> None:
        self._lod_state.reset()

    # -- tile data -------------------------------------------------------------------------
    def _slots(
        self,
        terrain: TerrainStack,
        keys: np.ndarray,
        exag: float,
        displace: Callable[[np.ndarray], np.ndarray] | None = None,
        dkey: tuple | None = None,
    ) -> np.ndarray:
        """Slots in the packed cache (`ClodTiles`) holding the tiles' CLOD data for this
        exaggeration and displacement ``dkey`` (`displacement_key`), built where missing."""

        def build(keys: list[tuple[int, int, int]]) -> list[TileClod]:
            # In batches: the errors of many tiles in one pass of array operations.
            out: list[TileClod] = []
            for i in range(0, len(keys), BUILD_BATCH):
                part = keys[i : i + BUILD_BATCH]
                out += tile_clods(part, [terrain.heights(k) for k in part], exag, displace)
            return out

        return self._tiles.slots(keys, terrain.tile_size, (exag, dkey), build)

    def tau_px(self, view: ViewState) -> float:
        """The threshold in pixels: the setting, or the view's when the setting is 0."""
        tau = float(self.values.get("tau_px", 0.0))
        return tau if tau > 0.0 else float(view.tau_px)

    # -- selection -----------------------------------------------------------------------------
    def select(self, view: ViewState, terrain: TerrainStack) -> RenderSet:
        if terrain is None or not terrain.layers:
            return RenderSet.empty()
        t0 = time.perf_counter()
        v = self.values
        tid = (id(terrain), int(getattr(terrain, "version", 0)))
        if tid != self._terrain_id:
            self._tiles.clear()
            self._last = None
            self._terrain_id = tid
        tau = self.tau_px(view)
        base = traverse(
            view,
            terrain,
            ScreenSpaceErrorPolicy(tau_px=tau, texel_px=v["texel_px"], max_tiles=v["max_tiles"]),
            state=self._lod_state,
        )
        keys = base.keys
        exag = float(view.exaggeration)
        dkey = displacement_key(view)
        sig = (
            tau,
            exag,
            dkey,
            tuple(view.viewport),
            float(view.fovy_deg),
            tuple(sorted(v.items())),
            keys.tobytes(),
        )
        reused = self._reuse(view, sig)
        if reused is not None:
            rs = RenderSet(
                keys, base.variant_ids, base.variants, reused.custom_indices, reused.error_px
            )
            rs.stats.update(reused.stats)
            # This frame's tile selection, not the reused one's.
            rs.stats.update({k: v for k, v in base.stats.items() if k.startswith("lod_")})
            self.cache_hits += 1
            rs.stats["clod_cache_hits"] = self.cache_hits
            rs.stats["clod_reused"] = 1
            rs.stats["lod_ms"] = (time.perf_counter() - t0) * 1e3
            return rs

        rs = self._build(view, terrain, keys, base, tau, exag, dkey)
        rs.stats["clod_cache_hits"] = self.cache_hits
        rs.stats["clod_reused"] = 0
        rs.stats["lod_ms"] = (time.perf_counter() - t0) * 1e3
        self._last = {"sig": sig, "eye": view.eye.copy(), "rot": view.rotation.copy(), "rs": rs}
        return rs

    def _reuse(self, view: ViewState, sig: tuple) -> RenderSet | None:
        last = self._last
        if last is None or last["sig"] != sig:
            return None
        rs = last["rs"]
        moved = float(np.linalg.norm(view.eye - last["eye"]))
        near = float(rs.stats.get("clod_nearest_m", 0.0))
        if moved > float(self.values["reuse_fraction"]) * near:
            return None
        # Turn angle between the two camera frames.
        c = (np.trace(view.rotation @ last["rot"].T) - 1.0) / 2.0
        if math.degrees(math.acos(min(max(c, -1.0), 1.0))) > float(self.values["reuse_turn_deg"]):
            return None
        return rs

    def _build(
        self,
        view: ViewState,
        terrain: TerrainStack,
        keys: np.ndarray,
        base: RenderSet,
        tau: float,
        exag: float,
        dkey: tuple | None = None,
    ) -> RenderSet:
        if len(keys) == 0:
            rs = RenderSet.empty()
            rs.stats.update(base.stats)
            return rs
        slots = self._slots(terrain, keys, exag, view.displace, dkey)
        data = self._tiles
        eye_local, planes_local = view.in_local_frames(
            data.origin.take(slots, axis=0), data.basis.take(slots, axis=0)
        )
        k_px = view.sse_factor
        frame = clod_frame(
            keys,
            data,
            slots,
            eye_local,
            planes_local,
            tau / k_px,
            k_px,
            cull=bool(self.values["cull_blocks"]),
        )
        self.last_frame = frame
        size = data.size
        chunks, counts = triangulate(frame, size, keys)
        rs = RenderSet(
            keys,
            base.variant_ids,
            base.variants,
            custom_indices=dict(enumerate(chunks)),
            error_px=frame.error_px,
        )
        rs.stats.update(base.stats)
        # Nearest tile distance (for the reuse rule): the nearest node of any tile.
        q = np.arange(0, size, size // 4)
        d = np.linalg.norm(
            data.pos[slots[:, None, None], q[None, :, None], q[None, None, :]].reshape(
                len(slots), -1, 3
            )
            - eye_local[:, None, :],
            axis=-1,
        )
        rs.stats["clod_nearest_m"] = float(d.min())
        rs.stats["clod_triangles"] = int(counts.sum())
        rs.stats["clod_vertices"] = int(np.count_nonzero(frame.enabled))
        rs.stats["clod_exchange_passes"] = frame.exchange_passes
        rs.stats["clod_tau_ratio"] = tau / k_px
        return rs
