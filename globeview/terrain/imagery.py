"""Imagery and thematic rasters as per-tile textures aligned with the terrain quadtree.

Any raster GDAL reads becomes, for a terrain tile (level, x, y), an RGBA uint8 texture of
``tex_size`` x ``tex_size`` texels (TREND §4.1.2): the interior ``tex_size - 2`` texels cover
the tile's lon/lat bounds exactly and a **one-texel border** on every side repeats the
neighbouring tiles' content, so bilinear filtering across a tile edge reads the neighbour's
colour and no seam shows. Texel i (0-based, any axis) is centred at
``west + (i - 0.5) * d`` with ``d = (east - west) / (tex_size - 2)`` (rows run from the north).

Sources:
- RGB(A) imagery (3 or 4 bands, any dtype scaled to 0..255 by the dtype's range for uint8/16);
- a single band with a colour table (thematic classes, nearest-neighbour resampling);
- a single band coloured by a ramp (``colour_ramp``: list of (value, (r, g, b)) stops) —
  e.g. a hillshade/slope computed from a DEM (`hillshade_tile`).

Tiles are built lazily (rasterio.warp.reproject straight from the file's bands, so GDAL reads
only the window it needs) and cached in an LRU. `ImageryStack` composes several layers in
order with their opacities (alpha "over") into one texture per tile. Pure numpy/rasterio: no GL.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import rasterio
import rasterio.warp
import rasterio.windows
from affine import Affine
from rasterio.crs import CRS
from rasterio.enums import Resampling

from globeview.errors import GlobeviewError
from globeview.geodesy import WGS84
from globeview.terrain.quadtree import TileKey, tile_bounds

WGS84_CRS = CRS.from_epsg(4326)
DEFAULT_TEX_SIZE = 256
#: Most source pixels a side one texel may gather in a warp. Beyond it (a global view over a
#: huge raster: 2 000 000 pixels wide puts ~4 000 x 4 000 under one texel) GDAL's warper asks
#: for gigabytes, so the tile's window is first read decimated (overviews used when present).
MAX_SOURCE_PER_TEXEL = 64

#: A terrain hillshade ramp: grey levels (value in 0..1 = shade).
GREY_RAMP: tuple[tuple[float, tuple[int, int, int]], ...] = (
    (0.0, (0, 0, 0)),
    (1.0, (255, 255, 255)),
)


class ImageryError(GlobeviewError):
    """A raster cannot be used as imagery (unreadable, no CRS, unsupported bands, ...)."""


TileKeyLike = tuple[int, int, int]


def texel_grid(key: TileKeyLike, tex_size: int) -> tuple[Affine, tuple[float, float, float, float]]:
    """Affine (texel -> lon/lat, degrees) of a tile's texture including its border, and the
    tile's (west, south, east, north)."""
    w, s, e, n = tile_bounds(TileKey(*key))
    m = tex_size - 2
    dx = (e - w) / m
    dy = (n - s) / m
    return Affine(dx, 0.0, w - dx, 0.0, -dy, n + dy), (w, s, e, n)


def ramp_lookup(
    values: np.ndarray, stops: Sequence[tuple[float, tuple[int, int, int]]]
) -> np.ndarray:
    """(..., 3) uint8 colours of ``values`` by piecewise-linear ``stops`` (NaN -> 0)."""
    xs = np.array([s[0] for s in stops], dtype=np.float64)
    cs = np.array([s[1] for s in stops], dtype=np.float64)
    v = np.nan_to_num(values.astype(np.float64), nan=xs[0])
    out = np.stack([np.interp(v, xs, cs[:, k]) for k in range(3)], axis=-1)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


