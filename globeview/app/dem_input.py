"""DEMs handed to the Python API as arrays: a numpy array with an affine transform and a CRS,
or an xarray ``DataArray`` carrying rioxarray's CRS and transform.

`array_dem_file` checks the array (shape, dtype, finite heights, transform, CRS) and writes
it as a GeoTIFF into the cache (``arrays/array-HASH.tif``, HASH of the heights, transform,
CRS and nodata), so `globeview.terrain.sources.open_source` ingests it like any DEM file and
the same array opens from the cache the next time. Every problem is one `DemError` line,
raised before anything is written. xarray and rioxarray are optional: they are imported
only for a ``DataArray``, and their absence is one line saying what to install.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from globeview.errors import DemError
from globeview.fileio import atomic_outputs
from globeview.paths import cache_dir

__all__ = ["ArrayDem", "array_dem_file", "checked_array_dem", "is_data_array"]

#: Smallest raster side (pixels) a DEM array may have: a grid needs two posts a side.
MIN_SIDE_PX = 2


@dataclass(frozen=True)
class ArrayDem:
    """A checked DEM array.

    Attributes:
        heights: (rows, cols) float32 or integer heights (metres), row 0 at the top (north
            for a north-up transform).
        transform: the affine pixel -> CRS transform of the top-left corner of each pixel
            (rasterio's / GDAL's convention), as an `affine.Affine`.
        crs: the horizontal CRS as WKT.
        nodata: the value marking missing heights (None: NaN only).
    """

    heights: np.ndarray
    transform: Any
    crs: str
    nodata: float | None

    def digest(self) -> str:
        """A short hash of the heights, transform, CRS and nodata (the cache key)."""
        h = hashlib.sha256()
        h.update(str(self.heights.dtype).encode())
        h.update(repr(self.heights.shape).encode())
        h.update(np.ascontiguousarray(self.heights).tobytes())
        h.update(repr(tuple(self.transform)[:6]).encode())
        h.update(self.crs.encode())
        h.update(repr(self.nodata).encode())
        return h.hexdigest()[:16]


def is_data_array(obj: object) -> bool:
    """Whether ``obj`` is an xarray ``DataArray`` (told without importing xarray)."""
    cls = type(obj)
    return cls.__name__ == "DataArray" and cls.__module__.split(".")[0] == "xarray"


def checked_array_dem(
    data: Any, transform: Any = None, crs: Any = None, nodata: float | None = None
) -> ArrayDem:
    """``data`` (a numpy array or an xarray DataArray) checked as a DEM; ``transform``,
    ``crs`` and ``nodata`` override a DataArray's own (rioxarray's). One `DemError` line for
    a missing transform or CRS, a shape that is not one band of rows x cols, a dtype that is
    not numbers, or no finite height at all."""
    if is_data_array(data):
        data, transform, crs, nodata = _from_data_array(data, transform, crs, nodata)
    arr = np.asarray(data)
    arr = _one_band(arr)
    if arr.dtype.kind not in "iuf":
        raise DemError(f"add_dem: heights must be numbers, not {arr.dtype} values")
    if transform is None:
        raise DemError(
            "add_dem: a numpy array needs transform= (an affine.Affine or GDAL's 6 numbers: "
            "where its pixels are) and crs="
        )
    if crs is None:
        raise DemError("add_dem: a numpy array needs crs= (e.g. 'EPSG:4326')")
    nodata_f = _nodata(nodata)
    heights = arr.astype(np.float32) if arr.dtype.kind == "f" or arr.dtype.itemsize > 4 else arr
    _check_heights(heights, nodata_f)
    return ArrayDem(np.ascontiguousarray(heights), _affine(transform), _crs_wkt(crs), nodata_f)


def _one_band(arr: np.ndarray) -> np.ndarray:
    """The (rows, cols) heights of a 2-D array or of a 3-D array with one band (first or
    last axis); one line for any other shape."""
    if arr.ndim == 3 and 1 in (arr.shape[0], arr.shape[-1]):
        arr = arr[0] if arr.shape[0] == 1 else arr[..., 0]
    if arr.ndim != 2:
        raise DemError(
            f"add_dem: heights must be one band of rows x columns, not an array of shape "
            f"{arr.shape}"
        )
    if min(arr.shape) < MIN_SIDE_PX:
        raise DemError(
            f"add_dem: heights of shape {arr.shape} are too small (at least "
            f"{MIN_SIDE_PX}x{MIN_SIDE_PX} pixels)"
        )
    return arr


def _nodata(nodata: Any) -> float | None:
    if nodata is None:
        return None
    try:
        value = float(nodata)
    except (TypeError, ValueError):
        raise DemError(f"add_dem: nodata must be a number, not {nodata!r:.40}") from None
    return None if np.isnan(value) else value


def _check_heights(heights: np.ndarray, nodata: float | None) -> None:
    """One line when no height is finite and different from ``nodata``."""
    valid = np.isfinite(heights) if heights.dtype.kind == "f" else np.ones(heights.shape, bool)
    if nodata is not None:
        valid &= heights != nodata
    if not valid.any():
        what = "NaN, infinite or nodata" if nodata is not None else "NaN or infinite"
        raise DemError(f"add_dem: every height is {what}: there is no terrain to add")


def _affine(transform: Any) -> Any:
    """``transform`` as an `affine.Affine`: one already, or its 6 numbers in affine's order
    (a, b, c, d, e, f: ``Affine(*t)``, not GDAL's geotransform order); its pixels must have
    a size."""
    from affine import Affine

    if not isinstance(transform, Affine):
        try:
            values = [float(v) for v in transform]
        except (TypeError, ValueError):
            raise DemError(
                f"add_dem: transform must be an affine.Affine or its 6 numbers, not "
                f"{type(transform).__name__}"
            ) from None
        if len(values) not in (6, 9):
            raise DemError(f"add_dem: transform has {len(values)} numbers, not 6")
        transform = Affine(*values[:6])
    coeffs = tuple(transform)[:6]
    if not all(np.isfinite(coeffs)) or abs(transform.determinant) == 0.0:
        raise DemError(f"add_dem: transform {coeffs} has no pixel size (or is not finite)")
    return transform


def _crs_wkt(crs: Any) -> str:
    """``crs`` (anything rasterio's CRS takes: 'EPSG:4326', WKT, a CRS object) as WKT.
    Parsed inside a rasterio environment, as `globeview.terrain.dem.reader.parse_crs` does,
    so PROJ's own "ERROR 1: ..." goes to logging, not stderr: the DemError's line is all."""
    import rasterio
    from rasterio.crs import CRS
    from rasterio.errors import CRSError

    try:
        with rasterio.Env():
            return str(CRS.from_user_input(crs).to_wkt())
    except (CRSError, TypeError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DemError(f"add_dem: crs {crs!r:.60} is not a CRS ({first[:120]})") from None


def _from_data_array(da: Any, transform: Any, crs: Any, nodata: Any) -> tuple:
    """(values, transform, crs, nodata) of a DataArray through rioxarray's ``.rio``; the
    arguments given win. One line when rioxarray is missing or the array has no CRS or
    transform."""
    try:
        import rioxarray  # noqa: F401  registers the .rio accessor
    except ImportError:
        raise DemError(
            "add_dem: an xarray DataArray is read through rioxarray (its CRS and transform): "
            "pip install rioxarray, or pass da.values with transform= and crs="
        ) from None
    rio = da.rio
    if crs is None:
        crs = rio.crs
        if crs is None:
            raise DemError(
                "add_dem: the DataArray has no CRS (da.rio.write_crs('EPSG:4326') or crs=)"
            )
    if transform is None:
        if len(da.dims) < 2 or any(da[d].size < MIN_SIDE_PX for d in da.dims[-2:]):
            raise DemError(f"add_dem: the DataArray's dims {tuple(da.dims)} are not a raster")
        try:
            transform = rio.transform(recalc=True)
        except Exception as exc:  # noqa: BLE001  rioxarray raises its own and xarray's errors
            raise DemError(f"add_dem: the DataArray has no transform ({exc})"[:200]) from None
    if nodata is None:
        nodata = rio.nodata if rio.nodata is not None else rio.encoded_nodata
    return np.asarray(da.values), transform, crs, nodata


def array_dem_file(dem: ArrayDem) -> Path:
    """The GeoTIFF of ``dem`` in the cache (``arrays/array-HASH.tif``, keyed by content
    only), written atomically the first time: the same array, whatever its layer is called,
    reuses the file and so its ingested store."""
    path = cache_dir() / "arrays" / f"array-{dem.digest()}.tif"
    if path.is_file():
        return path
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DemError(
            f"add_dem: cannot create {path.parent} ({exc.strerror or exc}); set "
            "GLOBEVIEW_CACHE_DIR to a writable folder"
        ) from None
    _write_geotiff(dem, path)
    return path


def _write_geotiff(dem: ArrayDem, path: Path) -> None:
    import rasterio

    rows, cols = dem.heights.shape
    profile = {
        "driver": "GTiff",
        "height": rows,
        "width": cols,
        "count": 1,
        "dtype": str(dem.heights.dtype),
        "crs": dem.crs,
        "transform": dem.transform,
        "compress": "deflate",
        "tiled": rows >= 256 and cols >= 256,
    }
    if dem.nodata is not None:
        profile["nodata"] = dem.nodata
    with atomic_outputs([path]) as (tmp,), rasterio.open(tmp, "w", **profile) as dst:
        dst.write(dem.heights, 1)
