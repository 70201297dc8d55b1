"""Hypsometric colour ramp for land and a separate bathymetry ramp for water (thesis §5.1:
land and water coloured apart), and the per-tile albedo and coast texels baked from it.

The terrain shader does not evaluate the ramp: each tile's node colours are baked once, when
the tile is uploaded (`tile_texels`), into an RGBA8 texture the fragment shader samples
with one fetch (the ramp depends on the height alone, and the height of a node never changes
while the tile is resident). On llvmpipe a float32 height fetch followed by a dependent ramp
fetch cost about a third of a full-screen terrain frame.
"""

from __future__ import annotations

import numpy as np

# (height m, RGB 0..1). Below 0 m: water, light to deep blue; above: lowland green, tan,
# brown, grey rock, snow.
BATHYMETRY_STOPS = [
    (-11000.0, (0.02, 0.04, 0.20)),
    (-6000.0, (0.04, 0.12, 0.38)),
    (-3000.0, (0.08, 0.24, 0.55)),
    (-1000.0, (0.16, 0.38, 0.70)),
    (-200.0, (0.32, 0.56, 0.82)),
    (-0.01, (0.52, 0.74, 0.90)),
]
LAND_STOPS = [
    (0.0, (0.30, 0.52, 0.26)),
    (300.0, (0.46, 0.62, 0.32)),
    (800.0, (0.74, 0.71, 0.44)),
    (1600.0, (0.62, 0.47, 0.30)),
    (3000.0, (0.55, 0.42, 0.33)),
    (4600.0, (0.62, 0.56, 0.52)),
    (5800.0, (0.86, 0.86, 0.86)),
    (9000.0, (1.00, 1.00, 1.00)),
]


def ramp_colour(heights: np.ndarray) -> np.ndarray:
    """RGB (..., 3) in 0..1 for heights in metres (vectorised)."""
    h = np.asarray(heights, dtype=np.float64)
    out = np.empty((*h.shape, 3))
    for stops, mask in ((BATHYMETRY_STOPS, h < 0.0), (LAND_STOPS, h >= 0.0)):
        xs = np.array([s[0] for s in stops])
        cs = np.array([s[1] for s in stops])
        for ch in range(3):
            out[..., ch] = np.where(mask, np.interp(h, xs, cs[:, ch]), out[..., ch])
    return out


