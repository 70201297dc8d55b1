"""An LOD provider that reads heights in ``select`` (quadtree-clod) over a store served by
HTTP, on a thread that never waits for the network (the window's UI thread,
`TileStore.forbid_network_on`): a tile not fetched yet (`TileNotReady`) is late data, not the
provider's fault - that frame is the default provider's selection, the provider stays chosen
and enabled, and draws once its tiles have arrived (issue #18). A real server on 127.0.0.1."""

from __future__ import annotations

import shutil
import threading
import time

import pytest

from globeview.terrain.store.backend import TileNotReady


@pytest.fixture
def remote_wm(tmp_path):
    """The embedded White Mountains store (levels 0..12) served on 127.0.0.1, opened by URL
    with its blend mask read (as the window's loader thread does) and reads on this thread
    forbidden to wait for the network."""
    from globeview.bench.http_server import StaticServer
    from globeview.terrain.compose.blend import BlendMask
    from globeview.terrain.embedded import embedded_stores
    from globeview.terrain.store.tile_store import TileStore

    wm = next(st for st in embedded_stores() if st.path.name.startswith("N44W072"))
    shutil.copytree(wm.path, tmp_path / "www" / "wm")
    with StaticServer(tmp_path / "www") as server:
        store = TileStore.open(f"{server.url}/wm")
        BlendMask(store)
        store.forbid_network_on(threading.get_ident())
        yield server, store
        store.close()


@pytest.mark.slow
def test_a_provider_reading_late_tiles_is_not_failed(remote_wm, monkeypatch, tmp_path, seed_cache):
    from globeview.app.session import GlobeSession
    from globeview.model.camera import Camera
    from globeview.plugins.registry import PluginRegistry
    from globeview.render.offscreen import OffscreenTarget, create_headless_context
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.embedded import embedded_stores

    # A cache of the test's own, the embedded stores copied in (etopo20 not ingested again).
    monkeypatch.setenv("GLOBEVIEW_CACHE_DIR", str(seed_cache(tmp_path / "cache")))
    server, store = remote_wm
    terrain = TerrainStack.from_stores([embedded_stores()[0], store], ["etopo20", "wm"])
    ctx = create_headless_context()
    target = OffscreenTarget(ctx, (320, 240))
    registry = PluginRegistry().discover()
    camera = Camera.from_lonlat(-71.3, 44.27, 6000.0, 0.0, -35.0)
    session = GlobeSession(ctx, terrain, camera, registry=registry, lod="quadtree-clod")
    session.renderer.async_loading = True
    provider = registry.find("lod", "quadtree-clod")
    view = session.view_state((320, 240))
    with pytest.raises(TileNotReady):  # its first selection needs tiles no one fetched
        provider.select(view, terrain)
    deadline = time.monotonic() + 120
    ready = False
    while time.monotonic() < deadline:
        result = session.render(target.fbo, (320, 240))
        assert registry.failure_of("quadtree-clod") is None
        assert session.lod_name == "quadtree-clod"  # still the user's choice
        try:
            provider.select(view, terrain)
        except TileNotReady:
            time.sleep(0.1)
            continue
        ready = True
        break
    assert ready, "the tiles the provider reads arrived in the background"
    result = session.render(target.fbo, (320, 240))
    assert result.stats.triangles > 0 and registry.failure_of("quadtree-clod") is None
    assert server.requests("*/wm/chunks/1[0-2]/*")
