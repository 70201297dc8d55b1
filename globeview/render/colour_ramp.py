"""Hypsometric colour ramp for land and a separate bathymetry ramp for water (thesis §5.1:
land and water coloured apart), and the per-tile albedo texels baked from it.

The terrain shader does not evaluate the ramp: each tile's node colours are baked once, when
the tile is uploaded (`albedo_texels`), into an RGBA8 texture the fragment shader samples
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
#: where the sampled ramp blends water into land, 1 above) and its height clamped to
#: +-COAST_M (normal alpha, `coast_texels`). The fragment shader recomputes t from the
#: interpolated height and adds ``jump * (t - interpolated node t)``: zero wherever the ramp
#: has no jump in the cell, the coast's step drawn sharp where it has (`coast_ramp`).
COAST_M = 100.0

#: Heights are looked up in a table of baked colours every RAMP_STEP_M metres (the ramp's
#: texels are 19.5 m apart, so rounding the height to 0.5 m moves a colour by well under one
#: 8-bit level), one 32-bit RGBA word per entry: one gather per tile instead of a lerp.
RAMP_STEP_M = 0.5

_LUTS: tuple[np.ndarray, np.ndarray] | None = None


def _luts() -> tuple[np.ndarray, np.ndarray]:
    """Tables of the heights RAMP_LO_M, RAMP_LO_M + RAMP_STEP_M, ... RAMP_HI_M: (n,) uint32
    RGBA8 words (the ramp colour, alpha the coast blend t) and (n,) uint8 coast texels."""
    global _LUTS
    if _LUTS is None:
        ramp = ramp_texture_data(RAMP_LO_M, RAMP_HI_M, RAMP_TEXELS)[0].astype(np.float64)
        h = np.arange(RAMP_LO_M, RAMP_HI_M + RAMP_STEP_M / 2, RAMP_STEP_M)
        # The old shader's lookup: a linearly filtered, edge-clamped 1-D texture at
        # u = (h - lo) / (hi - lo), texel centres at (i + 0.5) / RAMP_TEXELS.
        x = np.clip((h - RAMP_LO_M) / (RAMP_HI_M - RAMP_LO_M) * RAMP_TEXELS - 0.5, 0, None)
        texel_x = np.arange(RAMP_TEXELS, dtype=np.float64)
        rgba = np.empty((len(h), 4), dtype=np.uint8)
        for ch in range(3):
            rgba[:, ch] = np.rint(np.interp(x, texel_x, ramp[:, ch]))
        lo, hi = _coast_band()
        rgba[:, 3] = np.rint(np.clip((h - lo) / (hi - lo), 0.0, 1.0) * 255.0)
        coast = np.rint(np.clip(h, -COAST_M, COAST_M) * (127.5 / COAST_M) + 127.5)
        _LUTS = rgba.view(np.uint32).reshape(-1), coast.astype(np.uint8)
    return _LUTS


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


def tile_texels(heights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(albedo (..., 4) uint8, coast (...) uint8) of heights in metres: `albedo_texels` and
    `coast_texels` from one table index (what a tile upload needs; ~25 us for 65x65)."""
    albedo, coast = _luts()
    idx = _lut_index(heights)
    return albedo[idx].view(np.uint8).reshape(*idx.shape, 4), coast[idx]


def albedo_texels(heights: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 RGBA albedo of heights (metres; NaN is treated as 0 m, heights beyond
    the ramp's range take its end colours): the ramp colour of each height, alpha its coast
    blend weight t (see COAST_M). Heights are rounded to RAMP_STEP_M (vectorised: one table
    gather)."""
    idx = _lut_index(heights)
    return _luts()[0][idx].view(np.uint8).reshape(*idx.shape, 4)


def _coast_band() -> tuple[float, float]:
    """(lo, hi) metres: the centres of the ramp texels either side of 0 m, between which the
    sampled ramp blends water into land."""
    texel_m = (RAMP_HI_M - RAMP_LO_M) / RAMP_TEXELS
    below = np.floor((0.0 - RAMP_LO_M) / texel_m - 0.5)  # the last texel centre below 0 m
    lo = RAMP_LO_M + (below + 0.5) * texel_m
    return float(lo), float(lo + texel_m)


def coast_ramp() -> dict[str, tuple[float, ...]]:
    """The terrain shader's coast uniforms (see COAST_M): ``coast_jump``, the ramp's RGB step
    (0..1) across the band, and ``coast_t`` = (scale, offset) with the blend weight
    t = clamp(s * scale + offset, 0, 1) at s = clamped height / COAST_M."""
    lo, hi = _coast_band()
    ramp = ramp_texture_data(RAMP_LO_M, RAMP_HI_M, RAMP_TEXELS)[0].astype(np.float64) / 255.0
    i = round((lo - RAMP_LO_M) / ((RAMP_HI_M - RAMP_LO_M) / RAMP_TEXELS) - 0.5)
    jump = ramp[i + 1] - ramp[i]
    # The band must lie inside the stored height range, else t could not be recomputed.
    assert -COAST_M < lo < 0.0 <= hi < COAST_M
    return {
        "coast_jump": (float(jump[0]), float(jump[1]), float(jump[2])),
        "coast_t": (COAST_M / (hi - lo), -lo / (hi - lo)),
    }


def coast_texels(heights: np.ndarray) -> np.ndarray:
    """(...) uint8: the height (metres, rounded to RAMP_STEP_M; NaN as 0 m) clamped to
    +-COAST_M, as 127.5 + h * 127.5 / COAST_M rounded: what the shader decodes to the
    clamped height s = h / COAST_M in [-1, 1] (8-bit: ~0.8 m steps)."""
    return _luts()[1][_lut_index(heights)]
