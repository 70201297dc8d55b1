"""Suite-wide guard: where the project's test command runs (./test sets
GLOBEVIEW_REQUIRE_GL=1), a missing headless OpenGL must fail the run, not quietly skip every
rendering test. Run plain `pytest` on a machine without EGL and those tests skip instead."""

from __future__ import annotations

import os

import pytest


def pytest_sessionstart(session: pytest.Session) -> None:
    if os.environ.get("GLOBEVIEW_REQUIRE_GL") != "1":
        return
    from globeview.render.offscreen import RenderError, create_headless_context

    try:
        create_headless_context().release()
    except RenderError as exc:
        pytest.exit(f"headless OpenGL is required by ./test: {exc}", returncode=1)
