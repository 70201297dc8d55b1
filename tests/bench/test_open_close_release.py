"""What makes open-render-close cycles flat (benchmarks/bench_open_close.py has the figures):
a released session holds no live GL object, and a closed cycle leaves none of its stores,
terrain, session or rasterio datasets reachable. Structural facts, never timings."""

from __future__ import annotations

import gc

import pytest


@pytest.fixture(scope="module", autouse=True)
def _need_gl():
    from globeview.render.offscreen import RenderError, create_headless_context

    try:
        create_headless_context().release()
    except RenderError as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL: {exc}")


@pytest.fixture(scope="module")
def store_paths():
    from globeview.terrain.embedded import embedded_stores

    stores = embedded_stores()
    paths = [s.path for s in stores]
    for s in stores:
        s.close()
    return paths


def test_release_gl_releases_every_gl_object_of_the_session(store_paths):
    """In a context that outlives the session (a window, a script rendering many globes),
    anything release_gl misses stays in GPU memory: the tile pool alone is ~100 MB."""
    from globeview.app.session import GlobeSession
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.render.gpu_objects import gpu_objects
    from globeview.render.offscreen import OffscreenTarget, create_headless_context
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.store.tile_store import TileStore

    stores = [TileStore.open(p) for p in store_paths]
    ctx = create_headless_context()
    try:
        target = OffscreenTarget(ctx, (96, 64))
        tracker = gpu_objects(ctx)  # the one GL-object tracker: what the session makes
        mark = tracker.mark
        session = GlobeSession(
            ctx,
            TerrainStack.from_stores(stores),
            registry=PluginRegistry(MemorySettings()).discover(),
        )
        assert session.render(target.fbo, (96, 64)).stats.triangles > 0
        live = [t for t in tracker.live if t.serial > mark]
        owners = {t.owner for t in live}
        assert "globeview.render.tile_pool" in owners  # the tracker sees the pool
        session.release_gl()
        assert [str(t) for t in tracker.live if t.serial > mark] == []
        target.release()
    finally:
        ctx.release()
        for s in stores:
            s.close()


def test_a_closed_cycle_leaves_nothing_of_it_reachable(store_paths):
    import rasterio

    from globeview.bench.soak import open_close_cycle

    def open_datasets() -> dict[int, str]:
        """Open rasterio datasets on the embedded stores' level files (other tests' stores
        may hold some: only the cycle's own count)."""
        return {
            id(o): o.name
            for o in gc.get_objects()
            if isinstance(o, rasterio.io.DatasetReader)
            and not o.closed
            and any(str(p) in o.name for p in store_paths)
        }

    gc.collect()
    before = open_datasets()
    out = open_close_cycle(store_paths, (96, 64))
    assert out["triangles"] > 0 and out["gl_left"] == []
    gc.collect()
    alive = sorted(name for name, ref in out["refs"].items() if ref() is not None)
    assert alive == []
    left = [name for key, name in open_datasets().items() if key not in before]
    assert left == []


def test_a_handed_back_headless_context_is_reused_and_draws_the_same(store_paths):
    """moderngl leaks ~40 kB per context it creates; `release_headless_context` keeps the
    context for the next globe instead, reset so that the next render is pixel-identical."""
    import numpy as np

    from globeview.app.session import GlobeSession
    from globeview.model.camera import Camera
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings
    from globeview.render.offscreen import (
        OffscreenTarget,
        create_headless_context,
        release_headless_context,
    )
    from globeview.terrain.compose.stack import TerrainStack
    from globeview.terrain.store.tile_store import TileStore

    def render(wireframe: bool) -> tuple[object, np.ndarray]:
        # The global base alone: what is drawn is not the point here, and each new stack of
        # the regional layers measures their blend masks again (~1.5 CPU-s a render).
        stores = [TileStore.open(p) for p in store_paths[:1]]
        ctx = create_headless_context()
        target = OffscreenTarget(ctx, (120, 80))
        session = GlobeSession(
            ctx,
            TerrainStack.from_stores(stores),
            camera=Camera.from_lonlat(-71.3, 44.2, 60000.0, 30.0, -40.0),
            registry=PluginRegistry(MemorySettings()).discover(),
        )
        session.renderer.settings.wireframe = wireframe  # leaves GL state behind it
        session.render(target.fbo, (120, 80))
        rgb = target.read_rgb()
        session.release_gl()
        target.release()
        release_headless_context(ctx)
        for s in stores:
            s.close()
        return ctx, rgb

    first_ctx, _ = render(wireframe=True)
    again_ctx, plain = render(wireframe=False)
    assert again_ctx is first_ctx
    fresh = create_headless_context()
    assert fresh is first_ctx
    fresh.release()  # a plain release destroys it: the next one is new
    new_ctx, new_plain = render(wireframe=False)
    assert new_ctx is not first_ctx
    assert np.array_equal(plain, new_plain)
    assert len(np.unique(plain.reshape(-1, 3), axis=0)) > 10  # terrain drawn, not a blank


@pytest.mark.slow  # over 5 CPU-s (tests/cpu_durations.py)
def test_bench_soak_cycles_prints_drift_and_verdict(capsys):
    import argparse

    from globeview.cli import bench

    parser = argparse.ArgumentParser(prog="globeview bench")
    bench.add_arguments(parser)
    assert bench.run(parser.parse_args(["soak", "--cycles", "3", "--size", "64x48"])) == 0
    out = capsys.readouterr().out
    assert "drift" in out and "objects of the last cycle alive after release: none" in out
    assert "target: drift <= 1 MB" in out
