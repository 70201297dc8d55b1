"""globeview: a desktop virtual globe for terrain.

The Python API (documented in docs/python_api.md)::

    import globeview
    globe = globeview.Globe()           # a globe without a window (Qt-free)
    globe.add_dem("N44W072.hgt")        # a path, a store URL, a numpy array, an xarray DataArray
    globe.fly_to(-71.3, 44.27, 12_000, heading=20, pitch=-35)
    rgba = globe.render((800, 600))     # (600, 800, 4) uint8, drawn headless (EGL)
    globeview.show(globe)               # the window on the same globe (IPython: %gui qt)

``Globe`` and ``show`` are imported when first used, so ``import globeview`` stays cheap.

Layers (imports point downwards only; see docs/architecture.md and the import-linter contract
in pyproject.toml)::

    globeview.cli       the command line
    globeview.ui        Qt shell (globeview.show lives here)
    globeview.app       the application without a window (globeview.Globe lives here)
    globeview.render    moderngl renderer, offscreen frames
    globeview.plugins   plugin API, registry, built-in LOD providers and tools (no Qt)
    globeview.model     the evented model of a globe
    globeview.lod       level of detail
    globeview.terrain   DEM readers, ingest, tile stores
    globeview.geodesy   ellipsoid, geodetic<->ECEF, ENU frames, rays
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

__all__ = ["CameraPose", "Globe", "Profile", "__version__", "show"]

#: Public name -> the module that defines it (imported on first use, by name: the layers
#: contract sees no import of app or ui here, so a module importing ``globeview`` for its
#: ``__version__`` imports nothing above it). Type checkers read __init__.pyi.
_LAZY = {
    "Globe": "globeview.app.globe",
    "CameraPose": "globeview.app.globe",
    "Profile": "globeview.app.globe",
    "show": "globeview.ui.show",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'globeview' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
