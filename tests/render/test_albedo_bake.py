"""The per-tile albedo bake (issue #17: the terrain shader reads baked ramp colours instead of
looking the ramp up per pixel): the baked texels equal the ramp as the old per-pixel lookup
sampled it, survive hostile heights, keep water and land apart near sea level (sharp
coasts), and are what the tile pool uploads for a real tile."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.render.colour_ramp import (
    COAST_MIN_M,
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


def decoded(codes: np.ndarray, scale: float) -> np.ndarray:
    """The height (metres) the terrain shader decodes from coast texels: (2 a - 1) s."""
    return (codes.astype(float) / 255.0 * 2.0 - 1.0) * scale


def test_coast_texels_keep_water_and_land_apart() -> None:
    # Heights are rounded to 0.5 m (RAMP_STEP_M): within 0.25 m of sea level they are 0 m,
    # land (the ramp blends water into land over ~20 m there anyway).
    water = [-0.3, -0.5, -50.0, -1e4, -np.inf]
    land = [-0.2, 0.0, 1e-6, 0.3, 50.0, 1e4, np.inf]
    for line in (np.array(water + land), np.array([-0.5, 0.0, -0.5, 9000.0, -11000.0, 0.5])):
        codes, scale = coast_texels(line)
        assert ((codes <= 127) == (np.nan_to_num(line, posinf=1, neginf=-1) < -0.25)).all()
        assert COAST_MIN_M <= scale <= 11000.0
    codes, scale = coast_texels(np.array([np.nan, np.nan]))
    assert codes.tolist() == [128, 128] and scale == COAST_MIN_M  # as 0 m
    # Linear (the shader interpolates it): a coast's nodes are divided by one scale.
    codes, scale = coast_texels(np.array([-COAST_MIN_M, COAST_MIN_M / 2, COAST_MIN_M]))
    assert scale == COAST_MIN_M and codes[0] == 0 and codes[2] == 255
    assert abs(int(codes[1]) - 191) <= 1
    for shape in ((0, 0), (1, 0), (0, 1), (1, 1), (65, 65), ()):
        codes, scale = coast_texels(np.zeros(shape, np.float32))
        assert codes.shape == shape and scale == COAST_MIN_M


def test_coast_crosses_zero_where_the_heights_do() -> None:
    """The coast lies where the linearly interpolated height crosses 0 m, however far the
    cell's nodes lie beyond the band: a clamped encoding (+-100 m) put the coast of a
    -150 / +1000 m cell at 48 % of the cell instead of 13 %."""
    f = np.linspace(0.0, 1.0, 100001)
    for a_h, b_h in ((-150.0, 1000.0), (-1000.0, 150.0), (-40.0, 60.0), (-3.0, 2500.0)):
        # A 2x2 grid (one cell) with the edge from node a to node b; the far row is land.
        grid = np.array([[a_h, b_h], [6000.0, 6000.0]])
        codes, scale = coast_texels(grid)
        h = decoded(codes[0], scale)
        along = (1 - f) * h[0] + f * h[1]  # the shader's interpolated height on that edge
        true = a_h / (a_h - b_h)
        got = f[np.argmax(np.sign(along) != np.sign(along[0]))]
        # 8 bits over +-scale: the nodes are within half a code of their height.
        tol = 0.5 * scale / 127.5 / abs(b_h - a_h) + 1e-4
        assert abs(got - true) <= tol, (a_h, b_h, got, true)


def test_cells_away_from_the_coast_keep_their_blend() -> None:
    """Nodes of cells wholly out of the band decode out of it (t stays 0 or 1 there, so
    such cells get no coast correction), however large the tile's scale."""
    lo, hi = -13.671875, 5.859375  # the band: the ramp texel centres either side of 0 m
    rng = np.random.default_rng(3)
    for side in (1.0, -1.0):  # a tile of lowland, then one of shallow water
        # Heights on the table's 0.5 m steps, out of the band (from 6 m, -14 m on).
        grid = side * np.round(rng.uniform(6.0 if side > 0 else 14.0, 40.0, (17, 17)) * 2) / 2
        grid[0, 0], grid[0, 1] = -600.0, 450.0  # one steep coast cell: a large scale
        codes, scale = coast_texels(grid)
        assert scale == 600.0  # 4.7 m a code: nearest codes could decode into the band
        h = decoded(codes, scale)
        away = np.ones(grid.shape, bool)
        away[:2, :2] = False  # the coast cell's nodes
        assert ((h >= hi) if side > 0 else (h <= lo))[away].all()


def test_coast_uniforms_reproduce_the_sampled_blend() -> None:
    """The shader's coast blend t(h) is the albedo alpha of the same height (so cells with no
    coast get no correction), and its jump is the ramp's step across sea level."""
    u = coast_ramp()
    scale, offset = u["coast_t"]
    h = np.linspace(-COAST_MIN_M, COAST_MIN_M, 4001)
    codes, s = coast_texels(h)
    t = np.clip(decoded(codes, s) * scale + offset, 0.0, 1.0)
    alpha = albedo_texels(h)[:, 3] / 255.0
    # 8-bit heights (0.13 m steps, the blend rises 1/19.5 a metre) and 8-bit weights.
    assert np.abs(t - alpha).max() <= 0.01
    assert alpha[0] == 0.0 and alpha[-1] == 1.0
    texel_m = (RAMP_HI_M - RAMP_LO_M) / RAMP_TEXELS  # the texel centres either side of 0 m:
    lo = RAMP_LO_M + (np.floor(-RAMP_LO_M / texel_m - 0.5) + 0.5) * texel_m
    step = sampled_ramp(np.array([lo + texel_m]))[0] - sampled_ramp(np.array([lo]))[0]
    assert np.allclose(np.array(u["coast_jump"]) * 255.0, step, atol=1.0)


@pytest.mark.slow
def test_the_pool_uploads_baked_albedo_and_normals(gl_ctx, terrain) -> None:
    """What the shader samples for a real tile: albedo RGB = the baked ramp, albedo alpha =
    the coast blend, normal RGB = n * 0.5 + 0.5, normal alpha = the height over the tile's
    coast scale (kept per slot for the draw)."""
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
        codes, scale = coast_texels(mesh.heights)
        _, tile_codes, tile_scale = tile_texels(mesh.heights)
        assert (tile_codes == codes).all() and tile_scale == scale
        assert (normal[:, :, 3] == codes).all() and pool.coast_scale[slot] == scale
        decoded = normal[:, :, :3] / 255.0 * 2.0 - 1.0
        assert np.abs(decoded - mesh.normals).max() <= 1.0 / 255.0 + 1e-6
    finally:
        renderer.release()
