"""The separable resampler (globeview.terrain.dem.resample, issue #25 C1) against GDAL's own warp.

`Dem.read_grid_parts` used `rasterio.warp.reproject` (GDAL's bilinear warp) for every source;
lon/lat sources now go through `resample_bilinear`. The tolerance, derived in the module's
docstring: GDAL forms the same weighted sums in double and rounds them to float32; ours are
float64 sums in another order, rounded once. Two float64 sums of the same terms differ by a
few 1e-16 of the sum of |terms| (<= the window's largest |height|), so after the rounding the
values differ by at most 1 ulp of float32 of the value, plus ~1e-15 of the largest |height|
where the terms cancel (a value near 0 m between hills and sea). Tested with 1e-12 for that
second term: still below 1e-8 m at 9 km. NaN (no value) must be exactly where GDAL's is.

GDAL is called with the kernel scales ours takes from the grids (its XSCALE / YSCALE warp
options, as `Dem._warp` passes them to the general path): plain GDAL takes them from each
warp piece's source window, so one node gets different heights from different windows
(the window-independence tests at the end).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from affine import Affine
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rasterio.enums import Resampling
from rasterio.warp import reproject

from globeview.terrain.dem import reader as dem_module
from globeview.terrain.dem.reader import open_dem
from globeview.terrain.dem.resample import grid_scales, resample_bilinear, warp_chunks
from globeview.terrain.quadtree import node_spacing

DATA = Path(__file__).resolve().parents[2] / "data"


def _gdal(
    arr: np.ndarray,
    src_t: Affine,
    dst_t: Affine,
    shape: tuple[int, int],
    scales: tuple[float, float] | None = None,
    *,
    window_scales: bool = False,
) -> np.ndarray:
    """GDAL's bilinear warp, as `Dem._warp` calls it on its general path: with XSCALE /
    YSCALE = ``scales`` (default: `grid_scales` of the transforms); ``window_scales``: plain
    GDAL, each warp piece's scale from its own source window."""
    if scales is None:
        scales = grid_scales((src_t.a, src_t.e), (dst_t.a, dst_t.e))
    options = {} if window_scales else {"XSCALE": repr(scales[0]), "YSCALE": repr(scales[1])}
    dst = np.full(shape, np.nan, dtype=np.float32)
    reproject(
        arr,
        dst,
        src_transform=src_t,
        src_crs="EPSG:4326",
        dst_transform=dst_t,
        dst_crs="EPSG:4326",
        resampling=Resampling.bilinear,
        src_nodata=np.nan,
        dst_nodata=np.nan,
        **options,
    )
    return dst


def _assert_within_rounding(ours: np.ndarray, gdal: np.ndarray, largest: float) -> None:
    """NaN where GDAL's is; elsewhere within 1 ulp of float32 + 1e-12 of ``largest``."""
    assert ours.dtype == np.float32 and ours.shape == gdal.shape
    np.testing.assert_array_equal(np.isnan(ours), np.isnan(gdal))
    ok = ~np.isnan(gdal)
    tol = np.spacing(np.abs(gdal[ok])).astype(np.float64) + 1e-12 * largest
    diff = np.abs(ours[ok].astype(np.float64) - gdal[ok])
    assert (diff <= tol).all(), f"max {diff.max():.3g} m, {np.max(diff / tol):.1f}x the tolerance"


# ---- real data, through Dem.read_grid_parts ---------------------------------------------------