def ramp_texture_data(lo: float, hi: float, width: int) -> np.ndarray:
    """(1, width, 3) uint8 texels over [lo, hi] metres, texel centres at the sample heights."""
    h = lo + (np.arange(width) + 0.5) / width * (hi - lo)
    return (np.clip(ramp_colour(h), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)[None, :, :]


#: Height range (metres) of the baked ramp and how many texels sample it: the ramp as the
#: fragment shader used to sample it (a 1024-texel texture over [-11 km, 9 km], linear filter,
#: clamped at the ends), so baked colours match the old per-pixel lookup at every node.
RAMP_LO_M = -11000.0
RAMP_HI_M = 9000.0
RAMP_TEXELS = 1024

#: Coasts. Baked colours alone would blur a coast over a whole texel (the water and land
#: colours blended) where the per-pixel ramp drew it sharp. So each node also stores the
#: ramp's water-to-land blend weight t(h) (albedo alpha: 0 below the ~20 m band around 0 m
#: where the sampled ramp blends water into land, 1 above) and, in the normal's alpha, its
#: height divided by a per-tile scale s (`coast_texels`). The fragment shader recomputes t
#: from the interpolated height and adds ``jump * (t - interpolated node t)``: zero wherever
#: the ramp has no jump in the cell, the coast's step drawn sharp where it has (`coast_ramp`).
#:
#: Why a per-tile scale: a map h -> g(h) of the node heights keeps the zero crossing of
#: their linear interpolation only if it is linear on the cell's nodes (g(h1) / g(h0) =
#: h1 / h0 for every h0 < 0 < h1), so no per-node clamp or companding will do (a +-100 m
#: clamp moved the coast of a -150 / +1000 m cell from 13 % to 48 % of the cell: green bands
#: on the water along steep coasts). s is at least the largest |h| of the nodes of the cells
#: that meet the band, so all of those are divided exactly; nodes of other cells (wholly
#: land or water: t constant) are clamped to +-s and rounded away from the band, so their t
#: stays 0 or 1. It costs no texture fetch: s is a per-draw attribute like the layer.
#: The price is precision: llvmpipe filters RGBA8 to whole 8-bit codes, s / 127.5 m of
#: height (~8 m where a tile has a 1 km cliff at its coast), coarse against the 20 m band.
#: The shader lets the interpolated node t (exact where a cell's nodes all lie in the band)
#: refine the blend by up to a quarter code (terrain.vert COAST_REFINE_CODES: at the
#: Vancouver bench view, 640x360, pixels > 40/255 from the per-pixel ramp: 375 with the
#: +-100 m clamp, 352 with the scale alone, 173 with a quarter-code refinement; 913 with a
#: whole code, where at.a is wrong in cells that reach beyond the band).
#: COAST_MIN_M is the smallest scale (tiles with no coast, low coasts: ~0.13 m steps); it
#: must exceed the band's half-width so that clamped nodes stay out of the band.
COAST_MIN_M = 16.0

#: Heights are looked up in a table of baked colours every RAMP_STEP_M metres (the ramp's
#: texels are 19.5 m apart, so rounding the height to 0.5 m moves a colour by well under one
#: 8-bit level), one 32-bit RGBA word per entry: one gather per tile instead of a lerp.
RAMP_STEP_M = 0.5

_LUT: np.ndarray | None = None


def _lut() -> np.ndarray:
    """Table of the heights RAMP_LO_M, RAMP_LO_M + RAMP_STEP_M, ... RAMP_HI_M: (n,) uint32
    RGBA8 words, the ramp colour, alpha the coast blend t."""
    global _LUT
    if _LUT is None:
        ramp = ramp_texture_data(RAMP_LO_M, RAMP_HI_M, RAMP_TEXELS)[0].astype(np.float64)
        h = _lut_height(np.arange(round((RAMP_HI_M - RAMP_LO_M) / RAMP_STEP_M) + 1))
        # The old shader's lookup: a linearly filtered, edge-clamped 1-D texture at
        # u = (h - lo) / (hi - lo), texel centres at (i + 0.5) / RAMP_TEXELS.
        x = np.clip((h - RAMP_LO_M) / (RAMP_HI_M - RAMP_LO_M) * RAMP_TEXELS - 0.5, 0, None)
        texel_x = np.arange(RAMP_TEXELS, dtype=np.float64)
        rgba = np.empty((len(h), 4), dtype=np.uint8)
        for ch in range(3):
            rgba[:, ch] = np.rint(np.interp(x, texel_x, ramp[:, ch]))
        lo, hi = _coast_band()
        rgba[:, 3] = np.rint(np.clip((h - lo) / (hi - lo), 0.0, 1.0) * 255.0)
        _LUT = rgba.view(np.uint32).reshape(-1)
    return _LUT


def _lut_height(idx: np.ndarray) -> np.ndarray:
    """float32 metres: the height of table entries (exact: multiples of 0.5 m, |h| <= 11 km)."""
    return idx.astype(np.float32) * np.float32(RAMP_STEP_M) + np.float32(RAMP_LO_M)


def _lut_index(heights: np.ndarray) -> np.ndarray:
    """Index of each height's nearest table entry (heights beyond the ramp's range clamp to
    its ends, NaN counts as 0 m): clip first (inf stays finite), then round by truncating
    x + 0.5 (x >= 0)."""
    h = np.asarray(heights, dtype=np.float32)
    x = np.clip(np.atleast_1d(h), np.float32(RAMP_LO_M), np.float32(RAMP_HI_M))
    x -= np.float32(RAMP_LO_M - 0.5 * RAMP_STEP_M)
    x *= np.float32(1.0 / RAMP_STEP_M)
    x[np.isnan(x)] = -RAMP_LO_M / RAMP_STEP_M + 0.5
    return x.astype(np.intp).reshape(h.shape)


def tile_texels(heights: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(albedo (..., 4) uint8, coast (...) uint8, coast scale metres) of a tile's heights
    (metres, (rows, cols)): `albedo_texels` and `coast_texels` from one table index (what a
    tile upload needs; ~0.1 ms for 65x65)."""
    idx = _lut_index(heights)
    albedo = _lut()[idx].view(np.uint8).reshape(*idx.shape, 4)
    return (albedo, *_coast_of(_lut_height(idx)))


def tile_texels_batch(heights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`tile_texels` of B tiles at once: heights (B, rows, cols) metres (rows, cols >= 2) ->
    (albedo (B, rows, cols, 4) uint8, coast (B, rows, cols) uint8, coast scales (B,) metres
    float64); each tile's the bits `tile_texels` gives it alone."""
    idx = _lut_index(heights)
    albedo = _lut()[idx].view(np.uint8).reshape(*idx.shape, 4)
    return (albedo, *_coast_of_grids(_lut_height(idx)))


def albedo_texels(heights: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 RGBA albedo of heights (metres; NaN is treated as 0 m, heights beyond
    the ramp's range take its end colours): the ramp colour of each height, alpha its coast
    blend weight t (see COAST_MIN_M). Heights are rounded to RAMP_STEP_M (vectorised: one
    table gather)."""
    idx = _lut_index(heights)
    return _lut()[idx].view(np.uint8).reshape(*idx.shape, 4)


def coast_texels(heights: np.ndarray) -> tuple[np.ndarray, float]:
    """(codes (...) uint8, s metres) of a tile's node heights (metres, (rows, cols) of a
    grid, or a 1-D row of nodes; rounded to RAMP_STEP_M, NaN as 0 m; see COAST_MIN_M):
    code = 127.5 + 127.5 * clamp(h, -s, s) / s, rounded to the nearest code for nodes in
    the coast band, away from the band for the others, never across 0 m (water <= 127,
    land >= 128). The shader decodes h = (code / 255 * 2 - 1) * s."""
    return _coast_of(_lut_height(_lut_index(heights)))


def _coast_of(h: np.ndarray) -> tuple[np.ndarray, float]:
    """`coast_texels` of heights already rounded to the table's (h: float32 metres)."""
    lo, hi = _coast_band()
    grid = h.reshape(1, -1) if h.ndim < 2 else h
    if grid.shape[0] >= 2 and grid.shape[1] >= 2:  # cells of 2x2 nodes
        cell_lo = np.minimum(grid[:-1], grid[1:])
        cell_hi = np.maximum(grid[:-1], grid[1:])
        cell_lo = np.minimum(cell_lo[:, :-1], cell_lo[:, 1:])
        cell_hi = np.maximum(cell_hi[:, :-1], cell_hi[:, 1:])
    else:  # one row or column of nodes: cells of 2 (one node: a cell of its own)
        line = grid.reshape(-1)
        pair = (line[:-1], line[1:]) if len(line) >= 2 else (line, line)
        cell_lo, cell_hi = np.minimum(*pair), np.maximum(*pair)
    # Cells where t varies: their nodes must be divided exactly (unclamped) by s.
    band = (cell_lo < hi) & (cell_hi > lo)
    s = COAST_MIN_M
    if band.any():
        s = max(s, -float(cell_lo[band].min()), float(cell_hi[band].max()))
    x = np.clip(h, np.float32(-s), np.float32(s)) * np.float32(127.5 / s) + np.float32(127.5)
    # Nearest code: x < 127.5 exactly where h < 0 (h >= -11 km, s <= 11 km: x <= 127.49),
    # so no node changes side of 0 m. Outside the band, away from it (t stays 0 or 1 where
    # every node of a cell is out of it; the nearest code could decode into the band).
    code = np.floor(x + 0.5)
    code += (code < x) & (h >= hi)
    code -= (code > x) & (h <= lo)
    # float32: -s * (127.5 / s) + 127.5 can be -1e-5 (floored to -1).
    return np.clip(code, 0.0, 255.0).astype(np.uint8), s


def _coast_of_grids(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`_coast_of` of B grids (h: (B, rows, cols) float32 metres, table heights): the codes
    (B, rows, cols) uint8 and each grid's scale s (B,) float64, by the same operations."""
    lo, hi = _coast_band()
    cell_lo = np.minimum(h[:, :-1], h[:, 1:])
    cell_hi = np.maximum(h[:, :-1], h[:, 1:])
    cell_lo = np.minimum(cell_lo[:, :, :-1], cell_lo[:, :, 1:])
    cell_hi = np.maximum(cell_hi[:, :, :-1], cell_hi[:, :, 1:])
    band = (cell_lo < hi) & (cell_hi > lo)
    # Per grid max(COAST_MIN_M, -min(band lows), max(band highs)); a grid without a band
    # cell keeps COAST_MIN_M (its extremes are -inf).
    low = np.where(band, cell_lo, np.float32(np.inf)).min(axis=(1, 2)).astype(np.float64)
    high = np.where(band, cell_hi, np.float32(-np.inf)).max(axis=(1, 2)).astype(np.float64)
    s = np.maximum(np.maximum(COAST_MIN_M, -low), high)
    s32 = s.astype(np.float32)[:, None, None]
    scale = (127.5 / s).astype(np.float32)[:, None, None]
    x = np.clip(h, -s32, s32) * scale + np.float32(127.5)
    code = np.floor(x + 0.5)
    code += (code < x) & (h >= hi)
    code -= (code > x) & (h <= lo)
    return np.clip(code, 0.0, 255.0).astype(np.uint8), s


def _coast_band() -> tuple[float, float]:
    """(lo, hi) metres: the centres of the ramp texels either side of 0 m, between which the
    sampled ramp blends water into land."""
    texel_m = (RAMP_HI_M - RAMP_LO_M) / RAMP_TEXELS
    below = np.floor((0.0 - RAMP_LO_M) / texel_m - 0.5)  # the last texel centre below 0 m
    lo = RAMP_LO_M + (below + 0.5) * texel_m
    return float(lo), float(lo + texel_m)


def coast_ramp() -> dict[str, tuple[float, ...]]:
    """The terrain shader's coast uniforms (see COAST_MIN_M): ``coast_jump``, the ramp's RGB
    step (0..1) across the band, and ``coast_t`` = (scale, offset) with the blend weight
    t = clamp(h * scale + offset, 0, 1) at the height h in metres."""
    lo, hi = _coast_band()
    ramp = ramp_texture_data(RAMP_LO_M, RAMP_HI_M, RAMP_TEXELS)[0].astype(np.float64) / 255.0
    i = round((lo - RAMP_LO_M) / ((RAMP_HI_M - RAMP_LO_M) / RAMP_TEXELS) - 0.5)
    jump = ramp[i + 1] - ramp[i]
    # Clamped nodes (+-s, s >= COAST_MIN_M) must lie outside the band, or t could change
    # where every node of a cell is out of it.
    assert -COAST_MIN_M < lo < 0.0 <= hi < COAST_MIN_M
    return {
        "coast_jump": (float(jump[0]), float(jump[1]), float(jump[2])),
        "coast_t": (1.0 / (hi - lo), -lo / (hi - lo)),
    }
