"""globeview: a desktop virtual globe for terrain.

Layers (imports point downwards only; see DESIGN.md and the import-linter contract in
pyproject.toml)::

    globeview.ui        Qt shell
    globeview.plugins   plugin API, registry, built-in LOD providers and tools (no Qt)
    globeview.render    moderngl renderer, camera, meshes, offscreen frames
    globeview.terrain   DEM readers, ellipsoidal quadtree, wavelet pyramid, tile store
    globeview.geodesy   ellipsoid, geodetic<->ECEF, ENU frames, rays
"""

__version__ = "0.1.0"
