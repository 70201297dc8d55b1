"""Make data/egm96_15.tif, the EGM96 geoid shipped with globeview, from the GTX grid.

Usage: python scripts/make_geoid_tif.py [SRC.gtx] [OUT.tif]
(defaults: ../shared/data/egm96_15.gtx -> data/egm96_15.tif)

The GTX grid (1440 x 721 float32, N in metres, pixel-is-point nodes at lon -180..179.75,
lat -90..90 every 0.25 deg) is copied value for value into a float32 GeoTIFF with the same
georeferencing, compressed with DEFLATE + floating-point predictor (3). Nothing is resampled.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import rasterio

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str]) -> int:
    src = Path(argv[0]) if argv else ROOT.parent / "shared" / "data" / "egm96_15.gtx"
    out = Path(argv[1]) if len(argv) > 1 else ROOT / "data" / "egm96_15.tif"
    with rasterio.open(src) as ds:
        grid = ds.read(1).astype(np.float32)
        profile = {
            "driver": "GTiff",
            "width": ds.width,
            "height": ds.height,
            "count": 1,
            "dtype": "float32",
            "crs": ds.crs,
            "transform": ds.transform,
            "compress": "deflate",
            "predictor": 3,
            "zlevel": 9,
            "tiled": False,
            "blockysize": 16,
        }
    if not np.isfinite(grid).all():
        raise SystemExit(f"{src}: non-finite undulations")
    tmp = out.with_suffix(".tmp.tif")
    with rasterio.open(tmp, "w", **profile) as dst:
        dst.write(grid, 1)
        # The nodes are the GTX grid's points: the half-cell corner transform is GDAL's way of
        # writing a pixel-is-point grid.
        dst.update_tags(AREA_OR_POINT="Point", SOURCE=src.name, UNITS="metre")
        dst.update_tags(1, DESCRIPTION="EGM96 geoid undulation N above WGS84 (m)")
    tmp.replace(out)
    print(f"{out}: {out.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
