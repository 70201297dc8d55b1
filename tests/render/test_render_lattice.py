"""No screen-door lattice at the data's sample spacing (issue #29, item 6).

Tiles drawn finer than their data hold the data's bilinear surface, creased along every data
node line; shaded with their own triangles' normals, those creases covered nadir views with a
lattice of lines one data spacing apart (White Mountains, SRTM3 at the store's level 12:
7 px at 9 km, 16 px at 4 km). `render/tile_normals.py` shades them with the data level's
normals, interpolated smoothly.

The lattice is found by its period on the ground, so relief (which moves a node line by
pixels in a nadir view) does not smear it: each pixel's ground point comes from the depth
buffer, its lon (lat) in data node spacings is the lattice coordinate c, and g = |L(c + 1 px)
- L(c)| is the luminance's change across node lines. Its share that repeats with period p is
A(p) = sum g exp(2 pi i c / p) / sum g. Lines on the node lines, of either sign, are more
change at c = 0 mod 1 than between: A(1) with phase 0, so the measure is Re A(1).
(Interpolating between nodes has the opposite signature: a curve through the nodes' values
turns at the nodes, where its slope, hence g, passes through its smallest values; A(1) there
has phase 180 degrees: tiles at the data level, the 30 km view, the views below after the
fix. A power spectrum, blind to phase, cannot tell the two apart: the data-level rendering's
|A(1)| is 0.05-0.07 here, half the lattice's.)

The threshold, from a lattice-free reference: |A| at 24 periods incommensurate with the
data's (0.70-0.92 and 1.08-1.40 spacings) is what chance gives these images (no structure of
the renderer's repeats there; their largest is 2-4x their median), and a lattice-free Re A(1)
is one more such draw. A lattice stands above the largest of them by PEAK_FACTOR. At
1280x720, Re A(1) / max |A(neighbours)| (lon, lat): before the fix 4 km +7.0, +7.3, 9 km +9.3,
+6.1; after it -1.7, -1.2 and -3.8, -2.1; 30 km (tiles at the data level, unchanged) -6.6,
-14.3.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from globeview.geodesy import ecef_to_lonlat
from globeview.model.camera import Camera
from globeview.render.picking import depth_to_view_distance
from globeview.render.tile_normals import data_level
from globeview.terrain.quadtree import key_for_lonlat

pytestmark = pytest.mark.gl

SIZE = (1280, 720)
#: The issue's nadir views over the White Mountains (`globeview render --camera=...`).
VIEWS = [(-71.3, 44.15, h, 0.0, -90.0) for h in (4000.0, 9000.0, 30000.0)]
#: A level below any data: `data_level` of its tile is the data's.
DEEP_LEVEL = 20
#: Periods (data node spacings) no lattice of the renderer's has: the neighbourhood of p = 1.
NEIGHBOURS = np.r_[np.linspace(0.70, 0.92, 12), np.linspace(1.08, 1.40, 12)]
PEAK_FACTOR = 2.0
SUBSAMPLE = 4


def ground_lonlat(view, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(h, w) lon and lat (degrees) of each pixel's drawn point: its window depth (logarithmic,
    `picking.depth_to_view_distance`) unprojected along the pixel's ray."""
    h, w = depth.shape
    dist = depth_to_view_distance(depth.astype(np.float64), view.far)
    t = math.tan(math.radians(view.fovy_deg) / 2.0)
    nx, ny = np.meshgrid(
        ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * t * view.aspect,
        (1.0 - (np.arange(h) + 0.5) / h * 2.0) * t,
    )
    p_cam = np.stack([nx * dist, ny * dist, -dist], axis=-1)
    lon, lat, _ = ecef_to_lonlat((view.eye + p_cam @ view.rotation).reshape(-1, 3))
    return np.asarray(lon).reshape(h, w), np.asarray(lat).reshape(h, w)


def lattice_amplitudes(
    lum: np.ndarray, coord: np.ndarray, mask: np.ndarray, axis: int, periods: np.ndarray
) -> np.ndarray:
    """(P,) complex A(p) (module docstring) of luminance ``lum`` (h, w) across the node lines
    whose lattice coordinate ``coord`` (h, w, data node spacings) grows along image ``axis``,
    over the pixel pairs with both pixels in ``mask``: every SUBSAMPLE-th line of pixels along
    ``axis`` (neighbouring lines cross the same node lines; the figures move by a few per cent
    at a quarter of the cost)."""
    keep = (slice(None, None, SUBSAMPLE), slice(None)) if axis == 1 else np.s_[:, ::SUBSAMPLE]
    lum, coord, mask = lum[keep], coord[keep], mask[keep]
    n = lum.shape[axis]
    lo, hi = np.arange(n - 1), np.arange(1, n)
    g = np.abs(np.take(lum, hi, axis) - np.take(lum, lo, axis))
    c = 0.5 * (np.take(coord, lo, axis) + np.take(coord, hi, axis))
    m = np.take(mask, lo, axis) & np.take(mask, hi, axis)
    g, c = g[m], c[m]
    return np.array([np.sum(g * np.exp(2j * np.pi * c / p)) for p in periods]) / g.sum()


@pytest.mark.slow
@pytest.mark.parametrize("cam", VIEWS)
def test_no_lattice_at_the_data_spacing(chunked_scene, targets, gv, terrain, cam):
    rgb, result = gv.render(chunked_scene, targets, Camera.from_lonlat(*cam), SIZE)
    depth = targets(SIZE).read_depth()
    lon, lat = ground_lonlat(result.view, depth)
    kx, ky = key_for_lonlat(DEEP_LEVEL, cam[0], cam[1])
    level = data_level(terrain, (DEEP_LEVEL, int(np.ravel(kx)[0]), int(np.ravel(ky)[0])))
    assert level == 12  # SRTM3 (3"), resampled to the store's 2.47" nodes
    step = 180.0 / 2**level / (terrain.tile_size - 1)  # degrees between data nodes
    lum = rgb.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    periods = np.r_[1.0, NEIGHBOURS]
    # Heading 0, nadir: image x runs east (across meridian lines), y south.
    for axis, coord in ((1, (lon + 180.0) / step), (0, (90.0 - lat) / step)):
        a = lattice_amplitudes(lum, coord, depth < 1.0, axis, periods)
        chance = np.abs(a[1:]).max()
        assert a[0].real <= PEAK_FACTOR * chance, (axis, a[0], chance)
