"""Hypsometric colour ramp for land and a separate bathymetry ramp for water (thesis §5.1:
land and water coloured apart), sampled into a 1-D texture over a height range (metres)."""

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