class RasterImagery:
    """A georeferenced raster read as RGBA tiles.

    Args:
        path: any raster GDAL reads.
        ramp: colour stops for a single-band raster without a colour table (default: grey
            from the band's min to max).
        crs: CRS to assume when the file has none (else ImageryError).
        tex_size: texels per tile side, border included.
    """

    def __init__(
        self,
        path: str | Path,
        ramp: Sequence[tuple[float, tuple[int, int, int]]] | None = None,
        crs: str | None = None,
        tex_size: int = DEFAULT_TEX_SIZE,
    ) -> None:
        self.path = Path(path)
        self.tex_size = int(tex_size)
        try:
            # PAM off: GDAL would otherwise save the band statistics we ask for below as a
            # .aux.xml next to the user's file (a write into their folder, or a failure in a
            # read-only one).
            with rasterio.Env(GDAL_PAM_ENABLED="NO"):
                self.ds = rasterio.open(self.path)
        except rasterio.errors.RasterioIOError as exc:
            first = str(exc).splitlines()[0] if str(exc) else "unreadable"
            raise ImageryError(f"{self.path.name}: cannot read as a raster ({first})") from None
        ds = self.ds
        if crs is not None:
            try:
                self.crs = CRS.from_user_input(crs)
            except Exception:  # noqa: BLE001  pyproj/GDAL raise several types here: one line
                raise ImageryError(f"{self.path.name}: unknown CRS {crs!r}") from None
        elif ds.crs is None:
            raise ImageryError(
                f"{self.path.name}: the raster has no coordinate reference system (give one)"
            )
        else:
            self.crs = ds.crs
        if ds.count in (3, 4):
            self.mode = "rgba" if ds.count == 4 else "rgb"
        elif ds.count == 1:
            try:
                cmap = ds.colormap(1)
            except ValueError:
                cmap = None
            if cmap:
                self.mode = "palette"
                lut = np.zeros((max(256, max(cmap) + 1), 4), np.uint8)
                for k, c in cmap.items():
                    lut[k] = c
                self.lut = lut
            else:
                self.mode = "ramp"
                if ramp is None:
                    stats = ds.statistics(1, approx=True)
                    ramp = ((stats.min, (0, 0, 0)), (stats.max, (255, 255, 255)))
                self.ramp = tuple(ramp)
        else:
            raise ImageryError(
                f"{self.path.name}: {ds.count} bands; imagery needs 1 (thematic), 3 (RGB) "
                "or 4 (RGBA)"
            )
        if ds.width < 1 or ds.height < 1:
            raise ImageryError(f"{self.path.name}: the raster is empty")
        try:
            west, south, east, north = rasterio.warp.transform_bounds(
                self.crs, WGS84_CRS, *ds.bounds, densify_pts=21
            )
        except Exception as exc:  # noqa: BLE001  pyproj/GDAL raise several types here: one line
            raise ImageryError(
                f"{self.path.name}: cannot transform bounds to WGS84 ({exc})"
            ) from None
        self.bounds = (west, south, east, north)
        self._lock = threading.Lock()

    def intersects(self, key: TileKeyLike) -> bool:
        w, s, e, n = tile_bounds(TileKey(*key))
        bw, bs, be, bn = self.bounds
        return not (e < bw or w > be or n < bs or s > bn)

    def _scale(self, dtype: str) -> float:
        if dtype == "uint8":
            return 1.0
        if dtype == "uint16":
            return 255.0 / 65535.0
        return 255.0  # floats in 0..1

    def tile_rgba(self, key: TileKeyLike) -> np.ndarray | None:
        """(tex_size, tex_size, 4) uint8 RGBA of a tile (alpha 0 outside the raster), or None
        where the raster does not reach the tile."""
        if not self.intersects(key):
            return None
        t = self.tex_size
        dst_t, _ = texel_grid(key, t)
        ds = self.ds
        nodata = ds.nodata
        if self.mode in ("rgb", "rgba"):
            dst = np.zeros((ds.count, t, t), np.float32)
            src_nodata = nodata
            with self._lock:
                src = self._decimated(key)
                for b in range(ds.count):
                    rasterio.warp.reproject(
                        rasterio.band(ds, b + 1) if src is None else src[0][b],
                        dst[b],
                        src_transform=None if src is None else src[1],
                        src_crs=self.crs,
                        dst_transform=dst_t,
                        dst_crs=WGS84_CRS,
                        resampling=Resampling.bilinear,
                        src_nodata=src_nodata,
                        dst_nodata=np.nan,
                        init_dest_nodata=True,
                    )
            valid = ~np.isnan(dst[0])
            rgb = np.clip(np.nan_to_num(dst[:3]) * self._scale(ds.dtypes[0]), 0, 255)
            alpha = valid * 255.0
            if ds.count == 4:
                alpha = np.clip(np.nan_to_num(dst[3]) * self._scale(ds.dtypes[3]), 0, 255)
                alpha = alpha * valid
            out = np.concatenate([rgb, alpha[None]], axis=0)
            return np.ascontiguousarray(np.round(out).astype(np.uint8).transpose(1, 2, 0))
        dst = np.full((t, t), np.nan, np.float32)
        with self._lock:
            src = self._decimated(key)
            rasterio.warp.reproject(
                rasterio.band(ds, 1) if src is None else src[0][0],
                dst,
                src_transform=None if src is None else src[1],
                src_crs=self.crs,
                dst_transform=dst_t,
                dst_crs=WGS84_CRS,
                resampling=Resampling.nearest if self.mode == "palette" else Resampling.bilinear,
                src_nodata=nodata,
                dst_nodata=np.nan,
                init_dest_nodata=True,
            )
        valid = ~np.isnan(dst)
        if self.mode == "palette":
            idx = np.clip(np.nan_to_num(dst), 0, len(self.lut) - 1).astype(np.int64)
            out = self.lut[idx].copy()
            out[..., 3] = np.where(valid, out[..., 3], 0)
            return out
        rgb = ramp_lookup(dst, self.ramp)
        return np.concatenate([rgb, (valid * 255).astype(np.uint8)[..., None]], axis=-1)

    def _decimated(self, key: TileKeyLike) -> tuple[np.ndarray, Affine] | None:
        """None when the tile can warp straight from the file (its source window is at most
        `MAX_SOURCE_PER_TEXEL` x tex_size pixels a side); else (bands, transform): that window
        read at 2 x tex_size pixels a side (nearest: GDAL streams it, using overviews when
        there are), nodata as NaN, so one texel never gathers thousands of pixels a side."""
        ds = self.ds
        try:
            b = rasterio.warp.transform_bounds(WGS84_CRS, self.crs, *tile_bounds(TileKey(*key)))
            win = ds.window(*b).intersection(rasterio.windows.Window(0, 0, ds.width, ds.height))
        except Exception:  # noqa: BLE001  no overlap, or bounds the CRS cannot take: warp as before
            return None
        t = self.tex_size
        if max(win.width, win.height) <= MAX_SOURCE_PER_TEXEL * t:
            return None
        scale = max(win.width, win.height) / (2 * t)
        shape = (max(1, round(win.height / scale)), max(1, round(win.width / scale)))
        data = ds.read(
            window=win, out_shape=(ds.count, *shape), masked=True, resampling=Resampling.nearest
        )
        bands = data.astype(np.float32).filled(np.nan)
        transform = ds.window_transform(win) @ Affine.scale(
            win.width / shape[1], win.height / shape[0]
        )
        return bands, transform

    def close(self) -> None:
        self.ds.close()


