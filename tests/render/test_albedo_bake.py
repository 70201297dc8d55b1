"""The per-tile albedo bake (issue #17: the terrain shader reads baked ramp colours instead of
looking the ramp up per pixel): the baked texels equal the ramp as the old per-pixel lookup
sampled it, survive hostile heights, keep water and land apart near sea level (sharp
coasts), and are what the tile pool uploads for a real tile."""

from __future__ import annotations

import numpy as np

from globeview.render.colour_ramp import (
    COAST_M,
    RAMP_HI_M,
    RAMP_LO_M,
    RAMP_TEXELS,
    albedo_texels,
    coast_ramp,
    coast_texels,
    ramp_colour,
    ramp_texture_data,
    tile_texels,
)
from globeview.render.tile_pool import TilePool


def sampled_ramp(h: np.ndarray) -> np.ndarray:
    """(N, 3) float 0..255: the 1024-texel ramp texture sampled with a linear filter, clamped
    at the ends, at u = (h - lo) / (hi - lo): what the fragment shader used to compute."""
    ramp = ramp_texture_data(RAMP_LO_M, RAMP_HI_M, RAMP_TEXELS)[0].astype(np.float64)
    x = np.clip((h - RAMP_LO_M) / (RAMP_HI_M - RAMP_LO_M) * RAMP_TEXELS - 0.5, 0, None)
    texel = np.arange(RAMP_TEXELS, dtype=np.float64)
    return np.stack([np.interp(x, texel, ramp[:, c]) for c in range(3)], axis=1)


def test_baked_albedo_is_the_sampled_ramp() -> None:
    h = np.linspace(-12000.0, 10000.0, 20001)
    got = albedo_texels(h)
    assert got.shape == (len(h), 4) and got.dtype == np.uint8
    # Heights are looked up every 0.5 m: at most one 8-bit level from the exact sampling,
    # two in the ~20 m band where water blends into land (~8 levels a metre there).
    diff = np.abs(got[:, :3].astype(float) - sampled_ramp(h)).max(axis=1)
    band = (h > -15.0) & (h < 7.0)
    assert diff[~band].max() <= 1.0 and diff[band].max() <= 2.5
    # ... which is the hypsometric ramp itself away from sea level (within 2 levels).
    far = np.abs(h) > 40.0
    assert np.abs(got[far, :3] - ramp_colour(h[far]) * 255.0).max() <= 2.0


def test_baked_albedo_of_hostile_heights() -> None:
    h = np.array([np.nan, np.inf, -np.inf, 1e30, -1e30, 0.0], dtype=np.float32)
    got = albedo_texels(h)
    assert (got[0] == got[5]).all()  # NaN: as 0 m
    top, bottom = albedo_texels(np.array([RAMP_HI_M, RAMP_LO_M]))
    assert (got[1] == top).all() and (got[3] == top).all()
    assert (got[2] == bottom).all() and (got[4] == bottom).all()
    assert albedo_texels(np.zeros((0, 0))).shape == (0, 0, 4)
    assert albedo_texels(np.zeros((65, 65), np.float32)).shape == (65, 65, 4)


def test_coast_texels_keep_water_and_land_apart() -> None:
    # Heights are rounded to 0.5 m (RAMP_STEP_M): within 0.25 m of sea level they are 0 m,
    # land (the ramp blends water into land over ~20 m there anyway).
    water = np.array([-0.3, -0.5, -50.0, -1e4, -np.inf])
    land = np.array([-0.2, 0.0, 1e-6, 0.3, 50.0, 1e4, np.inf])
    assert (coast_texels(water) <= 127).all() and (coast_texels(land) >= 128).all()
    assert coast_texels(np.array([np.nan]))[0] == 128  # as 0 m
    # Linear within the band (the shader interpolates it): +-COAST_M map to the ends.
    assert coast_texels(np.array([-COAST_M, COAST_M])).tolist() == [0, 255]
    assert abs(int(coast_texels(np.array([COAST_M / 2]))[0]) - 191) <= 1


def test_coast_uniforms_reproduce_the_sampled_blend() -> None:
    """The shader's coast blend t(s) is the albedo alpha of the same height (so cells with no
    coast get no correction), and its jump is the ramp's step across sea level."""
    u = coast_ramp()
    scale, offset = u["coast_t"]
    h = np.linspace(-COAST_M, COAST_M, 4001)
    s = coast_texels(h).astype(float) / 255.0 * 2.0 - 1.0
    t = np.clip(s * scale + offset, 0.0, 1.0)
    alpha = albedo_texels(h)[:, 3] / 255.0
    # 8-bit heights (0.8 m steps, the blend rises 1/19.5 a metre) and 8-bit weights.
    assert np.abs(t - alpha).max() <= 0.045
    assert alpha[0] == 0.0 and alpha[-1] == 1.0
    texel_m = (RAMP_HI_M - RAMP_LO_M) / RAMP_TEXELS  # the texel centres either side of 0 m:
    lo = RAMP_LO_M + (np.floor(-RAMP_LO_M / texel_m - 0.5) + 0.5) * texel_m
    step = sampled_ramp(np.array([lo + texel_m]))[0] - sampled_ramp(np.array([lo]))[0]
    assert np.allclose(np.array(u["coast_jump"]) * 255.0, step, atol=1.0)


def test_the_pool_uploads_baked_albedo_and_normals(gl_ctx, terrain) -> None:
    """What the shader samples for a real tile: albedo RGB = the baked ramp, albedo alpha =
    the coast blend, normal RGB = n * 0.5 + 0.5, normal alpha = the clamped height."""
    from globeview.render.renderer import GlobeRenderer

    renderer = GlobeRenderer(gl_ctx, terrain, capacity=4)
    try:
        key = (2, 1, 1)
        mesh = renderer.build_mesh(key)
        pool: TilePool = renderer.pool
        pool.load(np.array([key]), lambda k: mesh)
        slot = int(pool.slots_of(np.array([key]))[0])
        s = pool.size
        layer = slice(slot * s * s * 4, (slot + 1) * s * s * 4)
        albedo = np.frombuffer(pool.albedo_tex.read(), np.uint8)[layer].reshape(s, s, 4)
        normal = np.frombuffer(pool.normal_tex.read(), np.uint8)[layer].reshape(s, s, 4)
        assert (albedo == albedo_texels(mesh.heights)).all()
        assert (tile_texels(mesh.heights)[1] == coast_texels(mesh.heights)).all()
        assert (normal[:, :, 3] == coast_texels(mesh.heights)).all()
        decoded = normal[:, :, :3] / 255.0 * 2.0 - 1.0
        assert np.abs(decoded - mesh.normals).max() <= 1.0 / 255.0 + 1e-6
    finally:
        renderer.release()