# (file, level, (west, north) offsets from the footprint's west/north edge in node spacings,
# nodes (cols, rows)): inside the data, reaching past each side, and an ingest-sized window.
CASES = [
    ("N44W072.hgt", 12, (100, 100), (257, 129)),  # upsampled (nodes 2.47", pixels 3")
    ("N44W072.hgt", 12, (-40, -30), (300, 200)),  # past the west and north edges
    ("N44W072.hgt", 12, (1400, 1300), (300, 200)),  # past the east and south edges
    ("N44W072.hgt", 12, (-16, -16), (1025, 1025)),  # an ingest chunk over the whole tile
    ("N44W072.hgt", 10, (-8, -8), (400, 400)),  # downsampled 3.3x: GDAL's general kernel
    ("craterlake-elev-16bit-30m.tif", 13, (-20, -20), (400, 300)),  # fill -> NaN, 1.27x
    ("craterlake-elev-16bit-30m.tif", 14, (-50, -50), (700, 500)),  # past every side, 0.64x
    ("craterlake-elev-16bit-30m.tif", 12, (10, 10), (60, 40)),  # 2.5x, inside
    ("etopo20.tif", 3, (-8, 0), (1025, 513)),  # global: poles, antimeridian, 1.05x
    ("etopo20.tif", 5, (300, 100), (200, 200)),  # 0.26x inside the globe
    ("topobathy_vancouver.tif", 7, (-5, -5), (100, 80)),  # sea and land, upsampled
]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "level", "offset", "nodes"), CASES)
def test_read_grid_parts_is_gdals_warp_on_real_data(
    monkeypatch: pytest.MonkeyPatch,
    name: str,
    level: int,
    offset: tuple[int, int],
    nodes: tuple[int, int],
) -> None:
    """The data part (the warp) within rounding of GDAL's, NaN where GDAL's; the edge part
    (the surface continued past the data edge, decided from the data part's NaN) the same
    within the same tolerance."""
    d = node_spacing(level, 6)
    with open_dem(DATA / name) as dem:
        west, _, _, north = dem.info.bounds_lonlat
        args = (west + offset[0] * d, north - offset[1] * d, d, d, *nodes)
        ours = dem.read_grid_parts(*args)
        largest = max(abs(dem.vmin), abs(dem.vmax))
        with monkeypatch.context() as mp:
            mp.setattr(dem_module, "resample_bilinear", _gdal)
            gdal = dem.read_grid_parts(*args)
    assert np.isfinite(ours.data).any()
    _assert_within_rounding(ours.data, gdal.data, largest)
    _assert_within_rounding(ours.edge, gdal.edge, largest)


# ---- synthetic rasters: NaN holes and edges, every ratio ------------------------------------


