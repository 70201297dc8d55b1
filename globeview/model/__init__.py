"""The globe as plain objects, free of Qt and GL: camera, layers, overlays, the active LOD
provider and tool, display settings. Renderers and windows subscribe to their events.

The names below are imported on first use (PEP 562 ``__getattr__``): the plugin API imports
`globeview.model.drawables` and `globeview.model.plot` when a manifest is read, and that
must not load the globe, and with it the terrain, rasterio and the stores.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from globeview.model.camera import Camera
    from globeview.model.display import DisplaySettings
    from globeview.model.globe import DEFAULT_LOD, Globe, GlobeEvents

__all__ = ["DEFAULT_LOD", "Camera", "DisplaySettings", "Globe", "GlobeEvents"]

_MODULES = {
    "Camera": "globeview.model.camera",
    "DisplaySettings": "globeview.model.display",
    "DEFAULT_LOD": "globeview.model.globe",
    "Globe": "globeview.model.globe",
    "GlobeEvents": "globeview.model.globe",
}


def __getattr__(name: str) -> Any:
    module = _MODULES.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
