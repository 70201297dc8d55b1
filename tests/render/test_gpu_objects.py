"""One place tracks the GL objects (issue #14): the renderer, pools, overlays and targets
allocate through `globeview.render.gpu_objects`; a session releases all it made; the
``globeview_gl`` fixture fails a test that leaks (a planted leak is caught)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from globeview.render.gpu_objects import gpu_objects

pytestmark = pytest.mark.gl


def test_tracker_counts_live_objects(globeview_gl) -> None:
    tracker = gpu_objects(globeview_gl)
    assert gpu_objects(globeview_gl) is tracker  # one per context
    before = len(tracker.live)
    buf = tracker.buffer(reserve=64)
    tex = tracker.texture((4, 4), 4)
    assert len(tracker.live) == before + 2
    assert {str(t) for t in tracker.live[-2:]} == {
        f"buffer from {__name__}",
        f"texture from {__name__}",
    }
    buf.release()
    tex.release()
    assert len(tracker.live) == before


@pytest.mark.slow
def test_leaked_since_finds_only_dropped_unreleased_objects(globeview_gl) -> None:
    tracker = gpu_objects(globeview_gl)
    mark = tracker.mark
    kept = tracker.buffer(reserve=16)  # held: not a leak
    tracker.buffer(reserve=16).release()  # released: not a leak
    tracker.buffer(reserve=16)  # dropped unreleased: a leak
    leaked = tracker.leaked_since(mark)
    assert [t.kind for t in leaked] == ["buffer"] and leaked[0].obj is not kept
    tracker.release_leaked(leaked)
    assert tracker.leaked_since(mark) == []
    kept.release()


@pytest.mark.slow
def test_a_session_releases_every_gl_object_it_made(
    globeview_gl, globeview_terrain, globeview_registry
) -> None:
    from globeview.app.session import GlobeSession
    from globeview.model.camera import Camera
    from globeview.render.offscreen import OffscreenTarget

    tracker = gpu_objects(globeview_gl)
    before = tracker.counts()
    session = GlobeSession(
        globeview_gl, globeview_terrain, Camera.from_lonlat(-71.3, 44.27, 4e4), globeview_registry
    )
    session.add_embedded_overlays(imagery=True)
    session.settings.hillshade = True
    target = OffscreenTarget(globeview_gl, (96, 72))
    session.render(target.fbo, (96, 72))
    made = tracker.counts()
    assert sum(made.values()) > sum(before.values()) + 10  # pools, programs, overlays...
    session.release_gl()
    target.release()
    assert tracker.counts() == before


LEAKY_TEST = """
    from globeview.render.gpu_objects import gpu_objects

    def test_leaks(globeview_gl):
        gpu_objects(globeview_gl).buffer(reserve=64)  # never released, dropped

    def test_keeps_and_releases(globeview_gl):
        buf = gpu_objects(globeview_gl).buffer(reserve=64)
        buf.release()
"""


@pytest.mark.slow
def test_the_gl_fixture_fails_a_test_that_leaks(tmp_path) -> None:
    (tmp_path / "test_leaky.py").write_text(textwrap.dedent(LEAKY_TEST))
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_leaky.py"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    text = out.stdout + out.stderr
    assert out.returncode == 1, text
    # The leak check runs at teardown: pytest reports the leaking test as an error.
    assert "2 passed, 1 error" in text and "ERROR test_leaky.py::test_leaks" in text, text
    assert "GL objects leaked by this test (1): buffer from test_leaky" in text, text