def _raster(rng: np.random.Generator, h: int, w: int, holes: str) -> np.ndarray:
    """A rough random-walk surface (metres) with no-data of the given kind."""
    base = rng.uniform(-500.0, 6000.0)
    a = np.cumsum(np.cumsum(rng.normal(size=(h, w)), 0), 1) * rng.uniform(0.01, 5.0) + base
    a = a.astype(np.float32)
    if holes == "speckle":
        a[rng.random((h, w)) < 0.1] = np.nan
    elif holes == "hole":
        r, c = int(rng.integers(0, h)), int(rng.integers(0, w))
        a[r : r + int(rng.integers(1, 20)), c : c + int(rng.integers(1, 20))] = np.nan
    elif holes == "edge":  # a data edge through the window
        a[:, : int(rng.integers(1, w // 2))] = np.nan
    return a


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    ratio=st.one_of(
        st.floats(0.3, 4.0), st.sampled_from([0.5, 0.96, 1.0, 1.04, 1.06, 1.5, 2.0, 2.97, 3.0])
    ),
    aspect=st.one_of(st.just(1.0), st.floats(0.7, 1.4)),
    holes=st.sampled_from(["none", "speckle", "hole", "edge"]),
    past=st.booleans(),
)
def test_resample_bilinear_is_gdals_warp(seed, ratio, aspect, holes, past) -> None:
    """Upsampling and downsampling (GDAL's 4-sample formula and its general kernel, snapped
    scales), NaN holes and data edges, destinations inside the raster and reaching past it
    (where GDAL cuts the warp into pieces), GDAL given the grids' scales."""
    ratio_y = ratio * aspect
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(20, 160, 2))
    arr = _raster(rng, h, w, holes)
    px = rng.uniform(1e-4, 0.05)
    src_t = Affine(px, 0.0, rng.uniform(-170.0, 150.0), 0.0, -px, rng.uniform(-50.0, 80.0))
    dx, dy = px * ratio, px * ratio_y
    cols, rows = max(1, int(w / ratio) - 2), max(1, int(h / ratio_y) - 2)
    west = src_t.c + rng.uniform(0.0, max(1e-12, w * px - cols * dx))
    north = src_t.f - rng.uniform(0.0, max(1e-12, h * px - rows * dy))
    if past:
        cols, rows = cols + int(rng.integers(1, 60)), rows + int(rng.integers(1, 60))
        west -= int(rng.integers(0, 15)) * dx
        north += int(rng.integers(0, 15)) * dy
    dst_t = Affine(dx, 0.0, west, 0.0, -dy, north)
    ours = resample_bilinear(arr, src_t, dst_t, (rows, cols))
    _assert_within_rounding(
        ours, _gdal(arr, src_t, dst_t, (rows, cols)), float(np.nanmax(abs(arr)))
    )


def test_warp_chunks_cut_a_destination_mostly_off_the_raster() -> None:
    """A destination 3x a raster's width at a 1.4x ratio, half of it past the raster: GDAL
    halves it until each piece is mostly on the raster (pieces over 100 pixels); the pieces
    tile the destination; a piece inside the raster has the grids' own scale 1/1.4, those
    reaching past its end a larger one (a narrower kernel), none where it has no source."""
    step = 1.4
    chunks = warp_chunks((-60.0, step), (-10.0, step), (150, 300), (100, 120))
    cover = np.zeros((150, 300), dtype=int)
    for c in chunks:
        cover[c.row0 : c.row1, c.col0 : c.col1] += 1
    assert (cover == 1).all()
    assert len(chunks) > 2
    scales = [v for c in chunks if c.scales is not None for v in c.scales]
    assert any(v == pytest.approx(1 / step) for v in scales)
    assert any(v > 1 / step * 1.01 for v in scales)
    assert any(c.scales is None for c in chunks)
    # One piece when the destination is inside the raster.
    inside = warp_chunks((3.0, step), (3.0, step), (60, 60), (100, 120))
    assert [(c.row0, c.row1, c.col0, c.col1) for c in inside] == [(0, 60, 0, 60)]
    assert inside[0].scales == pytest.approx((1 / step, 1 / step))


def test_resample_bilinear_refuses_rotated_grids() -> None:
    arr = np.zeros((4, 4), dtype=np.float32)
    with pytest.raises(ValueError, match="north-up"):
        resample_bilinear(arr, Affine(1, 0.1, 0, 0, -1, 0), Affine(1, 0, 0, 0, -1, 0), (2, 2))


# ---- window independence: a node's height does not depend on the window that read it ----


@pytest.mark.slow
def test_a_node_shared_by_two_chunks_gets_one_height_from_either_window() -> None:
    """N44W072 at level 11 spans two ingest chunks (1025 nodes a side, the closing row and
    column shared with the next chunk): the shared nodes read through either chunk's window
    agree to the last bit of float32 (their pixel coordinates are formed in each window's
    frame, as GDAL's transformer does). Plain GDAL, whose kernel narrows where a warp piece
    reaches past the raster, gives them heights over a metre apart there."""
    level, c = 11, 1024
    d = node_spacing(level, 6)
    with open_dem(DATA / "N44W072.hgt") as dem:
        west, _, east, north = dem.info.bounds_lonlat
        cy, cx = int((90.0 - north) / d) // c, int((west + 180.0) / d) // c
        assert int((east + 180.0) / d) // c == cx + 1  # the data spans chunks cx and cx + 1

        def window(col: int) -> np.ndarray:
            return dem.read_grid_parts(
                -180.0 + col * c * d, 90.0 - cy * c * d, d, d, c + 1, c + 1
            ).data

        left, right = window(cx)[:, -1], window(cx + 1)[:, 0]
        ok = np.isfinite(left) & np.isfinite(right)
        assert ok.sum() > 300
        spacing = np.spacing(np.abs(left[ok])).astype(np.float64)
        assert (np.abs(left[ok].astype(np.float64) - right[ok]) <= spacing).all()
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(
                dem_module,
                "resample_bilinear",
                lambda a, s, t, shape, _scales: _gdal(a, s, t, shape, window_scales=True),
            )
            gdal_left, gdal_right = window(cx)[:, -1], window(cx + 1)[:, 0]
        assert np.nanmax(np.abs(gdal_left - gdal_right)) > 1.0


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    ratio=st.floats(0.3, 4.0),
    holes=st.sampled_from(["none", "speckle", "edge"]),
)
def test_overlapping_windows_give_the_same_heights(seed, ratio, holes) -> None:
    """Two destination windows of one node grid, each reaching past a different side of the
    raster (GDAL's pieces and their own window scales differ): the nodes they share get the
    same heights (within the last bit of float32) and NaN at the same nodes."""
    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(40, 160, 2))
    arr = _raster(rng, h, w, holes)
    px = rng.uniform(1e-4, 0.05)
    src_t = Affine(px, 0.0, 10.0, 0.0, -px, 50.0)
    step = px * ratio
    cols, rows = int(w / ratio) + 20, int(h / ratio) + 20
    # The node grid's origin, off the raster's pixel edges (a node exactly on the raster's
    # edge is on or off it by the rounding of its pixel coordinate in each window's frame).
    west = src_t.c - (10 + rng.uniform(0.05, 0.95)) * step
    north = src_t.f + (10 + rng.uniform(0.05, 0.95)) * step
    # Window A: nodes (0..ra, 0..ca); window B: nodes (rb.., cb..) to the grid's end.
    ra, ca = int(rng.integers(rows // 3, rows)), int(rng.integers(cols // 3, cols))
    rb, cb = int(rng.integers(0, ra)), int(rng.integers(0, ca))

    def window(r0: int, c0: int, nr: int, nc: int) -> np.ndarray:
        t = Affine(step, 0.0, west + (c0 - 0.5) * step, 0.0, -step, north - (r0 - 0.5) * step)
        return resample_bilinear(arr, src_t, t, (nr, nc))

    a = window(0, 0, ra, ca)[rb:, cb:]
    b = window(rb, cb, rows - rb, cols - cb)[: ra - rb, : ca - cb]
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a)
    spacing = np.spacing(np.abs(a[ok])).astype(np.float64)
    assert (np.abs(a[ok].astype(np.float64) - b[ok]) <= spacing).all()


def _utm_copy(path: Path) -> Path:
    """N44W072 warped into UTM zone 19N at 90 m (a projected source: `Dem._warp`'s general
    path, GDAL's warp given XSCALE / YSCALE)."""
    import rasterio
    from rasterio.warp import calculate_default_transform

    with rasterio.open(DATA / "N44W072.hgt") as src:
        t, w, h = calculate_default_transform(
            src.crs, "EPSG:32619", src.width, src.height, *src.bounds, resolution=90.0
        )
        arr = np.full((h, w), np.nan, dtype=np.float32)
        reproject(
            src.read(1).astype(np.float32),
            arr,
            src_transform=src.transform,
            src_crs=src.crs,
            dst_transform=t,
            dst_crs="EPSG:32619",
            resampling=Resampling.bilinear,
            src_nodata=-32768.0,
            dst_nodata=np.nan,
        )
    profile = {"driver": "GTiff", "dtype": "float32", "nodata": np.nan}
    with rasterio.open(
        path, "w", width=w, height=h, count=1, crs="EPSG:32619", transform=t, **profile
    ) as out:
        out.write(arr, 1)
    return path


@pytest.mark.slow
def test_a_projected_source_gives_a_shared_node_one_height(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The general path (a UTM source, GDAL's warp) with XSCALE / YSCALE from the grids: the
    nodes two level-11 chunks share get the same heights from either chunk's window (within
    the last bit of float32); plain GDAL (the scale of each piece's window) gives them
    heights 1.9 m apart there."""
    level, c = 11, 1024
    d = node_spacing(level, 6)
    with open_dem(_utm_copy(tmp_path / "utm.tif")) as dem:
        west, south, east, north = dem.info.bounds_lonlat
        cy = int((90.0 - (north + south) / 2.0) / d) // c  # the chunk row of the data's middle
        cx = int((west + 180.0) / d) // c
        assert int((east + 180.0) / d) // c == cx + 1

        def shared() -> tuple[np.ndarray, np.ndarray]:
            def window(col: int) -> np.ndarray:
                lon = -180.0 + col * c * d
                return dem.read_grid_parts(lon, 90.0 - cy * c * d, d, d, c + 1, c + 1).data

            return window(cx)[:, -1], window(cx + 1)[:, 0]

        left, right = shared()
        ok = np.isfinite(left) & np.isfinite(right)
        assert ok.sum() > 300
        spacing = np.spacing(np.abs(left[ok])).astype(np.float64)
        assert (np.abs(left[ok].astype(np.float64) - right[ok]) <= spacing).all()
        plain = dem_module.rasterio.warp.reproject

        def without_scales(*args: object, **kw: object) -> object:
            kw.pop("XSCALE"), kw.pop("YSCALE")
            return plain(*args, **kw)

        monkeypatch.setattr(dem_module.rasterio.warp, "reproject", without_scales)
        gl, gr = shared()
    assert np.nanmax(np.abs(gl - gr)) > 1.0
