"""The application layer: what a globe does with its plugins, without a window.

`GlobeSession` (the host boundary: the frame host the render pipeline draws for) and its
hosts, one per concern: `LodHost` (the active LOD provider and the fallback), `ToolHost`
(the active tool: its shader hook, checked CPU displacement, overlay, plot) and
`OverlayHost` (files opened as overlay layers through the layer types, `layer_dispatch`);
the checks of what plugin code returns (`host_checks`), headless tool input
(`headless.place_points`) and the pytest fixtures for plugin authors (`testing`).

It sits between the window (`globeview.ui`) and the renderer (`globeview.render`), and
reaches plugins only through the registry and the API (`globeview.plugins`), which never
import it. No Qt here.
"""
