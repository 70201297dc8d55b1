"""The data that ships with globeview (``data/``): where it is, and the embedded DEMs.

A leaf module (standard library only): the DEM reader and the vertical datums (the EGM96
grid) both find files here without importing each other.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["EMBEDDED_DATA_DIR", "embedded_dem_paths"]


# globeview/terrain/dem/data.py -> the repository root's data/
def _find_data_dir() -> Path:
    """Where the embedded data lives: ``$GLOBEVIEW_DATA_DIR``; the checkout's ``data/`` (an
    editable install or running from the source tree); else ``<prefix>/share/globeview/data``
    where a wheel install puts it (pyproject's data-files)."""
    env = os.environ.get("GLOBEVIEW_DATA_DIR")
    if env:
        return Path(env)
    checkout = (Path(__file__).resolve().parents[3] / "data").resolve()
    if (checkout / "etopo20.tif").exists():
        return checkout
    installed = Path(sys.prefix) / "share" / "globeview" / "data"
    return installed if installed.exists() else checkout


EMBEDDED_DATA_DIR: Path = _find_data_dir()


def embedded_dem_paths() -> list[Path]:
    """The DEMs shipped in data/: the global base first, then the regional samples."""
    names = [
        "etopo20.tif",
        "N44W072.hgt",
        "craterlake-elev-16bit-30m.tif",
        "topobathy_vancouver.tif",
    ]
    return [EMBEDDED_DATA_DIR / n for n in names]