def hillshade_tile(
    heights: Callable[[TileKeyLike], np.ndarray],
    key: TileKeyLike,
    tex_size: int,
    azimuth_deg: float = 315.0,
    altitude_deg: float = 45.0,
) -> np.ndarray:
    """(tex_size, tex_size, 4) uint8 grey hillshade of a terrain tile computed from its DEM
    heights (metres) with the sun at ``azimuth_deg`` (clockwise from north) and
    ``altitude_deg``; slopes use metres on the ellipsoid (lon spacing scaled by cos(lat))."""
    h = heights(key).astype(np.float64)
    size = h.shape[0]
    w, s, e, n = tile_bounds(TileKey(*key))
    dlon = np.radians((e - w) / (size - 1))
    dlat = np.radians((n - s) / (size - 1))
    lat = np.radians(np.linspace(n, s, size))[:, None]
    dx = WGS84.a * np.maximum(np.cos(lat), 1e-6) * dlon
    dy = WGS84.a * dlat
    gy, gx = np.gradient(h)
    dzdx = gx / dx
    dzdy = -gy / dy  # rows run south: north-positive gradient
    az = np.radians(azimuth_deg)
    alt = np.radians(altitude_deg)
    sun = np.array([np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt)])
    norm = np.sqrt(dzdx**2 + dzdy**2 + 1.0)
    shade = np.clip((-dzdx * sun[0] - dzdy * sun[1] + sun[2]) / norm, 0.0, 1.0)
    # Resample the node grid onto the texel grid (texel centres, border included).
    m = tex_size - 2
    pos = (np.arange(tex_size) - 0.5) / m * (size - 1)
    pos = np.clip(pos, 0.0, size - 1.0)
    i0 = np.minimum(np.floor(pos).astype(np.int64), size - 2)
    f = pos - i0
    rows = shade[i0] * (1 - f)[:, None] + shade[i0 + 1] * f[:, None]
    img = rows[:, i0] * (1 - f)[None, :] + rows[:, i0 + 1] * f[None, :]
    g = np.round(img * 255.0).astype(np.uint8)
    return np.stack([g, g, g, np.full_like(g, 255)], axis=-1)


