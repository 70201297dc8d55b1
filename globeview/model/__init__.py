"""The globe as plain objects, free of Qt and GL: camera, layers, overlays, the active LOD
provider and tool, display settings. Renderers and windows subscribe to their events."""

from globeview.model.camera import Camera
from globeview.model.display import DisplaySettings
from globeview.model.globe import DEFAULT_LOD, Globe, GlobeEvents

__all__ = ["DEFAULT_LOD", "Camera", "DisplaySettings", "Globe", "GlobeEvents"]
