"""The renderer's screen-space-error selection moved behind the LOD-provider interface: drawing
through the plugin registry (GlobeSession, lod="chunked-sse") gives the same image, pixel for
pixel, as calling the selection function directly (GlobeScene with lod = the shared
traversal with ScreenSpaceErrorPolicy, with chunked-sse's default min_triangles)."""

from __future__ import annotations

import numpy as np
import pytest

from globeview.model.camera import Camera

pytestmark = pytest.mark.gl

VIEWS = [(0.0, 20.0, 2.0e7, 0.0, -90.0), (-71.3, 44.15, 9000.0, 0.0, -30.0)]


@pytest.mark.slow
def test_chunked_sse_plugin_renders_pixel_identical_to_the_direct_selection() -> None:
    from globeview.app.session import GlobeSession
    from globeview.lod.sse_policy import ScreenSpaceErrorPolicy
    from globeview.lod.traversal import traverse
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.render.offscreen import OffscreenTarget, create_headless_context
    from globeview.render.scene import GlobeScene
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores

    ctx = create_headless_context()
    size = (240, 160)
    target = OffscreenTarget(ctx, size)
    terrain = TerrainStack.from_stores(embedded_stores())
    direct = GlobeScene(
        ctx, terrain, lod=lambda v, t: traverse(v, t, ScreenSpaceErrorPolicy(min_triangles=True))
    )
    registry = PluginRegistry(MemorySettings()).discover()
    plugin = GlobeSession(ctx, terrain, registry=registry, lod="chunked-sse")
    for view in VIEWS:
        images = []
        for scene in (direct, plugin):
            scene.camera = Camera.from_lonlat(*view)
            scene.render(target.fbo, size)
            images.append(target.read_rgb())
        assert images[0].std() > 5  # a real picture, not a blank frame
        assert np.array_equal(images[0], images[1]), view
    assert registry.get("chunked-sse").status == "ok"