class HillshadeImagery:
    """A thematic layer computed from the terrain itself: hillshade of the composed DEM."""

    mode = "hillshade"

    def __init__(
        self, terrain, tex_size: int = DEFAULT_TEX_SIZE, azimuth_deg: float = 315.0
    ) -> None:
        self.terrain = terrain
        self.tex_size = int(tex_size)
        self.azimuth_deg = azimuth_deg
        self.path = Path("hillshade")

    def tile_rgba(self, key: TileKeyLike) -> np.ndarray | None:
        return hillshade_tile(self.terrain.heights, key, self.tex_size, self.azimuth_deg)


class ImagerySource(Protocol):
    """What a layer draws from (RasterImagery, HillshadeImagery, a plugin's source): RGBA
    tiles of the terrain's quadtree, None where it has nothing."""

    def tile_rgba(self, key: TileKeyLike) -> np.ndarray | None: ...


@dataclass
class ImageryLayer:
    """One imagery layer: a source of RGBA tiles plus display state."""

    source: ImagerySource  # RasterImagery | HillshadeImagery (anything with tile_rgba(key))
    name: str
    opacity: float = 1.0
    visible: bool = True


@dataclass
class ImageryStack:
    """Imagery layers composed in order (later on top, alpha over, times opacity) into one
    RGBA texture per terrain tile, built lazily and cached (LRU of ``cache_tiles``)."""

    layers: list[ImageryLayer] = field(default_factory=list)
    tex_size: int = DEFAULT_TEX_SIZE
    cache_tiles: int = 1024

    def __post_init__(self) -> None:
        self.version = 0
        self._cache: OrderedDict[TileKeyLike, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    def add(self, layer: ImageryLayer) -> ImageryLayer:
        size = getattr(layer.source, "tex_size", self.tex_size)
        if size != self.tex_size:
            raise ImageryError(f"{layer.name}: texture size {size} != {self.tex_size}")
        self.layers.append(layer)
        self.changed()
        return layer

    def remove(self, name: str) -> None:
        self.layers = [ly for ly in self.layers if ly.name != name]
        self.changed()

    def changed(self) -> None:
        """Call after changing a layer's opacity/visibility/order: tiles are recomposed."""
        self.version += 1
        with self._lock:
            self._cache.clear()

    @property
    def active(self) -> bool:
        return any(ly.visible and ly.opacity > 0 for ly in self.layers)

    def tile(self, key: TileKeyLike) -> np.ndarray:
        """(tex_size, tex_size, 4) uint8 composed RGBA of a tile (alpha = coverage)."""
        key = (int(key[0]), int(key[1]), int(key[2]))
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        t = self.tex_size
        acc = np.zeros((t, t, 4), np.float32)
        for layer in self.layers:
            if not layer.visible or layer.opacity <= 0:
                continue
            rgba = layer.source.tile_rgba(key)
            if rgba is None:
                continue
            a = rgba[..., 3:4].astype(np.float32) / 255.0 * float(layer.opacity)
            acc[..., :3] = rgba[..., :3].astype(np.float32) * a + acc[..., :3] * (1.0 - a)
            acc[..., 3:4] = a * 255.0 + acc[..., 3:4] * (1.0 - a)
        out = np.clip(np.round(acc), 0, 255).astype(np.uint8)
        with self._lock:
            self._cache[key] = out
            while len(self._cache) > self.cache_tiles:
                self._cache.popitem(last=False)
        return out
